"""Creep: move to the origin and hold, open and closed loop (paper Fig. 15)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nanosim.artifact_names import FIG15_CREEP
from nanosim.experiments.loop import FS, LoopProtocol, StageFactory, run_closed_loop
from nanosim.experiments.registry import Experiment, register
from nanosim.plant.noise import stream_seed
from nanosim.plots.experiments import fig_creep
from nanosim.ramps import raised_cosine

__all__ = ["CreepResult", "creep", "MOVE_S"]

MOVE_S = 0.1            # the move from home to the origin before the hold [s]


@dataclass(frozen=True)
class CreepResult:
    """Open- and closed-loop hold at the origin: readings (um) and drift over the hold (nm per axis)."""

    t_s: np.ndarray
    open_y_um: np.ndarray
    closed_y_um: np.ndarray
    open_drift_nm: np.ndarray      # per axis, over the hold
    closed_drift_nm: np.ndarray
    hold_s: float


def _drift_nm(y, n_after):
    w = int(0.2 * FS)
    return (y[-w:].mean(0) - y[n_after:n_after + w].mean(0)) * 1e3


def creep(factory: StageFactory, controller, G0_um_per_V, seed=0, hold_s=10.0) -> CreepResult:
    """Move to the origin and hold: open loop through inv(G0), and closed loop.

    Both moves take :data:`MOVE_S` along a raised cosine from home; the closed loop's
    :class:`~nanosim.experiments.loop.LoopProtocol` is that approach with no hold, so the
    two records start at the same time after the same move.
    """
    n_move, n_hold = int(round(MOVE_S * FS)), int(hold_s * FS)
    st = factory(stream_seed(seed, "creep", 0))
    home = st.sensors.step(st.table_um).reading_um if hasattr(st, "sensors") else np.zeros(3)
    v0 = np.linalg.solve(G0_um_per_V, -home)
    w = raised_cosine(n_move)
    u = np.vstack([w[:, None] * v0, np.tile(v0, (n_hold, 1))])
    tr = st.run(u)
    y_open = tr.sensor_um[n_move:]
    cl = run_closed_loop(factory(stream_seed(seed, "creep", 1)), controller, np.zeros((n_hold, 3)),
                         protocol=LoopProtocol(approach_s=MOVE_S, hold_s=0.0))
    n_after = int(0.5 * FS)
    return CreepResult(t_s=np.arange(n_hold) / FS, open_y_um=y_open, closed_y_um=cl.y_um,
                       open_drift_nm=_drift_nm(y_open, n_after), closed_drift_nm=_drift_nm(cl.y_um, n_after),
                       hold_s=hold_s)


def _metrics(r: CreepResult) -> dict:
    return {"creep": {"open_loop_drift_nm": float(np.linalg.norm(r.open_drift_nm)),
                      "closed_loop_drift_nm": float(np.linalg.norm(r.closed_drift_nm)),
                      "open_loop_drift_xyz_nm": r.open_drift_nm.tolist(),
                      "closed_loop_drift_xyz_nm": r.closed_drift_nm.tolist(), "hold_s": r.hold_s}}


register(Experiment("creep", run=lambda ctx: creep(ctx.factory, ctx.controller, ctx.static_gain_um_per_V,
                                                   seed=ctx.seed),
                    metrics=_metrics, figure=lambda r, ctx: fig_creep(r), figure_name=FIG15_CREEP,
                    order=20, cost=7))
