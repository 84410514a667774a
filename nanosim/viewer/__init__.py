"""Browser 3D viewer (viser) of the nanopositioner.

CLI glue: :func:`add_view_arguments` and :func:`run_view`. The server itself
lives in :mod:`nanosim.viewer.server` (imported lazily: viser is heavy).
"""
from __future__ import annotations

import argparse
import socket
import sys
import time

from nanosim.validation import Terminated


def add_view_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``view`` options to ``parser``."""
    parser.add_argument("--controller", metavar="FILE", default=None,
                        help="controller .npz (DiscreteController); without it the stage runs open loop")
    parser.add_argument("--bench", metavar="DIR", default=None,
                        help="nanosim compare run folder: its controllers in a dropdown, switched live without a "
                             "kick (without --controller the scorecard's default runs first)")
    parser.add_argument("--port", type=int, default=8080,
                        help="HTTP/websocket port (default 8080; 0 picks a free port and prints it)")
    parser.add_argument("--host", default="127.0.0.1",
                        help="bind address (default 127.0.0.1; anything else is reachable from the network)")
    parser.add_argument("--mjcf", metavar="PATH", default=None, help="stage MJCF (default: bundled scene)")
    parser.add_argument("--physics", choices=("auto", "mujoco", "linear"), default="auto",
                        help="mujoco: the nonlinear MuJoCo integrator; linear: MuJoCo's linearization about "
                             "home (much faster); auto (default): MuJoCo if it keeps real time, else linear")
    parser.add_argument("--seconds", type=float, default=None,
                        help="serve for S > 0 seconds then exit (tests, screenshots)")


def port_is_free(host: str, port: int) -> bool:
    """True if ``host:port`` can be bound now."""
    fam = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(fam, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def free_port(host: str) -> int:
    """A port on ``host`` that is free now (the kernel's choice)."""
    fam = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(fam, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def _error(msg: str) -> int:
    print(f"nanosim view: error: {msg}", file=sys.stderr)
    return 2


def run_view(args) -> int:
    """Serve the viewer until Ctrl-C (or ``args.seconds``). Returns an exit code."""
    port, host = int(args.port), str(args.host)
    host = "127.0.0.1" if host == "localhost" else host
    if not 0 <= port < 65536:
        return _error(f"--port: expected 0..65535 (0 = a free port), got {port}")
    if args.seconds is not None and not (args.seconds > 0 and args.seconds < float("inf")):
        return _error(f"--seconds: expected a positive number of seconds, got {args.seconds}")
    try:
        socket.getaddrinfo(host, None, 0, socket.SOCK_STREAM, 0, socket.AI_NUMERICHOST)
    except (socket.gaierror, UnicodeError):
        return _error(f"--host: expected a numeric IP address such as 127.0.0.1, got {host!r}")
    if port == 0:
        try:
            port = free_port(host)
        except OSError as exc:
            return _error(f"--host: cannot bind {host}: {exc.strerror or exc}")
    try:
        from nanosim.viewer.server import ViewerApp
        app = ViewerApp(model_path=args.mjcf, controller_path=args.controller, host=host, port=port,
                        physics=getattr(args, "physics", "auto"), bench=getattr(args, "bench", None))
    except (FileNotFoundError, ValueError) as exc:
        return _error(str(exc))
    if not port_is_free(host, port):
        return _error(f"--port: port {port} is busy (choose another, or 0 for a free one)")
    try:
        app.start()
    except OSError as exc:
        return _error(f"cannot serve on {host}:{port}: {exc.strerror or exc}")
    print(f"nanosim viewer on http://{'localhost' if host in ('127.0.0.1', '::1') else host}:{port}  "
          f"(Ctrl-C to stop)", flush=True)
    try:
        if args.seconds is not None:
            time.sleep(max(0.0, float(args.seconds)))
        else:
            while True:
                time.sleep(1.0)
    except KeyboardInterrupt as exc:        # Ctrl-C is how a viewer ends; SIGTERM ends it with its status
        if isinstance(exc, Terminated):
            raise
    finally:
        app.stop()
    return 0


__all__ = ["add_view_arguments", "run_view", "port_is_free", "free_port"]
