"""The command line's argument types and input checks: every bad value is refused with one line naming its option."""
from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

from nanosim.validation import named_message
from nanosim import constants as C
from nanosim.pipeline import artifacts as A

class _OneLineParser(argparse.ArgumentParser):
    """argparse that reports a usage error on one line (no usage block) and exits 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _field_default(config_class, name: str):
    """The default of field ``name`` of a config dataclass, also of one that needs arguments (CompareConfig)."""
    return next(f.default for f in dataclasses.fields(config_class) if f.name == name)


# --- argument types: the message names what was expected and what arrived ---------------------
def _int_at_least(lo: int):
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer >= {lo}, got {text!r}") from None
        if v < lo:
            raise argparse.ArgumentTypeError(f"expected an integer >= {lo}, got {v}")
        return v
    return parse


def _float_in(lo: float, hi: float, lo_open: bool = False):
    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(v) or v < lo or v > hi or (lo_open and v == lo):
            span = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
            raise argparse.ArgumentTypeError(f"expected a finite number in {span}, got {text}")
        return v
    return parse


def _file(text: str) -> str:
    p = Path(text)
    if p.is_dir():
        raise argparse.ArgumentTypeError(f"expected a file, got the directory {text!r}")
    if not p.is_file():
        raise argparse.ArgumentTypeError(f"no such file {text!r}")
    return text


def _type_error(name: str, exc: BaseException) -> argparse.ArgumentTypeError:
    """An argparse type's error (argparse puts ``argument NAME:`` in front)."""
    return argparse.ArgumentTypeError(named_message(name, exc)[len(name) + 2:])


def _out_folder(name: str):
    """``--out``/``--plot``: a folder that can be created or written, checked before any work."""
    def parse(text: str) -> str:
        from nanosim.pipeline.runfolder import RunFolderError, check_writable
        try:
            check_writable(text, name)
        except RunFolderError as exc:
            raise _type_error(name, exc) from None
        return text
    return parse


def _scheduler(text: str) -> str:
    """``--scheduler``: ``local`` or ``tcp://HOST:PORT`` (its form; whether it answers is known by connecting)."""
    from nanosim.pipeline.scaleout import check_scheduler
    try:
        return check_scheduler(text)
    except ValueError as exc:
        raise _type_error("--scheduler", exc) from None


def _seeds(sort: bool):
    """``--seeds``: ``0-4``, ``0,3,7`` or a mix, at most ``seeds.MAX_SEEDS`` distinct seeds."""
    def parse(text: str) -> tuple:
        from nanosim.pipeline.seeds import parse_seeds
        try:
            return parse_seeds(text, sort=sort)
        except ValueError as exc:
            raise _type_error("--seeds", exc) from None
    return parse


# --- checks of file contents, before any work: the message names the argument ----------------
def _load_mjcf(path):
    """The MJCF model (``None``: the bundled stage); errors name ``--mjcf``."""
    from nanosim.plant.mjcf import load_model
    try:
        return load_model(path)
    except (OSError, ValueError) as exc:
        raise ValueError(named_message("--mjcf", exc)) from None


def _check_mjcf(args) -> None:
    if getattr(args, "mjcf", None) is not None:
        _load_mjcf(args.mjcf)


def _check_controller(path, mjcf=None) -> Path:
    """``--controller``: matches its sealed run folder (if any), a controller file at the loop's period
    (:func:`~nanosim.design.architectures.protocol.read_controller_file`), and it stabilizes the stage.

    Stability is checked before any simulation: the discrete closed loop of the controller and the
    linear twin of the stage as the loop runs it (MuJoCo's linearization of the ideal stage, the
    bench electronics, the one-sample computation delay) must have every pole inside the unit circle.
    """
    import numpy as np

    from nanosim.design.architectures.protocol import read_controller_file
    from nanosim.design.robustness import closed_loop_poles, controller_systems
    from nanosim.pipeline.design import twin_loop_plant
    from nanosim.pipeline.runfolder import verify_input_file
    from nanosim.plant.runplant import RunPlant

    p = verify_input_file(path, "--controller").resolve()       # a sealed run's controller must match it
    cfg = read_controller_file(p, dt=C.CONTROL_PERIOD_S, name="--controller")
    plant = twin_loop_plant(RunPlant.of_model(_load_mjcf(mjcf)).twin.sysd_V)
    K, Ky = controller_systems(cfg)
    poles = closed_loop_poles(plant.G, K, Ky, plant.delay_samples)
    rho = float(np.max(np.abs(poles))) if poles.size else 0.0
    if not rho < 1.0:
        raise ValueError(f"--controller: {str(path)!r} does not stabilize the stage: a closed-loop pole at "
                         f"|z| = {rho:.4g} >= 1 with the linear twin (the loop as run); refused before the simulation")
    return p


def _check_model(path) -> Path:
    """``--model``: a model.npz (or a run folder holding one) matching its sealed run folder (if any)."""
    from nanosim.design.lti import load_state_space_npz
    from nanosim.pipeline.runfolder import verify_input_file

    p = Path(path)
    if p.is_dir():
        p = p / A.MODEL_NPZ
    if not p.is_file():
        raise ValueError(f"--model: expected a model.npz or a run folder holding one, got {str(path)!r}"
                         + (" (no model.npz in it)" if Path(path).is_dir() else ""))
    p = verify_input_file(p, "--model").resolve()                 # a sealed run's model must match it
    try:
        _, Gd = load_state_space_npz(p)
    except (OSError, ValueError) as exc:
        raise ValueError(named_message("--model", exc)) from None
    if Gd is not None and not math.isclose(float(Gd.dt), C.CONTROL_PERIOD_S, rel_tol=1e-9):
        raise ValueError(f"--model: expected a discrete model at the loop's period dt = {C.CONTROL_PERIOD_S:g} s, "
                         f"got dt = {float(Gd.dt)!r} s in {str(p)!r}")
    return p


def _check_model_mat(path) -> Path:
    """``--model`` as a MATLAB state space ``A, B, C, D, Ts`` (discrete at the loop's period, or continuous)."""
    import identification as ident
    try:
        *_, ts = ident.load_state_space(path)
    except (OSError, ValueError) as exc:
        raise ValueError(named_message("--model", exc)) from None
    if ts > 0 and not math.isclose(ts, C.CONTROL_PERIOD_S, rel_tol=1e-9):
        raise ValueError(f"--model: expected Ts = {C.CONTROL_PERIOD_S:g} s (the loop's period) or 0 (continuous), "
                         f"got Ts = {ts!r} s in {str(path)!r}")
    return Path(path).resolve()


def _check_weights(path):
    """``--weights``: a JSON/TOML file of usable weights (design, pipeline and sweep share this check)."""
    if path is None:
        return None
    from nanosim.design.weights import Weights
    try:
        Weights.coerce(path).check()
    except (OSError, ValueError) as exc:
        msg = named_message("--weights", exc)[len("--weights: "):]
        where = "" if str(path) in msg else f"{str(path)!r}: "           # name the file that arrived
        raise ValueError(f"--weights: {where}{msg}") from None
    return path
