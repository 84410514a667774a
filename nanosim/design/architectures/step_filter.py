"""Step filter: a second-order reference filter that settles the paper's step on the piezo it will drive.

A feedback loop designed on the identified model predicts a step that the stage does not make:
the model is linear at the identification's excursion (the PRBS, 20 V peak-to-peak at the piezo),
while a 2 um step moves the piezo a few volts on a hysteresis branch, and the piezo then creeps.
Both are properties of the actuator, stated in :class:`nanosim.plant.piezo.PiezoConfig` (the paper's
Fig. 14 loop and Fig. 15 creep), and both shape the step's last per cent:

* **gain** -- by the Masing property a branch after a reversal starts at the tangent gain ``w0``
  and ends, after an excursion ``d``, on the slope ``w0 + sum_(2 r_i < d) w_i``
  (:meth:`~nanosim.plant.piezo.PiezoConfig.branch_slope`); relative to the identification's secant
  gain (:meth:`~nanosim.plant.piezo.PiezoConfig.small_signal_gain` at its excursion) the step sees a
  gain between those two;
* **creep** -- after a step of ``d`` the piezo extends by ``gamma(d)`` of the step per decade of time
  (:meth:`~nanosim.plant.piezo.PiezoConfig.creep_rate_per_decade`) from its onset
  (:data:`nanosim.constants.CREEP_TAU_MIN_S`, 1 ms): the Kelvin-Voigt chain
  ``P_c(s) = 1 + sum_k (gamma / n) / (1 + s tau_k)`` with ``n`` = :data:`CREEP_ELEMENTS_PER_DECADE`
  elements per decade, ``tau_k`` from 1 ms to :data:`CREEP_SPAN_S`, has that logarithmic step response.

The step model is ``G_step(s) = g G(s) P_c(s)`` for each ``g`` of the gain band
(:func:`piezo_step_model`). The filter

    F(s) = (s^2 / wz^2 + 2 zeta_z s / wz + 1) / (s^2 / wp^2 + 2 zeta_p s / wp + 1)   (unit static gain)

is the one, of the second-order filters in :data:`SEARCH_BOUNDS`, that minimizes the worst
settling time of the paper's step into the paper's 2 % band (:data:`nanosim.paper.PAPER_SETTLING_BAND`),
over the group's axes and every ``g`` of the band, plus :data:`SETTLING_SPREAD_WEIGHT` times their sum
(so the search also improves the cases that do not set the worst), with an overshoot of at most
:data:`OVERSHOOT_BAND_FRACTION` of the band (a penalty: an excess of the whole band costs the record's
length); the other half of the band is left for what the step model does not hold. Nelder-Mead from
:data:`SEARCH_STARTS`, Tustin at the control period. X and Y share
one filter (:data:`AXIS_GROUPS`), so their ramp lags stay equal
(:func:`nanosim.design.architectures.prefilter.equalize_reference_lag`) and a straight path in the
scan plane stays straight; Z has its own. The feedback loop, and so its margins, mu and noise, is unchanged.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nanosim import constants as C
from nanosim.design.architectures.common import DT_S, IDENTIFIED_DELAY_SAMPLES, dc_gain_z
from nanosim.paper import PAPER_PRBS_AMPLITUDE_V, PAPER_SETTLING_BAND, PAPER_STEP_UM

__all__ = ["PiezoStepModel", "piezo_step_model", "step_filter_coefficients", "settling_time_s",
           "design_step_filter", "CREEP_ELEMENTS_PER_DECADE", "CREEP_SPAN_S", "SEARCH_BOUNDS", "SEARCH_STARTS",
           "SETTLING_SPREAD_WEIGHT", "STEP_RECORD_S", "AXIS_GROUPS",
           "OVERSHOOT_BAND_FRACTION"]

# Kelvin-Voigt elements per decade of the creep chain (a log-uniform set of time constants; the step
# response of n equal elements per decade rises by n c per decade)
CREEP_ELEMENTS_PER_DECADE = 2
# the chain's longest time constant [s]: longer ones are constant over a step's settling
CREEP_SPAN_S = 1.0
# the search's box: (fz, zeta_z, fp, zeta_p) [Hz, -, Hz, -]; corners below the Nyquist frequency's fifth
SEARCH_BOUNDS = ((5.0, 400.0), (0.2, 3.0), (5.0, 400.0), (0.2, 3.0))
# Nelder-Mead starts (fz, zeta_z, fp, zeta_p): about the loop's crossover, mild lead and lag
SEARCH_STARTS = ((60.0, 0.4, 60.0, 0.8), (40.0, 0.5, 80.0, 0.7), (30.0, 0.7, 45.0, 0.7),
                 (80.0, 0.5, 100.0, 0.7), (90.0, 0.5, 90.0, 0.65), (120.0, 0.5, 170.0, 0.7))
SEARCH_MAXITER = 400
# weight of the sum of the cases' settling times next to the worst
SETTLING_SPREAD_WEIGHT = 0.01
# the predicted step's record [s]
STEP_RECORD_S = 0.06
# the largest overshoot the search accepts on the step model, a fraction of the paper's band: the other half of
# the band is left for what the step model does not hold (the creep of the move before the step, the branch's
# curvature between its tangent and end slopes)
OVERSHOOT_BAND_FRACTION = 0.5
# axes sharing one filter: X and Y (the scan plane, where equal lags keep a path straight), then Z
AXIS_GROUPS = ((0, 1), (2,))


@dataclass(frozen=True)
class PiezoStepModel:
    """The piezo as the paper's step drives it, relative to the identified model (module docstring).

    Attributes
    ----------
    step_piezo_V : float
        The step's excursion at the piezo [V].
    gains : tuple of float
        The gain band relative to the identified model: tangent, midpoint, end slope [-].
    creep_per_decade : float
        Creep after a step of ``step_piezo_V``, fraction of the step per decade of time [-].
    creep_tau_s : tuple of float
        The Kelvin-Voigt chain's time constants [s].
    """

    step_piezo_V: float
    gains: tuple
    creep_per_decade: float
    creep_tau_s: tuple

    def creep_filter(self, dt: float = DT_S):
        """``P_c`` of the module docstring, Tustin at ``dt`` (SISO state space)."""
        import control as ct
        c = self.creep_per_decade / CREEP_ELEMENTS_PER_DECADE
        tau = np.asarray(self.creep_tau_s, float)
        if tau.size == 0:
            return ct.ss([], [], [], [[1.0]], dt)
        # parallel first-order elements as states (a diagonal A stays well conditioned over the decades)
        P = ct.ss(np.diag(-1.0 / tau), (1.0 / tau).reshape(-1, 1), np.full((1, tau.size), c), [[1.0]])
        return ct.ss(ct.c2d(P, dt, "tustin"))

    def to_dict(self) -> dict:
        """JSON-ready fields with their sources."""
        return {"step_piezo_V": self.step_piezo_V, "gains": list(self.gains),
                "creep_per_decade": self.creep_per_decade, "creep_tau_s": list(self.creep_tau_s),
                "gain_source": "PiezoConfig: tangent w0 and branch_slope at the step's excursion, over "
                               "small_signal_gain at the identification's excursion",
                "creep_source": "PiezoConfig.creep_rate_per_decade at the step's excursion, from "
                                f"CREEP_TAU_MIN_S ({C.CREEP_TAU_MIN_S:g} s), {CREEP_ELEMENTS_PER_DECADE} "
                                "Kelvin-Voigt elements per decade"}


def piezo_step_model(G, piezo=None, *, step_um: float = PAPER_STEP_UM,
                     identification_amplitude_V: float = PAPER_PRBS_AMPLITUDE_V) -> PiezoStepModel:
    """The gain band and creep of the piezo in a step of ``step_um`` on the identified ``G``.

    Parameters
    ----------
    G : control.StateSpace
        Identified model [sensor V / controller V], discrete or continuous, square.
    piezo : PiezoConfig or None
        The actuator (default: ``PiezoConfig()``, the stage's).
    step_um : float
        The step on one axis [um]; its excursion at the piezo is the largest actuator command of a
        step on any axis through the static gain, times :data:`nanosim.constants.AMPLIFIER_GAIN`.
    identification_amplitude_V : float
        The identification excitation's largest command [controller V] (peak-to-peak excursion twice
        that, times the amplifier gain).

    Returns
    -------
    PiezoStepModel

    Examples
    --------
    >>> import control as ct
    >>> G = ct.ss([], [], [], 0.25 * np.eye(3), 2.5e-4)      # 0.25 sensor V (1.25 um) per controller V
    >>> m = piezo_step_model(G)
    >>> round(m.step_piezo_V, 1), m.gains[0] < 1.0
    (32.0, True)
    """
    from nanosim.plant.piezo import PiezoConfig
    p = PiezoConfig() if piezo is None else piezo
    if not (math.isfinite(step_um) and step_um > 0):
        raise ValueError(f"step_um: expected a step > 0 [um], got {step_um!r}")
    if not (math.isfinite(identification_amplitude_V) and identification_amplitude_V > 0):
        raise ValueError(f"identification_amplitude_V: expected a command > 0 [V], got {identification_amplitude_V!r}")
    G0 = dc_gain_z(G)
    if G0.shape[0] != G0.shape[1]:
        raise ValueError(f"G: expected a square model, got {G0.shape[0]} x {G0.shape[1]}")
    u = np.linalg.solve(G0, np.eye(G0.shape[0]) * step_um / C.SENSOR_UM_PER_V)    # commands of a step per axis
    d = float(np.max(np.abs(u))) * C.AMPLIFIER_GAIN
    ident = p.small_signal_gain(2.0 * identification_amplitude_V * C.AMPLIFIER_GAIN)
    lo, hi = p.small_signal_gain(0.0) / ident, p.branch_slope(d) / ident
    gamma = p.creep_rate_per_decade(d) if (p.creep and p.hysteresis and p.thermal) else 0.0
    n = int(round(math.log10(CREEP_SPAN_S / C.CREEP_TAU_MIN_S) * CREEP_ELEMENTS_PER_DECADE))
    taus = tuple(float(C.CREEP_TAU_MIN_S * 10 ** (k / CREEP_ELEMENTS_PER_DECADE)) for k in range(n + 1))
    return PiezoStepModel(step_piezo_V=d, gains=(float(lo), float(0.5 * (lo + hi)), float(hi)),
                          creep_per_decade=float(gamma), creep_tau_s=taus if gamma > 0 else ())


def step_filter_coefficients(fz_hz: float, zeta_z: float, fp_hz: float, zeta_p: float, dt: float = DT_S):
    """``(b, a)`` of the module docstring's ``F``, Tustin at ``dt`` (no prewarp; unit static gain)."""
    from scipy.signal import bilinear
    wz, wp = 2 * math.pi * fz_hz, 2 * math.pi * fp_hz
    return bilinear([1 / wz ** 2, 2 * zeta_z / wz, 1.0], [1 / wp ** 2, 2 * zeta_p / wp, 1.0], fs=1.0 / dt)


def settling_time_s(y, dt: float, band: float = PAPER_SETTLING_BAND) -> float:
    """First time [s] after which the unit step response ``y`` (samples at ``k dt``) stays within ``band``
    of 1; ``len(y) dt`` if it ends outside.

    >>> settling_time_s(np.array([0.0, 0.5, 0.99, 1.01, 1.0]), 1.0)
    2.0
    """
    y = np.asarray(y, float)
    out = np.flatnonzero(np.abs(y - 1.0) > band)
    return 0.0 if out.size == 0 else float((out[-1] + 1) * dt)


def _step_set(G, Ke, Ky, model: PiezoStepModel, delay_samples: int, n_samples: int):
    """Unit step responses of ``T_ry``'s diagonal for every gain of the band, rows ``(gain, axis)``."""
    import control as ct

    from nanosim.design.loopresponse import loop_transfer_ss
    dt = float(G.dt)
    Gp = G
    if model.creep_tau_s:
        P = model.creep_filter(dt)
        Gp = ct.ss(ct.series(ct.append(*[P] * G.ninputs), G))
    out = []
    for g in model.gains:
        T = loop_transfer_ss(Gp * g, Ke, Ky, delay_samples).T_ry
        for j in range(T.ninputs):
            _, y = ct.step_response(T, T=np.arange(n_samples) * dt, input=j, output=j)
            out.append(np.asarray(np.squeeze(y), float))
    return np.array(out)


def design_step_filter(G, K, n_error: int, *, model: PiezoStepModel | None = None,
                       delay_samples: int = IDENTIFIED_DELAY_SAMPLES, dt: float = DT_S, groups=AXIS_GROUPS):
    """``(K2, parameters)``: ``K`` (inputs ``[e]`` or ``[e; y]``) with the step filter of the module docstring.

    Parameters
    ----------
    G : control.StateSpace
        Identified discrete model at ``dt``.
    K : control.StateSpace
        Discrete controller; any reference prefilter already in it counts.
    n_error : int
        Number of error (reference) channels.
    model : PiezoStepModel or None
        Default :func:`piezo_step_model` of ``G``.
    groups : tuple of tuple of int
        Axes that share one filter (default :data:`AXIS_GROUPS`: X and Y, the scan plane, then Z).

    Returns
    -------
    K2 : control.StateSpace
        Inputs ``[e; y]``.
    parameters : dict
        JSON-ready: the filters, the step model, the predicted settling times [ms] before and after.
    """
    import control as ct
    from scipy.optimize import minimize
    from scipy.signal import lfilter

    from nanosim.design.architectures.common import split_2dof
    from nanosim.design.architectures.prefilter import with_reference_prefilter
    axes = sorted(a for g in groups for a in g)
    if axes != list(range(n_error)):
        raise ValueError(f"groups: expected every axis 0..{n_error - 1} once, got {groups!r}")
    m = piezo_step_model(G) if model is None else model
    n = int(round(STEP_RECORD_S / dt))
    Y = _step_set(G, *split_2dof(K, n_error), m, delay_samples, n).reshape(len(m.gains), n_error, n)

    def settle(ys):
        return np.array([settling_time_s(y, dt) for y in ys])

    overshoot_limit = OVERSHOOT_BAND_FRACTION * PAPER_SETTLING_BAND
    filters, per_axis = [], [None] * n_error
    for group in groups:
        Yg = Y[:, list(group)].reshape(-1, n)

        def cost(p):
            if any(not lo <= v <= hi for v, (lo, hi) in zip(p, SEARCH_BOUNDS)):
                return 1e3
            b, a = step_filter_coefficients(*p, dt=dt)
            yf = lfilter(b, a, Yg, axis=1)
            t = settle(yf)
            excess = max(float(yf.max()) - 1.0 - overshoot_limit, 0.0)
            return float(t.max() + SETTLING_SPREAD_WEIGHT * t.sum() + excess / PAPER_SETTLING_BAND * STEP_RECORD_S)

        best = None
        for x0 in SEARCH_STARTS:
            r = minimize(cost, np.array(x0), method="Nelder-Mead",
                         options={"maxiter": SEARCH_MAXITER, "xatol": 0.01, "fatol": 1e-4})
            if best is None or r.fun < best.fun:
                best = r
        p = [float(v) for v in best.x]
        b, a = step_filter_coefficients(*p, dt=dt)
        for j in group:
            per_axis[j] = ct.ss(ct.tf(b, a, dt))
        yf = lfilter(b, a, Yg, axis=1)
        rows = (len(m.gains), -1)
        filters.append({"axes": ["XYZ"[j] for j in group], "fz_hz": p[0], "zeta_z": p[1], "fp_hz": p[2],
                        "zeta_p": p[3],
                        "predicted_settling_ms_before": (1e3 * settle(Yg)).reshape(rows).tolist(),
                        "predicted_settling_ms": (1e3 * settle(yf)).reshape(rows).tolist(),
                        "predicted_overshoot_percent": (100 * (yf.max(axis=1) - 1.0)).reshape(rows).tolist()})
    F = ct.ss(ct.append(*per_axis))                                   # diagonal: each axis its group's filter
    K2 = with_reference_prefilter(K, F, n_error)
    params = {"rule": "per group of axes, the second-order reference filter (unit static gain) minimizing the "
                      f"worst {100 * PAPER_SETTLING_BAND:g} % settling time of a {PAPER_STEP_UM:g} um step on the "
                      f"group's axes, overshoot at most {100 * overshoot_limit:g} %, over the piezo's gain band, with "
                      "its creep, on the identified model",
              "form": "F(s) = (s^2/wz^2 + 2 zeta_z s/wz + 1) / (s^2/wp^2 + 2 zeta_p s/wp + 1), Tustin",
              "filters": filters, "piezo_step_model": m.to_dict(),
              "overshoot_limit_percent": 100 * overshoot_limit,
              "predicted_settling_ms_worst": max(float(np.max(f["predicted_settling_ms"])) for f in filters),
              "predicted_settling_rows": "gains (tangent, midpoint, end slope) x the group's axes",
              "prefilter_states": int(F.nstates)}
    return K2, params
