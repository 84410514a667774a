"""Hysteresis, open and closed loop (paper Fig. 14)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nanosim.artifact_names import FIG14_HYSTERESIS
from nanosim.experiments.loop import (
    FS,
    LoopTrace,
    StageFactory,
    compensate,
    resolve_feedforward,
    plateaus,
    run_closed_loop,
)
from nanosim.experiments.registry import Experiment, register
from nanosim.plant.noise import stream_seed
from nanosim.plant.piezo import loop_hysteresis_percent
from nanosim.plots.experiments import fig_hysteresis

__all__ = ["HysteresisResult", "hysteresis"]


@dataclass(frozen=True)
class HysteresisResult:
    """Open loop: actuator A 0 -> 1.65 -> 0 V. Closed loop: X 0 -> 20 um -> 0.

    ``closed_loop_nm`` is the largest gap between the settled positions on the
    way up and on the way down (a staircase of ``levels`` levels), the
    hysteresis that remains under feedback; ``closed_ramp_lag_nm`` is the
    branch gap of the continuous triangle, dominated by velocity lag.
    """

    open_v: np.ndarray
    open_y_um: np.ndarray
    open_loop_percent: float
    open_loop_input_percent: float
    open_travel_um: np.ndarray
    closed: LoopTrace
    closed_levels_um: np.ndarray
    closed_up_um: np.ndarray
    closed_down_um: np.ndarray
    closed_loop_nm: float
    closed_loop_percent: float
    closed_ramp_lag_nm: float
    feedforward: str | None = None


def _branch_gap(x, y, n_grid=400) -> float:
    """Max vertical gap between rising and falling branches of y(x) on a triangle x."""
    k = int(np.argmax(x))
    grid = np.linspace(max(x[:k + 1].min(), x[k:].min()), x[k], n_grid)[1:-1]
    up = np.interp(grid, x[:k + 1], y[:k + 1])
    dn = np.interp(grid, x[k:][::-1], y[k:][::-1])
    return float(np.abs(up - dn).max())


def hysteresis(factory: StageFactory, controller, seed=0, duration_s=2.0, travel_um=20.0, levels=11,
               dwell_s=0.12, feedforward: str | None = None) -> HysteresisResult:
    """Open-loop loop on actuator A (0 -> 1.65 -> 0 V) and the closed-loop 20 um triangle and staircase.

    ``feedforward="inverse-pi"`` pre-distorts the open-loop command through the inverse of a
    Prandtl-Ishlinskii operator fitted to the stage's piezo beforehand
    (:func:`~nanosim.experiments.loop.fit_feedforward`) and puts the same inverse behind the controller
    (:func:`~nanosim.experiments.loop.compensate`); the loop width is measured against the undistorted command.
    """
    ffm = resolve_feedforward(factory, seed, feedforward)
    n = int(duration_s * FS)
    tri = np.concatenate([np.linspace(0, 1, n // 2), np.linspace(1, 0, n - n // 2)])
    u = np.zeros((n, 3))
    u[:, 0] = 1.65 * tri
    stage = factory(stream_seed(seed, "hysteresis", 0))
    ff, _ = compensate(stage, controller, ffm)
    tr = stage.run(u if ff is None else ff.run(u))
    y = tr.sensor_um - tr.sensor_um[0]
    travel = y[n // 2 - 1]
    out_pct, in_pct = loop_hysteresis_percent(u[:, 0], np.sign(travel[0]) * y[:, 0])
    ref = np.zeros((n, 3))
    ref[:, 0] = travel_um * tri
    stage = factory(stream_seed(seed, "hysteresis", 1))
    _, ctrl = compensate(stage, controller, ffm)
    cl = run_closed_loop(stage, ctrl, ref)
    lag_nm = _branch_gap(ref[:, 0], cl.y_um[:, 0]) * 1e3
    lv = np.linspace(0, travel_um, levels)
    seq = np.concatenate([lv, lv[-2::-1]])
    nd = int(dwell_s * FS)
    sref = np.zeros((len(seq) * nd, 3))
    sref[:, 0] = np.repeat(seq, nd)
    stage = factory(stream_seed(seed, "hysteresis", 2))
    _, ctrl = compensate(stage, controller, ffm)
    st = run_closed_loop(stage, ctrl, sref)
    settled, _ = plateaus(st.y_um[:, 0], nd, len(seq))
    up, down = settled[:levels], settled[levels - 1:][::-1]
    gap_nm = float(np.abs(up - down).max() * 1e3)
    return HysteresisResult(open_v=u[:, 0], open_y_um=y, open_loop_percent=out_pct, open_loop_input_percent=in_pct,
                            open_travel_um=travel, closed=cl, closed_levels_um=lv, closed_up_um=up,
                            closed_down_um=down, closed_loop_nm=gap_nm,
                            closed_loop_percent=100 * gap_nm * 1e-3 / travel_um, closed_ramp_lag_nm=lag_nm,
                            feedforward=feedforward)


def _metrics(r: HysteresisResult) -> dict:
    return {"hysteresis": {"open_loop_percent": r.open_loop_percent,
                           "open_loop_input_percent": r.open_loop_input_percent,
                           "open_loop_travel_um": r.open_travel_um.tolist(),
                           "closed_loop_nm": r.closed_loop_nm, "closed_loop_percent": r.closed_loop_percent,
                           "closed_loop_ramp_lag_nm": r.closed_ramp_lag_nm}}


register(Experiment("hysteresis", run=lambda ctx: hysteresis(ctx.factory, ctx.controller, seed=ctx.seed,
                                                              feedforward=ctx.feedforward),
                    metrics=_metrics, figure=lambda r, ctx: fig_hysteresis(r), figure_name=FIG14_HYSTERESIS,
                    order=10, cost=3))
