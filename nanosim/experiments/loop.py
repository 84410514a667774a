"""The closed loop as the bench runs it, and the signal helpers the experiments share.

The loop is ``e_k = r_k - y_k`` (sensor volts), ``u_k = K e_k (+ Ky y_k)``
(controller volts), ``y_{k+1} = stage.step(u_k)``. References are in um from
the probe origin. Every closed-loop record starts from the state that
:class:`LoopProtocol` states: the controller started at the stage's reading at
rest, the approach from that reading to the record's first reference, and a
hold there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from nanosim import constants as C
from nanosim.design.controller import DiscreteController
from nanosim.design.feedforward import (
    FEEDFORWARD_CHOICES,
    HysteresisCompensatedController,
    InversePI,
    PIModel,
    fit_prandtl_ishlinskii,
    fit_thresholds_V,
)
from nanosim.paper import PAPER_SETTLING_BAND

__all__ = ["FS", "UM_PER_V", "LoopTrace", "run_closed_loop", "StageFactory", "plateaus", "step_metrics",
           "INTERPOLATION_S", "interpolate", "LoopProtocol", "LOOP_PROTOCOL", "start_controller",
           "check_feedforward", "compensate", "fit_feedforward", "resolve_feedforward", "FIT_TURNING_POINTS_V",
           "FIT_RATE_V_PER_S"]

FS = C.CONTROL_RATE_HZ
UM_PER_V = C.SENSOR_UM_PER_V


def _samples(name: str, seconds) -> int:
    try:
        x = float(seconds)
    except (TypeError, ValueError):
        x = float("nan")
    if isinstance(seconds, bool) or not math.isfinite(x) or x < 0:
        raise ValueError(f"{name}: expected a finite duration >= 0 s, got {seconds!r}")
    return int(round(x * FS))


@dataclass(frozen=True)
class LoopProtocol:
    """The stated start of every closed-loop record (single stage and batch alike).

    1. **Controller start.** At the first sample the stage is at rest at its
       reading ``y0`` (home, zero command) and the controller is started there
       by :func:`start_controller`: ``controller.reset_at(y0)``, the bumpless
       state for zero error and zero command
       (:func:`~nanosim.design.controller.bumpless_state`). That is one rule for
       every controller: the zero state for a one-degree-of-freedom controller,
       the equilibrium at the reading (corrected along the integrators to a zero
       first command) for a two-degree-of-freedom one. No state is carried over
       from an earlier run of the same controller object.
    2. **Approach.** The reference moves from the home reading to the record's
       first reference ``ref[0]`` along a raised cosine
       ``r_k = y0 + (ref[0] - y0) (1 - cos(pi k / n_a)) / 2`` over
       ``approach_s`` (``n_a`` samples), a monotone move without jerk at its ends.
    3. **Hold.** The reference stays at ``ref[0]`` for ``hold_s``: the
       piezo's creep and the loop's transient after the approach decay for a
       stated time before the record.
    4. **Record.** ``ref`` from its first sample; the returned trace holds only
       this part.

    Parameters
    ----------
    approach_s : float
        Duration of the approach [s] (0: the record starts at home).
    hold_s : float
        Hold at the first reference before the record [s].
    """

    approach_s: float = 0.36
    hold_s: float = 0.24

    def __post_init__(self):
        for name in ("approach_s", "hold_s"):
            _samples(name, getattr(self, name))
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def n_approach(self) -> int:
        """Samples of the approach."""
        return _samples("approach_s", self.approach_s)

    @property
    def n_hold(self) -> int:
        """Samples of the hold."""
        return _samples("hold_s", self.hold_s)

    @property
    def n_before_record(self) -> int:
        """Samples run before the record (approach and hold)."""
        return self.n_approach + self.n_hold

    def weights(self) -> np.ndarray:
        """``(n_before_record,)`` fraction of the way from the home reading to ``ref[0]`` at each sample."""
        n = self.n_approach
        w = 0.5 * (1 - np.cos(np.pi * np.arange(n) / n)) if n else np.zeros(0)
        return np.concatenate([w, np.ones(self.n_hold)])

    def with_hold(self, hold_s: float) -> "LoopProtocol":
        """The same protocol with another hold [s]."""
        return LoopProtocol(approach_s=self.approach_s, hold_s=hold_s)

    def describe(self) -> dict:
        """The protocol as JSON types (for ``metrics.json`` and the report)."""
        return {"controller_start": "reset_at(home reading): bumpless state for zero error and zero command "
                                    "(zero state for a one-degree-of-freedom controller)",
                "approach": "raised cosine from the home reading to the first reference",
                "approach_s": self.approach_s, "hold_s": self.hold_s}


# The protocol of every closed-loop experiment unless it states another one.
LOOP_PROTOCOL = LoopProtocol()


def start_controller(controller, measurement_V) -> None:
    """Rule 1 of :class:`LoopProtocol`: ``controller.reset_at(measurement_V)`` (zero command).

    At a zero reading the bumpless state for zero command is the zero state, ``controller.reset()``
    (also for a controller whose equilibrium at a reading is not defined, an exact integrator on
    its measurement path).
    """
    y = np.asarray(measurement_V, dtype=float)
    if y.any():
        controller.reset_at(y)
    else:
        controller.reset()


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


def run_closed_loop(stage, controller: DiscreteController, ref_um: np.ndarray, *,
                    protocol: LoopProtocol = LOOP_PROTOCOL) -> LoopTrace:
    """Run the loop on ``ref_um`` (N, 3) from the state ``protocol`` states (:class:`LoopProtocol`).

    The controller is started at the stage's first reading (whatever state it
    holds from an earlier run), then the approach and the hold run, then the
    record. A stage that runs closed loops itself (a member of a batch,
    :mod:`nanosim.experiments.batch_suite`) is handed the whole call.
    """
    if not isinstance(protocol, LoopProtocol):
        raise ValueError(f"protocol: expected a LoopProtocol, got {type(protocol).__name__}")
    batched = getattr(stage, "closed_loop", None)
    if batched is not None:
        return batched(controller, ref_um, protocol=protocol)
    ref_um = np.asarray(ref_um, float)
    y = stage.sensors.step(stage.table_um).reading_V if hasattr(stage, "sensors") else np.zeros(3)
    start_controller(controller, y)
    if protocol.n_before_record:
        start = y * UM_PER_V
        w = protocol.weights()
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


def check_feedforward(feedforward) -> str | None:
    """``feedforward`` validated: None or one of :data:`~nanosim.design.feedforward.FEEDFORWARD_CHOICES`."""
    if feedforward is not None and feedforward not in FEEDFORWARD_CHOICES:
        raise ValueError(f"feedforward: expected None or one of {', '.join(FEEDFORWARD_CHOICES)}, "
                         f"got {feedforward!r}")
    return feedforward


# The feedforward's identification record, per actuator alone from rest: ramps through these turning points
# (nested minor loops inside the Fig. 14 span 0 -> 1.65 V) at the Fig. 14 rate
FIT_TURNING_POINTS_V = (0.0, 1.65, 0.2, 1.4, 0.4, 1.1, 0.6, 0.9, 0.0)
FIT_RATE_V_PER_S = 1.65


def _fit_command(points=FIT_TURNING_POINTS_V, rate_V_per_s: float = FIT_RATE_V_PER_S) -> np.ndarray:
    pieces = [np.linspace(a, b, max(2, int(round(abs(b - a) / rate_V_per_s * FS))), endpoint=False)
              for a, b in zip(points[:-1], points[1:])]
    return np.concatenate(pieces + [np.array([points[-1]])])


def fit_feedforward(factory, seed: int = 0) -> PIModel:
    """A Prandtl-Ishlinskii operator fitted to the stage's piezo (the inverse-PI feedforward's model).

    Each actuator alone, from rest on a fresh stage (stream ``stream_seed(seed, "feedforward.fit", j)``),
    runs the nested minor loops of :data:`FIT_TURNING_POINTS_V` open loop. Its reading is projected on
    its principal direction (the actuator's column of the static gain, up to scale) and scaled to
    controller volts by its least-squares slope; the three records are fitted together
    (:func:`~nanosim.design.feedforward.fit_prandtl_ishlinskii`, :data:`~nanosim.design.feedforward.FIT_OPERATORS`
    plays over the span).
    """
    from nanosim.plant.noise import stream_seed
    v = _fit_command()
    V, H = [], []
    for j in range(3):
        u = np.zeros((v.size, 3))
        u[:, j] = v
        tr = factory(stream_seed(seed, "feedforward.fit", j)).run(u)
        y = tr.sensor_um - tr.sensor_um[0]
        g = np.linalg.svd(y - y.mean(axis=0), full_matrices=False)[2][0]
        s = y @ g
        s = s * np.sign(s @ v)
        V.append(v)
        H.append(s * (v @ v) / (s @ v))                  # controller-volt equivalent
    return fit_prandtl_ishlinskii(np.column_stack(V), np.column_stack(H), fit_thresholds_V(max(FIT_TURNING_POINTS_V)))


def resolve_feedforward(factory, seed: int, feedforward) -> PIModel | None:
    """``feedforward`` as the experiments use it: None, or the operator :func:`fit_feedforward` identifies
    for ``"inverse-pi"`` (a :class:`~nanosim.design.feedforward.PIModel` passes through).
    """
    if isinstance(feedforward, PIModel):
        return feedforward
    if check_feedforward(feedforward) is None:
        return None
    return fit_feedforward(factory, seed)


def compensate(stage, controller, feedforward: PIModel | None):
    """``(open_loop, controller)`` for ``feedforward``: the inverse of the fitted operator
    (:class:`~nanosim.design.feedforward.InversePI`, fresh state) as the open-loop pre-distortion and
    behind the controller; ``(None, controller)`` for None.
    """
    if feedforward is None:
        return None, controller
    if not isinstance(feedforward, PIModel):
        raise ValueError(f"feedforward: expected None or a PIModel (resolve_feedforward), got {feedforward!r}")
    if getattr(stage, "closed_loop", None) is not None:
        raise ValueError("feedforward: a batched stage runs its loop itself; expected a single stage")
    return InversePI(feedforward), HysteresisCompensatedController(controller, InversePI(feedforward))


StageFactory = Callable[[int], object]


def plateaus(y, dwell: int, count: int):
    """Mean and std of the settled second half of ``count`` consecutive dwells of ``dwell`` samples."""
    parts = [y[i * dwell + dwell // 2:(i + 1) * dwell] for i in range(count)]
    return np.array([p.mean() for p in parts]), np.array([p.std() for p in parts])


def step_metrics(t_s, y, final):
    """Rise (10-90 %), peak and settling times (ms) and overshoot (%) of ``y`` normalised by ``final``.

    Settling: the first time after which ``y`` stays within :data:`nanosim.paper.PAPER_SETTLING_BAND` (2 %)
    of ``final``.
    """
    y = y / final
    rise = t_s[np.argmax(y >= 0.9)] - t_s[np.argmax(y >= 0.1)]
    ipk = int(np.argmax(y))
    outside = np.flatnonzero(np.abs(y - 1) > PAPER_SETTLING_BAND)
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
