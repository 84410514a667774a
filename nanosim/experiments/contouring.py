"""Contouring along a 45 degree line at 10-1000 um/s (paper Fig. 20).

The bench repeats the move: at each speed the path (out and back) runs
:func:`conditioning_cycles` times before the recorded cycle, on one stage
from the :class:`~nanosim.experiments.loop.LoopProtocol` start, so the record
starts from the state the repeated path leaves the piezo in. The paper runs
the same move at speeds from 10 to 1000 um/s on one stage (Sec. 5, Fig. 20):
its actuators have run the path before any one record. The piezo's play operators remember their
turning points (return-point memory). On the first cycle after the approach
from home (every actuator driven up), the actuators that keep going up ride
their initial loading curve, whose slope grows with the voltage (and, after
the hold's creep retraction, rejoin it in mid-path with a jump of gain),
while an actuator that turns back starts on a branch of the tangent gain; on
the 45 degree line actuator B turns back and A and C go on, so the X and Y
gains, and lags, part: with axes that match otherwise, the contour error of
that cycle is several times that of the repeated path. A full cycle between the path's own ends wipes the
approach out: every actuator then runs a branch from the path's turning
points, alike on every cycle; the remaining cycles let the operators' thermal
relaxation (creep) settle. ``first_cycle_*`` in the metrics keep the first
cycle's figures.
"""
from __future__ import annotations

import math
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

__all__ = ["ContourCase", "contour_reference", "contouring", "conditioning_cycles", "contour_error_nm",
           "ramp_lags_ms", "CONDITIONING_S", "RAMP_SETTLE_S"]

# Repetitions of the path before the recorded cycle: at least one, and at least this long [s]. After about
# 0.6 s of cycling the 1000 um/s contour error changes by < 5 nm from cycle to cycle
# (docs/explanation/paper-design.md, "The contour: a cycle of the repeated path").
CONDITIONING_S = 0.6


@dataclass(frozen=True)
class ContourCase:
    """One speed of the 45 degree contour: the recorded cycle and the first.

    ``trace``, ``contour_error_nm`` (nm), ``mean_error_nm``, ``max_error_nm`` (nm) and
    ``axis_tracking_error_um`` (um) are the recorded cycle's; ``conditioning_cycles`` ran before it;
    ``first_cycle_*`` (nm) are the first cycle's after the approach from home.
    """

    speed_um_s: float
    trace: LoopTrace
    contour_error_nm: np.ndarray
    mean_error_nm: float
    max_error_nm: float
    axis_tracking_error_um: float
    conditioning_cycles: int = 0
    first_cycle_mean_error_nm: float = float("nan")
    first_cycle_max_error_nm: float = float("nan")
    ramp_lag_ms: tuple = (float("nan"), float("nan"))

    @property
    def lag_difference_us(self) -> float:
        """X lag minus Y lag (us): the recorded cycle's contour error is about this times the speed per axis
        over sqrt(2).
        """
        return 1e3 * (self.ramp_lag_ms[0] - self.ramp_lag_ms[1])


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


def conditioning_cycles(cycle_s: float, conditioning_s: float = CONDITIONING_S) -> int:
    """Cycles of ``cycle_s`` (s) run before the record: ``max(1, ceil(conditioning_s / cycle_s))``."""
    c, t = float(cycle_s), float(conditioning_s)
    if not (math.isfinite(c) and c > 0):
        raise ValueError(f"cycle_s: expected a finite duration > 0 s, got {cycle_s!r}")
    if not (math.isfinite(t) and t >= 0):
        raise ValueError(f"conditioning_s: expected a finite duration >= 0 s, got {conditioning_s!r}")
    return max(1, math.ceil(t / c - 1e-9))


def contour_error_nm(ref_um, y_um):
    """Distance of the reading to the 45 degree path (nm) while the reference moves, and the moving mask.

    The path is the line x = y, so the distance is ``|x - y| / sqrt(2)``; samples count while the
    reference is between 0.5 and 19.5 um (the corners' interpolation left out).
    """
    ref_um, y_um = np.asarray(ref_um, float), np.asarray(y_um, float)
    moving = (ref_um[:, 0] > 0.5) & (ref_um[:, 0] < 19.5)
    return np.abs(y_um[:, 0] - y_um[:, 1])[moving] / np.sqrt(2) * 1e3, moving


# A ramp's error is read as a lag once the reference has run at its constant speed this long [s]: the
# loop's transient at the corner has settled (2 % settling of the bench's loops: about 10 ms).
RAMP_SETTLE_S = 0.01


def ramp_lags_ms(ref_um, y_um, moving, fs: float = FS, settle_s: float = RAMP_SETTLE_S) -> tuple[float, float]:
    """Each axis's ramp lag (X, Y; ms): the least-squares ``lag`` of ``ref - y = lag * dref/dt + offset``
    over the ``moving`` samples at which the reference has run at constant speed for ``settle_s``.

    On a ramp the error of a loop of type one settles to ``v / K_v`` (the velocity constant ``K_v``): a
    lag. On the 45 degree line both axes move at ``v / sqrt(2)``, so the distance to the path is
    ``(lag_x - lag_y) v / 2`` plus the offsets' difference: the contour error measures how well the
    axes' lags match, not how small they are (a 1 % gain difference between the axes' loops moves their
    lags apart by 1 %). NaN without such samples.
    """
    ref_um, y_um = np.asarray(ref_um, float), np.asarray(y_um, float)
    v = np.gradient(ref_um[:, :2], axis=0) * fs
    speed = np.hypot(v[:, 0], v[:, 1])
    const = (speed > 0) & (np.abs(speed - speed.max()) <= 0.01 * speed.max())
    n = max(1, int(round(settle_s * fs)))
    held = np.convolve(const.astype(int), np.ones(n, int))[:len(const)] == n     # constant for the last n samples
    m = np.asarray(moving, bool) & held
    e = ref_um[:, :2] - y_um[:, :2]
    if m.sum() < 2:
        return float("nan"), float("nan")
    out = []
    for ax in range(2):
        A = np.column_stack([v[m, ax], np.ones(int(m.sum()))])
        out.append(1e3 * float(np.linalg.lstsq(A, e[m, ax], rcond=None)[0][0]))
    return out[0], out[1]


def _cycle(tr: LoopTrace, k: int, n: int) -> LoopTrace:
    sl = slice(k * n, (k + 1) * n)
    return LoopTrace(t_s=tr.t_s[sl] - tr.t_s[k * n], ref_um=tr.ref_um[sl], y_um=tr.y_um[sl],
                     table_um=tr.table_um[sl], u_V=tr.u_V[sl], saturated=tr.saturated[sl])


def contouring(factory: StageFactory, controller, seed=0,
               speeds_um_s=(10, 30, 100, 300, PAPER_CONTOUR_SPEED_UM_S), feedforward: str | None = None,
               conditioning_s: float = CONDITIONING_S) -> list:
    """Run the contour at each speed (um/s); returns a list of :class:`ContourCase`.

    At each speed, on a fresh stage (stream ``stream_seed(seed, "contouring")``), the path runs
    :func:`conditioning_cycles` times back to back, then once more: that last cycle is the record.
    ``conditioning_s = 0`` still runs one cycle before the record.
    ``feedforward="inverse-pi"``: the controller's command passes the inverse of a
    Prandtl-Ishlinskii operator fitted to the stage's piezo
    (:func:`~nanosim.experiments.loop.fit_feedforward`, :func:`~nanosim.experiments.loop.compensate`).
    """
    ffm = resolve_feedforward(factory, seed, feedforward)
    cases = []
    for v in speeds_um_s:
        one = contour_reference(v)
        n_cond = conditioning_cycles(len(one) / FS, conditioning_s)
        stage = factory(stream_seed(seed, "contouring"))
        full = run_closed_loop(stage, compensate(stage, controller, ffm)[1], np.tile(one, (n_cond + 1, 1)))
        first, cl = _cycle(full, 0, len(one)), _cycle(full, n_cond, len(one))
        d0, _ = contour_error_nm(first.ref_um, first.y_um)
        d, moving = contour_error_nm(cl.ref_um, cl.y_um)
        ax_err = np.abs(cl.error_um[moving, :2]).max()
        cases.append(ContourCase(float(v), cl, d, float(d.mean()), float(d.max()), float(ax_err),
                                 conditioning_cycles=n_cond, first_cycle_mean_error_nm=float(d0.mean()),
                                 first_cycle_max_error_nm=float(d0.max()),
                                 ramp_lag_ms=ramp_lags_ms(cl.ref_um, cl.y_um, moving)))
    return cases


def _metrics(cases) -> dict:
    return {"contouring": [{"speed_um_s": c.speed_um_s, "mean_error_nm": c.mean_error_nm,
                            "max_error_nm": c.max_error_nm,
                            "axis_tracking_error_um": c.axis_tracking_error_um,
                            "conditioning_cycles": c.conditioning_cycles,
                            "first_cycle_mean_error_nm": c.first_cycle_mean_error_nm,
                            "first_cycle_max_error_nm": c.first_cycle_max_error_nm,
                            "ramp_lag_ms": list(c.ramp_lag_ms), "lag_difference_us": c.lag_difference_us}
                           for c in cases]}


register(Experiment("contouring", run=lambda ctx: contouring(ctx.factory, ctx.controller, seed=ctx.seed,
                                                             feedforward=ctx.feedforward),
                    metrics=_metrics, figure=lambda r, ctx: fig_contouring(r),
                    figure_name=FIG20_CONTOURING, order=70, cost=6))
