"""Browser 3D viewer (viser) of the nanopositioner.

CLI glue: :func:`add_view_arguments` and :func:`run_view`. The server itself
lives in :mod:`nanosim.viewer.server` (imported lazily: viser is heavy).
"""
from __future__ import annotations

import argparse
import socket
import sys
import time


def add_view_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``view`` options to ``parser``."""
    parser.add_argument("--controller", metavar="FILE", default=None,
                        help="controller .npz (DiscreteController); without it the stage runs open loop")
    parser.add_argument("--port", type=int, default=8080, help="HTTP/websocket port (default 8080)")
    parser.add_argument("--host", default="127.0.0.1",
                        help="bind address (default 127.0.0.1; anything else is reachable from the network)")
    parser.add_argument("--mjcf", metavar="PATH", default=None, help="stage MJCF (default: bundled scene)")
    parser.add_argument("--physics", choices=("auto", "mujoco", "linear"), default="auto",
                        help="mujoco: the nonlinear MuJoCo integrator; linear: MuJoCo's linearization about "
                             "home (much faster); auto (default): MuJoCo if it keeps real time, else linear")
    parser.add_argument("--seconds", type=float, default=None,
                        help="serve for S seconds then exit (tests, screenshots)")


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


def run_view(args) -> int:
    """Serve the viewer until Ctrl-C (or ``args.seconds``). Returns an exit code."""
    port, host = int(args.port), str(args.host)
    if not 0 < port < 65536:
        print(f"view: port must be 1..65535, got {port}", file=sys.stderr)
        return 2
    try:
        from nanosim.viewer.server import ViewerApp
        app = ViewerApp(model_path=args.mjcf, controller_path=args.controller, host=host, port=port,
                        physics=getattr(args, "physics", "auto"))
    except (FileNotFoundError, ValueError) as exc:
        print(f"view: {exc}", file=sys.stderr)
        return 2
    if not port_is_free(host, port):
        print(f"view: port {port} is busy (choose another with --port)", file=sys.stderr)
        return 2
    try:
        app.start()
    except OSError as exc:
        print(f"view: cannot serve on {host}:{port}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    print(f"nanosim viewer on http://{'localhost' if host in ('127.0.0.1', '::1') else host}:{port}  "
          f"(Ctrl-C to stop)", flush=True)
    try:
        if args.seconds is not None:
            time.sleep(max(0.0, float(args.seconds)))
        else:
            while True:
                time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        app.stop()
    return 0


__all__ = ["add_view_arguments", "run_view", "port_is_free"]
