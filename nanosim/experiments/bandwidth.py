"""Bandwidth from S and T measured with PRBS references, and the 2 um step (paper Fig. 18).

``S`` is the output sensitivity of the feedback loop, ``(I + G K_fb)^-1``. For a controller
with one degree of freedom (``u = K (r - y)``) it is the reference-to-error map ``I - T``,
measured directly. For two degrees of freedom (``u = K_e e + K_y y``, a reference prefilter)
the reference-to-error map also holds the prefilter, so ``S`` is computed from the same
record by the indirect closed-loop method (Ljung, *System Identification*, 2nd ed., Sec. 13.5):
the plant as the loop runs it, ``G = T_yr T_ur^-1`` (both H1 estimates from the reference),
closed with the controller's known feedback part ``K_fb = K_e - K_y``. The method is a
:class:`SensitivityMethod` (a formula, e.g. ``I - T``, and its explanation), recorded beside the curve.

:func:`nanosim.pipeline.compare.reading_disturbance_sensitivity` measures the same ``S`` directly, with
its own record (a PRBS added to the reading, zero reference), for any controller: on a linear loop the two
agree (``tests/test_bandwidth_sensitivity.py`` checks it); with the piezo's hysteresis in the loop each is the
best linear description of the loop under its own excitation, and they can differ by some percent. Both use
:func:`prbs_references`, :func:`h1_in_band` and :func:`sigma_in_band`.

The step is measured in eight cases: +X, -X, +Y and -Y, each after a hold of
1 s and of 3 s at the origin (:data:`STEP_HOLDS_S`), every case on a fresh
stage from the state :class:`~nanosim.experiments.loop.LoopProtocol` states
(controller started at the home reading, approach to the origin, the hold),
then 10 ms of the record at the origin before the step. The piezo's
hysteresis and creep make the step depend on that history (its sign relative
to the approach and the time the creep has had to decay), so each case states
it. The headline ``step_2um`` is the +X step after the 1 s hold (the paper's
Fig. 18 is an X step from rest); ``step_2um_worst`` is the worst case of the
eight (longest settling, largest overshoot).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import identification as ident
from nanosim.artifact_names import FIG18_BANDWIDTH_STEP
from nanosim.design.controller import DiscreteController
from nanosim.design.lti import crossing_hz
from nanosim.experiments.loop import (
    FS,
    UM_PER_V,
    LOOP_PROTOCOL,
    LoopProtocol,
    LoopTrace,
    StageFactory,
    run_closed_loop,
    step_metrics,
)
from nanosim.experiments.registry import Experiment, register
from nanosim.paper import PAPER_STEP_UM
from nanosim.plant.linearize import linearize
from nanosim.plant.noise import stream_seed
from nanosim.plots.experiments import fig_bandwidth

__all__ = ["BandwidthResult", "StepCase", "SensitivityMethod", "bandwidth", "step_case", "predicted_loop",
           "controller_response", "indirect_sensitivity_sigma", "prbs_references", "h1_in_band", "sigma_in_band",
           "SENSITIVITY_ONE_DOF", "SENSITIVITY_OBJECT", "SENSITIVITY_INDIRECT", "PRBS_DURATION_S", "PRBS_CLOCK_HZ",
           "PRBS_BAND_HZ", "PRBS_AMPLITUDE_UM", "STEP_HOLDS_S", "STEP_RECORD_S", "STEP_LEAD_S", "HEADLINE_STEP"]

# The PRBS references (also the reading disturbance of nanosim.pipeline.compare.reading_disturbance_sensitivity):
# duration, amplitude, the PRBS clock and the band the responses are estimated on [Hz].
PRBS_DURATION_S = 4.0
PRBS_AMPLITUDE_UM = 2.0
PRBS_CLOCK_HZ = 800.0
PRBS_BAND_HZ = (1.0, 1000.0)
# The 2 um step: holds at the origin before the record [s], the record after the step [s] and the
# part of the record at the origin before the step [s].
STEP_HOLDS_S = (1.0, 3.0)
STEP_RECORD_S = 0.3
STEP_LEAD_S = 0.01
# The case reported as ``step_2um``: (axis, sign, hold_s).
HEADLINE_STEP = (0, 1, 1.0)


@dataclass(frozen=True)
class SensitivityMethod:
    """How a measured ``sigma(S)`` was obtained.

    Attributes
    ----------
    formula : str
        The map measured, short enough for a legend: ``"I - T"`` or ``"(I + G K_fb)^-1"``.
    explanation : str
        What it was computed from and why this formula (a sentence fragment).
    """

    formula: str
    explanation: str

    def describe(self) -> str:
        """``"formula, explanation"``: the text of ``metrics.json``'s ``sensitivity_method``."""
        return f"{self.formula}, {self.explanation}"


SENSITIVITY_ONE_DOF = SensitivityMethod("I - T", "the reference-to-error map (one degree of freedom)")
SENSITIVITY_OBJECT = SensitivityMethod(
    "I - T", "the reference-to-error map (a controller object: its reference path is taken as one degree of freedom)")
SENSITIVITY_INDIRECT = SensitivityMethod(
    "(I + G K_fb)^-1", "G = T_yr T_ur^-1 from the reference record, K_fb = K_e - K_y (two degrees of freedom)")


@dataclass(frozen=True)
class StepCase:
    """One 2 um step: axis (0 = X, 1 = Y), sign, hold before the record (s), trace and its metrics (ms, %).

    ``trace`` starts ``STEP_LEAD_S`` before the step; ``baseline_um`` is the mean
    reading on the stepping axis over that lead.
    """

    axis: int
    sign: int
    hold_s: float
    trace: LoopTrace
    baseline_um: float
    rise_ms: float
    peak_ms: float
    settling_ms: float
    overshoot_percent: float

    @property
    def name(self) -> str:
        """``"+X after 1 s"`` style label."""
        return f"{'+' if self.sign > 0 else '-'}{'XYZ'[self.axis]} after {self.hold_s:g} s"

    def metrics(self) -> dict:
        """JSON metrics of the case."""
        return {"axis": "XYZ"[self.axis], "sign": self.sign, "hold_s": self.hold_s, "rise_ms": self.rise_ms,
                "peak_ms": self.peak_ms, "settling_ms": self.settling_ms,
                "overshoot_percent": self.overshoot_percent}


@dataclass(frozen=True)
class BandwidthResult:
    """sigma(S), sigma(T) measured with PRBS references (Hz grid), their -3 dB bandwidths and the 2 um step.

    ``sensitivity_method`` says how ``sigma_S`` was obtained; ``bandwidth_reference_error_hz`` is the
    ``I - T`` crossing whatever the method (equal to ``bandwidth_S_hz`` for one degree of freedom).
    """

    freq_hz: np.ndarray
    sigma_S: np.ndarray
    sigma_T: np.ndarray
    bandwidth_S_hz: float
    bandwidth_T_hz: float
    step: LoopTrace
    rise_ms: float
    peak_ms: float
    settling_ms: float
    overshoot_percent: float
    steps: tuple = ()
    protocol: LoopProtocol = LOOP_PROTOCOL
    bandwidth_reference_error_hz: float = float("nan")
    sensitivity_method: SensitivityMethod = SENSITIVITY_ONE_DOF

    @property
    def worst_step(self) -> dict:
        """The worst of :attr:`steps`: longest settling and largest overshoot (each over every case)."""
        if not self.steps:
            return {}
        slow = max(self.steps, key=lambda c: c.settling_ms)
        over = max(self.steps, key=lambda c: c.overshoot_percent)
        return {"settling_ms": slow.settling_ms, "settling_case": slow.name,
                "overshoot_percent": over.overshoot_percent, "overshoot_case": over.name}


def step_case(factory: StageFactory, controller, seed: int, axis: int, sign: int, hold_s: float,
              step_um: float = PAPER_STEP_UM, protocol: LoopProtocol = LOOP_PROTOCOL, index: int = 0) -> StepCase:
    """The ``sign`` x ``step_um`` step on ``axis`` after ``hold_s`` at the origin (``protocol`` with that hold).

    A fresh stage (stream ``stream_seed(seed, "bandwidth.step", index)``) and the controller
    started by the protocol; the record holds ``STEP_LEAD_S`` at the origin, then the step for
    ``STEP_RECORD_S``.
    """
    if axis not in (0, 1, 2) or sign not in (-1, 1):
        raise ValueError(f"axis, sign: expected 0-2 and +-1, got {axis!r}, {sign!r}")
    k0 = int(round(STEP_LEAD_S * FS))
    ref = np.zeros((k0 + int(round(STEP_RECORD_S * FS)), 3))
    ref[k0:, axis] = sign * step_um
    st = factory(stream_seed(seed, "bandwidth.step", index))
    tr = run_closed_loop(st, controller, ref, protocol=protocol.with_hold(hold_s))
    t = tr.t_s[k0:] - tr.t_s[k0]
    base = float(tr.y_um[:k0, axis].mean())
    y = sign * (tr.y_um[k0:, axis] - base)
    rise, peak, settle, over = step_metrics(t, y, step_um)
    return StepCase(axis=axis, sign=sign, hold_s=float(hold_s), trace=tr, baseline_um=base, rise_ms=rise,
                    peak_ms=peak, settling_ms=settle, overshoot_percent=over)


def bandwidth(factory: StageFactory, controller, seed=0, duration_s=PRBS_DURATION_S, amplitude_um=PRBS_AMPLITUDE_UM,
              step_um=PAPER_STEP_UM, holds_s=STEP_HOLDS_S, axes=(0, 1),
              protocol: LoopProtocol = LOOP_PROTOCOL) -> BandwidthResult:
    """sigma(S), sigma(T) from three uncorrelated PRBS references (MIMO H1), and the 2 um steps.

    The PRBS amplitude (2 um) drives the piezos with about the same swing as the
    identification experiment: the hysteretic actuator's gain depends on amplitude.
    Every run (the PRBS record and each step case) starts from ``protocol``'s
    state on a fresh stage; the steps are +-``step_um`` on each of ``axes`` after
    each hold of ``holds_s`` (:func:`step_case`). The headline fields
    (``rise_ms`` ... ``overshoot_percent``, ``step``) are :data:`HEADLINE_STEP`'s
    case, or the first case when that one is not among them.
    """
    ref = prbs_references(int(duration_s * FS), amplitude_um, stream_seed(seed, "bandwidth.reference"))
    cl = run_closed_loop(factory(stream_seed(seed, "bandwidth", 0)), controller, ref, protocol=protocol)
    fb, T = h1_in_band(ref, cl.y_um)
    lvl = 1 / np.sqrt(2)
    sT = sigma_in_band(T)
    sE = sigma_in_band(np.eye(3)[None] - T)
    bE = crossing_hz(fb, sE, lvl, rising=True)
    config = getattr(controller, "config", None)        # None: a controller object without matrices
    if config is not None and config.n_in > config.n_error:
        sS = indirect_sensitivity_sigma(T, h1_in_band(ref, cl.u_V)[1], config, fb)
        method = SENSITIVITY_INDIRECT
    else:
        sS, method = sE, (SENSITIVITY_ONE_DOF if config is not None else SENSITIVITY_OBJECT)
    bS = crossing_hz(fb, sS, lvl, rising=True)
    bT = crossing_hz(fb, sT, lvl, rising=False)
    plan = [(axis, sign, hold) for hold in holds_s for axis in axes for sign in (1, -1)]
    cases = tuple(step_case(factory, controller, seed, axis, sign, hold, step_um=step_um, protocol=protocol, index=i)
                  for i, (axis, sign, hold) in enumerate(plan))
    head = next((c for c in cases if (c.axis, c.sign, c.hold_s) == HEADLINE_STEP), cases[0])
    return BandwidthResult(freq_hz=fb, sigma_S=sS, sigma_T=sT, bandwidth_S_hz=bS, bandwidth_T_hz=bT, step=head.trace,
                           rise_ms=head.rise_ms, peak_ms=head.peak_ms, settling_ms=head.settling_ms,
                           overshoot_percent=head.overshoot_percent, steps=cases, protocol=protocol,
                           bandwidth_reference_error_hz=bE, sensitivity_method=method)


def prbs_references(n: int, amplitude_um: float, seed) -> np.ndarray:
    """Three uncorrelated PRBS of ``amplitude_um`` [um], shape (n, 3), clocked at :data:`PRBS_CLOCK_HZ`."""
    return ident.prbs_channels(n, PRBS_CLOCK_HZ, fs=FS, n_channels=3, amplitude=amplitude_um, seed=seed)


def h1_in_band(inputs, outputs) -> tuple[np.ndarray, np.ndarray]:
    """MIMO H1 estimate of ``outputs`` per ``inputs`` on :data:`PRBS_BAND_HZ`: ``(f_hz, H)``, H shape (F, ny, nu)."""
    est = ident.h1_estimate(inputs, outputs, fs=FS, nperseg=2048)
    band = (est.freq_hz >= PRBS_BAND_HZ[0]) & (est.freq_hz <= PRBS_BAND_HZ[1])
    return est.freq_hz[band], est.H[band]


def sigma_in_band(H) -> np.ndarray:
    """Largest singular value of each ``H[k]``, shape (F,)."""
    return np.linalg.svd(H, compute_uv=False)[:, 0]


def controller_response(config, f_hz) -> tuple[np.ndarray, np.ndarray]:
    """``(K_e, K_y)`` of ``u = K_e e + K_y y`` on ``f_hz`` [controller V / sensor V], shapes (F, nu, n_error) and
    (F, nu, n_in - n_error) (empty for one degree of freedom).
    """
    z = np.exp(2j * np.pi * np.asarray(f_hz, float) * config.dt)
    n = len(config.Akd)
    Kz = np.stack([config.Ckd @ np.linalg.solve(zz * np.eye(n) - config.Akd, config.Bkd) + config.Dkd for zz in z])
    return Kz[:, :, :config.n_error], Kz[:, :, config.n_error:]


def indirect_sensitivity_sigma(T_yr, T_ur, config, f_hz) -> np.ndarray:
    """``sigma_max((I + G K_fb)^-1)`` on ``f_hz`` from the closed-loop responses to the reference.

    The indirect closed-loop method (:data:`SENSITIVITY_INDIRECT`): no record beyond the reference one, but
    it needs the controller's matrices; :func:`nanosim.pipeline.compare.reading_disturbance_sensitivity`
    measures the same ``S`` directly, for any controller, with a record of its own.

    Parameters
    ----------
    T_yr : ndarray, shape (F, ny, ny)
        Reference to reading [um / um].
    T_ur : ndarray, shape (F, nu, ny)
        Reference to command [controller V / um].
    config : ControllerConfig
        The controller that ran (``K_fb = K_e - K_y``).
    f_hz : ndarray, shape (F,)

    Returns
    -------
    ndarray, shape (F,)
        ``G = T_yr T_ur^-1`` (the plant as the loop runs it, converted to sensor V per controller V)
        closed with ``K_fb``.
    """
    Ke, Ky = controller_response(config, f_hz)
    K_fb = Ke - Ky if Ky.shape[2] else Ke
    G_V = np.linalg.solve(np.swapaxes(T_ur, 1, 2), np.swapaxes(T_yr, 1, 2)).swapaxes(1, 2) / UM_PER_V
    ny = G_V.shape[1]
    S = np.linalg.inv(np.eye(ny)[None] + G_V @ K_fb)
    return sigma_in_band(S)


def predicted_loop(controller: DiscreteController, base, f_hz=None):
    """sigma(S), sigma(T) of the discrete loop with the linear twin (piezo small-signal gain included):
    ``S`` the feedback loop's output sensitivity, ``T`` the reference-to-reading map.
    """
    tw = linearize(base, include_piezo=True)
    G = tw.sysd_V
    c = controller.config
    f = np.logspace(0, 3, 400) if f_hz is None else f_hz
    z = np.exp(2j * np.pi * f * c.dt)
    sS, sT = [], []
    Kes, Kys = controller_response(c, f)
    for zz, Ke, Ky in zip(z, Kes, Kys):
        Gz = G(zz)
        K_fb = Ke - Ky if Ky.size else Ke                     # u = Ke e + Ky y (Ky empty for 1-DOF)
        T = np.linalg.solve(np.eye(3) + Gz @ K_fb, Gz @ Ke)   # r -> y
        S = np.eye(3) - T if not Ky.size else np.linalg.inv(np.eye(3) + Gz @ K_fb)
        sS.append(np.linalg.svd(S, compute_uv=False)[0])
        sT.append(np.linalg.svd(T, compute_uv=False)[0])
    return f, np.array(sS), np.array(sT)


def _metrics(r: BandwidthResult) -> dict:
    axis, sign, hold = HEADLINE_STEP
    return {"bandwidth_S_hz": r.bandwidth_S_hz, "bandwidth_T_hz": r.bandwidth_T_hz,
            "bandwidth_reference_error_hz": r.bandwidth_reference_error_hz,
            "sensitivity_method": r.sensitivity_method.describe(), "sensitivity_formula": r.sensitivity_method.formula,
            "step_2um": {"rise_ms": r.rise_ms, "peak_ms": r.peak_ms, "settling_ms": r.settling_ms,
                         "overshoot_percent": r.overshoot_percent,
                         "case": f"{'+' if sign > 0 else '-'}{'XYZ'[axis]} after {hold:g} s"},
            "step_2um_cases": [c.metrics() for c in r.steps], "step_2um_worst": r.worst_step,
            "loop_protocol": r.protocol.describe()}


register(Experiment("bandwidth", run=lambda ctx: bandwidth(ctx.factory, ctx.controller, seed=ctx.seed),
                    metrics=_metrics,
                    figure=lambda r, ctx: fig_bandwidth(r, predicted=predicted_loop(ctx.controller,
                                                                                    ctx.base_stage)),
                    figure_name=FIG18_BANDWIDTH_STEP, order=50, cost=4))
