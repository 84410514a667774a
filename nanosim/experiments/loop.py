"""The closed loop as the bench runs it, and the signal helpers the experiments share.

The loop is ``e_k = r_k - y_k`` (sensor volts), ``u_k = K e_k (+ Ky y_k)``
(controller volts), ``y_{k+1} = stage.step(u_k)``. References are in um from
the probe origin; closed-loop runs first ramp from the home reading to the
origin and settle.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from nanosim import constants as C
from nanosim.design.controller import DiscreteController
from nanosim.ramps import raised_cosine

__all__ = ["FS", "UM_PER_V", "LoopTrace", "run_closed_loop", "StageFactory", "plateaus", "step_metrics",
           "INTERPOLATION_S", "interpolate", "SETTLE_S"]

FS = C.CONTROL_RATE_HZ
UM_PER_V = C.SENSOR_UM_PER_V
# Duration of the move from home to the first reference point before a closed-loop record [s].
SETTLE_S = 0.6


@dataclass(frozen=True)
class LoopTrace:
    """Closed-loop record at 4 kHz (um, V, s)."""

    t_s: np.ndarray
    ref_um: np.ndarray
    y_um: np.ndarray
    table_um: np.ndarray
    u_V: np.ndarray
    saturated: np.ndarray

    @property
    def error_um(self) -> np.ndarray:
        """Tracking error ``ref_um - y_um`` (N, 3), um."""
        return self.ref_um - self.y_um


def run_closed_loop(stage, controller: DiscreteController, ref_um: np.ndarray, *, settle: bool = True,
                    settle_s: float = SETTLE_S) -> LoopTrace:
    """Run the loop on ``ref_um`` (N, 3); with ``settle`` first move to ref_um[0] from home.

    A stage that runs closed loops itself (a member of a batch,
    :mod:`nanosim.experiments.batch_suite`) is handed the whole call.
    """
    batched = getattr(stage, "closed_loop", None)
    if batched is not None:
        return batched(controller, ref_um, settle=settle, settle_s=settle_s)
    ref_um = np.asarray(ref_um, float)
    y = stage.sensors.step(stage.table_um).reading_V if hasattr(stage, "sensors") else np.zeros(3)
    if settle:
        if controller.two_dof:      # zero error at the home reading, zero command: no kick (reset_at)
            controller.reset_at(y)
        n = int(settle_s * FS)
        start = y * UM_PER_V
        w = raised_cosine(n, 0.6)
        pre = start + w[:, None] * (ref_um[0] - start)
        for r in pre:
            y = stage.step(controller.feedback(r / UM_PER_V, y))
    n = len(ref_um)
    ys, tb, us, sat = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3), bool)
    for k in range(n):
        u = controller.feedback(ref_um[k] / UM_PER_V, y)
        ys[k] = y * UM_PER_V
        tb[k] = stage.table_um
        us[k] = u
        y = stage.step(u)
        sat[k] = stage.last_saturated
    return LoopTrace(t_s=np.arange(n) / FS, ref_um=ref_um, y_um=ys, table_um=tb, u_V=us, saturated=sat)


StageFactory = Callable[[int], object]


def plateaus(y, dwell: int, count: int):
    """Mean and std of the settled second half of ``count`` consecutive dwells of ``dwell`` samples."""
    parts = [y[i * dwell + dwell // 2:(i + 1) * dwell] for i in range(count)]
    return np.array([p.mean() for p in parts]), np.array([p.std() for p in parts])


def step_metrics(t_s, y, final):
    """Rise (10-90 %), peak and 2 % settling times (ms) and overshoot (%) of ``y`` normalised by ``final``."""
    y = y / final
    rise = t_s[np.argmax(y >= 0.9)] - t_s[np.argmax(y >= 0.1)]
    ipk = int(np.argmax(y))
    outside = np.flatnonzero(np.abs(y - 1) > 0.02)
    if not len(outside):
        settle = t_s[0]
    elif outside[-1] + 1 < len(t_s):
        settle = t_s[outside[-1] + 1]
    else:
        settle = float("inf")                     # not settled inside the record
    return 1e3 * rise, 1e3 * t_s[ipk], 1e3 * settle, 100 * max(0.0, y[ipk] - 1)


INTERPOLATION_S = 0.0025


def interpolate(ref_um, smoothing_s: float = INTERPOLATION_S, fs: float = FS) -> np.ndarray:
    """The motion controller's command interpolation: two moving averages of ``smoothing_s``.

    The paper's UMAC interpolates commands (Sec. 5: "the command signals ... get
    round off at the corner"); two boxcars give an S-curve with finite
    acceleration and jerk. Straight paths stay on their line.
    """
    n = max(1, int(round(smoothing_s * fs)))
    if n == 1:
        return np.asarray(ref_um, float)
    k = np.ones(n) / n
    pad = np.pad(np.asarray(ref_um, float), ((2 * n, 2 * n), (0, 0)), mode="edge")
    out = np.apply_along_axis(lambda c: np.convolve(np.convolve(c, k, "same"), k, "same"), 0, pad)
    return out[2 * n:-2 * n]
