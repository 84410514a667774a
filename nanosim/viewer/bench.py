"""The controller bench in the viewer: load the bench's controllers, switch between them without a kick.

``nanosim view --bench DIR`` loads every ``DIR/<name>/controller.npz`` that ``nanosim compare``
wrote; the GUI offers them in a dropdown (:func:`add_bench_gui`) and the physics thread
switches with :func:`switch_controller`: the new controller starts at the current reading
with its first command equal to the last one applied (``reset_at`` with ``command_V``, see
:func:`nanosim.design.controller.bumpless_state`), so the stage does not jump.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nanosim.artifact_names import CONTROLLER_NPZ, SCORECARD_JSON
from nanosim.design.controller import DiscreteController

__all__ = ["load_bench", "switch_controller", "add_bench_gui", "apply_bench_choice", "bench_setup",
           "OPEN_LOOP"]

OPEN_LOOP = "(open loop)"


def load_bench(folder) -> dict[str, DiscreteController]:
    """``{name: DiscreteController}`` from a ``nanosim compare`` run folder (``<name>/controller.npz``).

    Raises
    ------
    FileNotFoundError
        ``folder`` is missing or holds no controller.
    """
    p = Path(folder)
    if not p.is_dir():
        raise FileNotFoundError(f"--bench: expected a nanosim compare run folder, got {str(p)!r}")
    out = {}
    files = sorted(p.glob(f"*/{CONTROLLER_NPZ}"))
    order = _scorecard_order(p)
    files.sort(key=lambda f: (order.index(f.parent.name) if f.parent.name in order else len(order), f.parent.name))
    for f in files:
        out[f.parent.name] = DiscreteController.from_npz(f)
    if not out:
        raise FileNotFoundError(f"--bench: no <name>/{CONTROLLER_NPZ} in {str(p)!r} (run nanosim compare first)")
    return out


def switch_controller(sim, controller, last_command_V=None) -> None:
    """Make ``controller`` (or None: open loop) the live controller of ``sim`` (:class:`LiveSim`) without a kick."""
    if controller is None:
        sim.controller_on = False
        return
    u = sim.u_V if last_command_V is None else np.asarray(last_command_V, float)
    sim.controller = controller
    sim.controller_on = True
    if isinstance(controller, DiscreteController):
        controller.reset_at(sim.y_V, command_V=u)
    else:
        controller.reset_at(sim.y_V)


def add_bench_gui(app, gui, bench: dict) -> None:
    """A dropdown of the bench's controllers; a change is applied by the physics thread."""
    names = (OPEN_LOOP,) + tuple(bench)
    active = next((n for n, c in bench.items() if c is app.sim.controller), OPEN_LOOP)
    sel = gui.add_dropdown("bench controller", names, initial_value=active,
                           hint="controllers of the nanosim compare run folder given with --bench; switching "
                                "starts the new one at the current reading and command (no kick)")
    gui.add_text("switches", "bumpless: same command before and after", disabled=True)

    @sel.on_update
    def _(_e):
        app.select_bench_controller(sel.value)


def bench_setup(bench, controller):
    """``(bench dict, initial controller)``: ``bench`` is None, a dict or a compare run folder; without
    ``--controller`` the loop starts with the scorecard's default (or the first bench controller).
    """
    if bench is None:
        return {}, controller
    if not isinstance(bench, dict):
        folder = Path(bench)
        bench = load_bench(folder)
        default = _scorecard_default(folder)
        if controller is None and bench:
            controller = bench.get(default) or next(iter(bench.values()))
    return dict(bench), controller


def _scorecard(folder: Path) -> dict:
    import json
    p = folder / SCORECARD_JSON
    try:
        return json.loads(p.read_text()) if p.is_file() else {}
    except (OSError, ValueError):
        return {}


def _scorecard_default(folder: Path):
    return _scorecard(folder).get("default")


def _scorecard_order(folder: Path) -> list:
    return list(_scorecard(folder).get("controllers", {}))


def apply_bench_choice(sim, bench: dict, name: str) -> None:
    """Physics-thread side of the dropdown: switch to ``bench[name]`` (open loop for :data:`OPEN_LOOP`)."""
    switch_controller(sim, None if name == OPEN_LOOP else bench[name])
