"""Contouring along a 45 degree line at 10-1000 um/s (paper Fig. 20)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nanosim.artifact_names import FIG20_CONTOURING
from nanosim.experiments.loop import (
    FS,
    INTERPOLATION_S,
    LoopTrace,
    StageFactory,
    compensate,
    resolve_feedforward,
    interpolate,
    run_closed_loop,
)
from nanosim.experiments.registry import Experiment, register
from nanosim.paper import PAPER_CONTOUR_SPEED_UM_S
from nanosim.plant.noise import stream_seed
from nanosim.plots.experiments import fig_contouring

__all__ = ["ContourCase", "contour_reference", "contouring"]


@dataclass(frozen=True)
class ContourCase:
    """One speed of the 45 degree contour: trace, contour error (nm) and per-axis tracking error (um)."""

    speed_um_s: float
    trace: LoopTrace
    contour_error_nm: np.ndarray
    mean_error_nm: float
    max_error_nm: float
    axis_tracking_error_um: float


def contour_reference(speed_um_s, corner_um=20.0, fs=FS, dwell_s=0.02, smoothing_s=INTERPOLATION_S):
    """45 degree line (0,0) -> (c,c) -> (0,0) at constant speed along the path (um), interpolated."""
    length = np.hypot(corner_um, corner_um)
    n = max(2, int(round(length / speed_um_s * fs)))
    s = np.linspace(0, 1, n)
    dwell = np.ones(int(dwell_s * fs))
    leg = np.concatenate([np.zeros(int(dwell_s * fs)), s, dwell, s[::-1]]) * corner_um
    ref = np.zeros((len(leg) + int(dwell_s * fs), 3))
    ref[:len(leg), 0] = leg
    ref[:len(leg), 1] = leg
    return interpolate(ref, smoothing_s, fs)


def contouring(factory: StageFactory, controller, seed=0,
               speeds_um_s=(10, 30, 100, 300, PAPER_CONTOUR_SPEED_UM_S), feedforward: str | None = None) -> list:
    """Run the contour at each speed (um/s); returns a list of :class:`ContourCase`.

    ``feedforward="inverse-pi"``: the controller's command passes the inverse of the piezo's
    Prandtl-Ishlinskii operator fitted on the stage
    (:func:`~nanosim.experiments.loop.fit_feedforward`, :func:`~nanosim.experiments.loop.compensate`).
    """
    ffm = resolve_feedforward(factory, seed, feedforward)
    cases = []
    for v in speeds_um_s:
        ref = contour_reference(v)
        stage = factory(stream_seed(seed, "contouring"))
        cl = run_closed_loop(stage, compensate(stage, controller, ffm)[1], ref)
        x, y = cl.y_um[:, 0], cl.y_um[:, 1]
        moving = (ref[:, 0] > 0.5) & (ref[:, 0] < 19.5)
        d = np.abs(x - y)[moving] / np.sqrt(2) * 1e3          # distance to the 45 degree path
        ax_err = np.abs(cl.error_um[moving, :2]).max()
        cases.append(ContourCase(float(v), cl, d, float(d.mean()), float(d.max()), float(ax_err)))
    return cases


def _metrics(cases) -> dict:
    return {"contouring": [{"speed_um_s": c.speed_um_s, "mean_error_nm": c.mean_error_nm,
                            "max_error_nm": c.max_error_nm,
                            "axis_tracking_error_um": c.axis_tracking_error_um} for c in cases]}


register(Experiment("contouring", run=lambda ctx: contouring(ctx.factory, ctx.controller, seed=ctx.seed,
                                                             feedforward=ctx.feedforward),
                    metrics=_metrics, figure=lambda r, ctx: fig_contouring(r),
                    figure_name=FIG20_CONTOURING, order=70, cost=6))
