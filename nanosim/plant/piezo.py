"""Piezo-actuator electromechanics: rate-independent hysteresis and linear creep.

The model maps the amplifier output ``v_piezo_V`` (piezo volts) of each actuator
channel to a *free-strain voltage* ``v_free_V``: the voltage a linear,
creep-free piezo would need to produce the same free strain. The mechanics
turns it into the tendon force ``F = PIEZO_FORCE_PER_PIEZO_V * v_free_V``.
With hysteresis and creep switched off, ``v_free_V == v_piezo_V`` exactly.

Hysteresis -- Prandtl-Ishlinskii (PI) operator
    ``h(t) = w0 * v(t) + sum_i w_i * z_i(t)``,  with play operators
    ``z_i(t) = max(v(t) - r_i, min(v(t) + r_i, z_i(t-))``, thresholds
    ``r_i > 0`` and weights ``w_i >= 0`` (Brokate & Sprekels, *Hysteresis and
    Phase Transitions*, Springer 1996, Sec. 2.3; Kuhnen, "Modeling,
    identification and compensation of complex hysteretic nonlinearities: a
    modified Prandtl-Ishlinskii approach", Eur. J. Control 9(4), 2003;
    Al Janaideh, Rakheja & Su, "A generalized Prandtl-Ishlinskii model for
    characterizing the hysteresis and saturation nonlinearities of smart
    actuators", Smart Mater. Struct. 18, 045001, 2009). The model is
    rate-independent by construction, starts from the virgin state
    ``z_i = 0`` at 0 V, and its ascending branch is convex ("concave up")
    as in piezo loops.

    Default weights: a discretised density ``w(r) ~ exp(-r / 20 V)`` on 12
    thresholds (1 ... 64 V, weight = density x threshold spacing). A nearly
    uniform density reproduces the Rayleigh law of piezoceramics at low and
    moderate fields (hysteresis grows with amplitude, small loops are nearly
    linear; Damjanovic, Rep. Prog. Phys. 61, 1267, 1998); the exponential
    roll-off keeps the full-stroke loop at ~10 %. One scale was fitted so that
    the virgin 0 -> 33 -> 0 piezo-V loop (0 -> 1.65 -> 0 controller V, paper
    Fig. 14) has ~14.4 % output and ~14.6 % input hysteresis (paper: 15 % and
    14 %), then all weights were normalised so that the *major-loop secant*
    ``h(33 V) / 33 V`` on the virgin curve is exactly 1
    (``PiezoConfig.normalize_loop_slope``).

    Consequences (documented for the identification): the small-signal gain
    after any reversal is ``w0 = 0.752`` for minor loops below 2 V
    peak-to-peak (smallest threshold 1 V: such loops are exactly linear),
    rising to 0.85 for a 10 V step from rest. See
    :meth:`PiezoConfig.small_signal_gain` and :meth:`PiezoConfig.loop_slope`.
    Literature check (no parameter fitted to it): in the Rayleigh regime of
    PZT, ``d(E0) = d_init + alpha E0``, a loop of amplitude ``E0`` has a
    relative width ``w = alpha E0 / (2 (d_init + alpha E0))`` and the slope
    right after a reversal is ``d_init``, so reversal gain / secant
    ``= 1 - 2 w`` (Damjanovic 1998): 0.70 for the paper's 15 % loop, 0.80
    for a 10 % loop; PI quotes 10-15 % for large-signal loops and ~2 % for
    small-signal ones (piceramic.com piezo tutorial). ``w0 = 0.752`` lies
    inside that 0.65-0.85 band.

Creep -- logarithmic law, realized by series Kelvin-Voigt elements
    Published creep of stack (and amplified) piezo actuators after a step is
    logarithmic in time: ``x(t) = x(t0) (1 + gamma log10(t / t0))`` with
    ``gamma`` "on the order of 0.01 to 0.02, which is 1 % to 2 % per time
    decade" (PI, *Piezo Tutorial*, Cat. 118 p. 4-18, and
    physikinstrumente.com/tutorial/4_21.html, t0 = 0.1 s; Jung & Gweon,
    "Creep characteristics of piezoelectric actuators", Rev. Sci. Instrum. 71,
    1896, 2000). The law has no time constant of its own; it is realized here
    as a spring in series with Kelvin-Voigt spring-dashpot elements (Croft,
    Shed & Devasia, J. Dyn. Sys. Meas. Control 123(1), 35-43, 2001)::

        v_free = s * (h + sum_k c_k x_k),   tau_k dx_k/dt = h - x_k,
        V_free(s) = s0 (1 + sum_k c_k / (tau_k s + 1)) H(s)

    with ``tau_k`` log-spaced from ``tau_min`` to ``tau_max`` at
    ``n`` stages per decade and equal weights ``c_k = gamma / n``
    (:func:`log_creep_stages`). For ``tau_min << t << tau_max`` the step
    response of the sum is ``sum_k c_k (1 - exp(-t / tau_k))
    ~ gamma log10(t / tau_min) + const``: slope ``gamma`` per decade (with
    n = 2 the slope ripples by < 1 % between 10 tau_min and tau_max / 10).
    Defaults (``nanosim.constants``): gamma = 0.02 per decade (top of PI's
    range; the creep doublet in every column of the paper's identified model,
    zero 8-11 % above the pole, points to the upper end), tau from 1 ms to
    100 s, two stages per decade (11 stages). With ``normalize_creep_dc`` the
    DC gain of the creep filter is 1 and the instantaneous gain
    ``1 / (1 + sum c_k) = 0.90``, so the quasi-static (datasheet) stroke is
    unchanged. Discretisation is exact for a zero-order-held input:
    ``x[n+1] = a x[n] + (1 - a) h[n]``, ``a = exp(-dt / tau)``.

    Stage v1's creep (:meth:`PiezoConfig.calibrated_v1`: 10 % at 1/29 s to
    place the paper's identified 29 rad/s pole, 1 % at 1 s and 10 s) had no
    source; identified through the paper's excitation, neither v1 nor v2
    creep returns that pole (``nanosim.pipeline.predictions``).

Why the paper's controller rings on this piezo (issue 12), in these equations
    The paper's design inverts the plant: its zeros sit on the 176/178 Hz
    poles, so the closed loop leaves those modes at their open-loop damping
    (zeta ~ 0.003). (1) An approach to the working point (~48 V) leaves every
    operator with ``r_i`` below the excursion on its edge, ``z_i = v - r_i``.
    (2) Creep keeps the stage moving, ``~ gamma dx log10(t)``, and the loop
    holds position by retracting the command by ``delta`` (~0.5 V after
    0.5 s): a reversal, after which all ``z_i`` hold. (3) A following step
    that drives the actuator up again has the gain ``w0 = 0.75`` until ``v``
    passes the old turning point, where every held operator re-engages at
    once (return-point memory: ``z_i = v - r_i`` again) and the gain jumps
    to ``w0 + sum w_i = 1.24``: a kink in the force rate in mid-step, which
    excites the undamped modes. Without creep there is no retraction and the
    step starts at its turning point (no mid-step kink); without hysteresis
    the gain is constant. Either alone settles in ~9 ms; a 0.1 um
    retraction imposed through the reference on a creep-free piezo rings
    just as creep does (``nanosim.pipeline.ablation`` docstring).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.signal import lfilter

from nanosim import constants as C
from nanosim.plant.loopmetrics import loop_hysteresis_percent
from nanosim.validation import as_finite_array

__all__ = [
    "log_creep_stages",
    "PiezoConfig",
    "PrandtlIshlinskii",
    "KelvinVoigtCreep",
    "PiezoModel",
    "loop_hysteresis_percent",
]

# Paper Fig. 14: 0 -> 1.65 controller V = 0 -> 33 piezo V.
DEFAULT_LOOP_PEAK_PIEZO_V = 33.0

# Operator thresholds: a realisation choice [E] (no source gives a PI operator set for the APA35XS):
# 12 roughly geometric steps from 1 V to 64 V, the range of reversal amplitudes the experiments
# produce (0.05 V ripple to the 33 V loop of Fig. 14). Weights: an exp(-r / 20 V) density whose
# scale is calibrated (least squares, no bound) to Fig. 14's 15 % output / 14 % input loop at
# 0-33 V; the linear weight w0 = 0.752 sits in the Rayleigh-law band 0.65-0.85 (mjcf/SOURCES.md item 3).
_DEFAULT_THRESHOLDS_V = (1.0, 2.0, 3.5, 5.5, 8.0, 11.0, 15.0, 20.0, 27.0, 36.0, 48.0, 64.0)
_DEFAULT_WEIGHTS = (0.02386, 0.02837, 0.03684, 0.04286, 0.04623, 0.05065,
                    0.05331, 0.05536, 0.05201, 0.04353, 0.03185, 0.01942)
_DEFAULT_LINEAR_WEIGHT = 0.7524

# Run the PI recursion over blocks of this many samples (bounds the
# (block, channels, operators) work arrays to a few MB).
_RUN_BLOCK = 8192


def log_creep_stages(per_decade: float = C.CREEP_PER_DECADE, tau_min_s: float = C.CREEP_TAU_MIN_S,
                     tau_max_s: float = C.CREEP_TAU_MAX_S,
                     stages_per_decade: int = C.CREEP_STAGES_PER_DECADE) -> tuple[tuple, tuple]:
    """Kelvin-Voigt stages realizing logarithmic creep ``gamma`` per decade.

    Parameters
    ----------
    per_decade : float
        Creep ``gamma`` per time decade, as a fraction of the instantaneous
        response (PI: 0.01-0.02), >= 0.
    tau_min_s, tau_max_s : float
        Shortest and longest time constants, seconds (``0 < tau_min < tau_max``).
    stages_per_decade : int
        Stages per decade of time constant (>= 1).

    Returns
    -------
    gains : tuple of float
        ``c_k = per_decade / stages_per_decade`` for every stage.
    time_constants_s : tuple of float
        ``tau_k = tau_min * 10**(k / stages_per_decade)`` up to ``tau_max``.

    Notes
    -----
    The step response ``sum_k c_k (1 - exp(-t / tau_k))`` has slope ``gamma``
    per decade of ``t`` for ``tau_min << t << tau_max`` (a log-uniform density
    of relaxation times); see the module docstring.
    """
    g = float(per_decade)
    lo, hi = float(tau_min_s), float(tau_max_s)
    if not np.isfinite(g) or g < 0:
        raise ValueError(f"per_decade: expected a finite value >= 0, got {per_decade}")
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
        raise ValueError(f"tau_min_s, tau_max_s: expected 0 < tau_min_s < tau_max_s, got {tau_min_s}, {tau_max_s}")
    if isinstance(stages_per_decade, bool) or int(stages_per_decade) != stages_per_decade or stages_per_decade < 1:
        raise ValueError(f"stages_per_decade: expected an integer >= 1, got {stages_per_decade}")
    n = int(stages_per_decade)
    k = np.arange(int(np.floor(n * np.log10(hi / lo) + 1e-9)) + 1)
    taus = lo * 10.0 ** (k / n)
    return tuple(float(g / n) for _ in taus), tuple(float(t) for t in taus)


_LOG_CREEP_GAINS, _LOG_CREEP_TAUS = log_creep_stages()
# Stage v1 (before issue 12): a 10 % stage placed at the identified 29 rad/s pole, plus 1 % at 1 s and 10 s.
_V1_CREEP_GAINS, _V1_CREEP_TAUS = (0.10, 0.01, 0.01), (1.0 / 29.0, 1.0, 10.0)


def _as_float_tuple(name: str, value) -> tuple[float, ...]:
    arr = as_finite_array(name, value, ndim=1)
    return tuple(float(x) for x in arr)


@dataclass(frozen=True)
class PiezoConfig:
    """Parameters of the piezo hysteresis and creep model (per channel, shared).

    Parameters
    ----------
    hysteresis : bool
        Apply the Prandtl-Ishlinskii hysteresis. Off: ``h = v_piezo``.
    pi_thresholds_V : tuple of float
        Play-operator thresholds ``r_i`` in piezo volts, strictly increasing, > 0.
    pi_weights : tuple of float
        Play-operator weights ``w_i`` (dimensionless, >= 0), same length.
    pi_linear_weight : float
        Weight ``w0`` of the linear (zero-threshold) term, > 0.
    normalize_loop_slope : bool
        Rescale ``w0`` and ``w_i`` so that the virgin-curve secant
        ``h(loop_peak_V) / loop_peak_V`` equals 1 (the defaults already
        satisfy it to 4 digits).
    loop_peak_V : float
        Peak piezo voltage of the normalisation loop (33 V = 1.65 controller V).
    creep : bool
        Apply the Kelvin-Voigt creep filter. Off: ``v_free = h``.
    creep_gains : tuple of float
        Creep stage gains ``c_k`` (>= 0), as fractions of the instantaneous
        response. Default: :func:`log_creep_stages` with the constants'
        ``CREEP_PER_DECADE`` (0.02), 1 ms ... 100 s, 2 stages per decade;
        :meth:`with_log_creep` builds other laws.
    creep_time_constants_s : tuple of float
        Creep stage time constants ``tau_k`` in seconds (> 0).
    normalize_creep_dc : bool
        Scale the creep filter by ``1 / (1 + sum c_k)`` so its DC gain is 1.
    """

    hysteresis: bool = True
    pi_thresholds_V: tuple = _DEFAULT_THRESHOLDS_V
    pi_weights: tuple = _DEFAULT_WEIGHTS
    pi_linear_weight: float = _DEFAULT_LINEAR_WEIGHT
    normalize_loop_slope: bool = True
    loop_peak_V: float = DEFAULT_LOOP_PEAK_PIEZO_V
    creep: bool = True
    creep_gains: tuple = _LOG_CREEP_GAINS
    creep_time_constants_s: tuple = _LOG_CREEP_TAUS
    normalize_creep_dc: bool = True

    def __post_init__(self):
        r = _as_float_tuple("pi_thresholds_V", self.pi_thresholds_V)
        w = _as_float_tuple("pi_weights", self.pi_weights)
        if len(r) != len(w):
            raise ValueError(f"pi_weights: expected {len(r)} weights (one per threshold), got {len(w)}")
        if len(r) and (min(r) <= 0 or any(b <= a for a, b in zip(r, r[1:]))):
            raise ValueError("pi_thresholds_V: expected strictly increasing values > 0")
        if any(x < 0 for x in w):
            raise ValueError("pi_weights: expected values >= 0")
        w0 = float(self.pi_linear_weight)
        if not np.isfinite(w0) or w0 <= 0:
            raise ValueError(f"pi_linear_weight: expected a finite value > 0, got {self.pi_linear_weight}")
        peak = float(self.loop_peak_V)
        if not np.isfinite(peak) or peak <= 0:
            raise ValueError(f"loop_peak_V: expected a finite value > 0, got {self.loop_peak_V}")
        c = _as_float_tuple("creep_gains", self.creep_gains)
        tau = _as_float_tuple("creep_time_constants_s", self.creep_time_constants_s)
        if len(c) != len(tau):
            raise ValueError(f"creep_time_constants_s: expected {len(c)} values (one per gain), got {len(tau)}")
        if any(x < 0 for x in c):
            raise ValueError("creep_gains: expected values >= 0")
        if any(x <= 0 for x in tau):
            raise ValueError("creep_time_constants_s: expected values > 0")
        object.__setattr__(self, "pi_thresholds_V", r)
        object.__setattr__(self, "pi_weights", w)
        object.__setattr__(self, "pi_linear_weight", w0)
        object.__setattr__(self, "loop_peak_V", peak)
        object.__setattr__(self, "creep_gains", c)
        object.__setattr__(self, "creep_time_constants_s", tau)

    @classmethod
    def linear(cls) -> "PiezoConfig":
        """Config with hysteresis and creep off (``v_free = v_piezo``)."""
        return cls(hysteresis=False, creep=False)

    @classmethod
    def with_log_creep(cls, per_decade: float = C.CREEP_PER_DECADE, tau_min_s: float = C.CREEP_TAU_MIN_S,
                       tau_max_s: float = C.CREEP_TAU_MAX_S, stages_per_decade: int = C.CREEP_STAGES_PER_DECADE,
                       **overrides) -> "PiezoConfig":
        """Config whose creep is the logarithmic law with these parameters (see :func:`log_creep_stages`)."""
        gains, taus = log_creep_stages(per_decade, tau_min_s, tau_max_s, stages_per_decade)
        return cls(creep_gains=gains, creep_time_constants_s=taus, **overrides)

    @classmethod
    def calibrated_v1(cls, **overrides) -> "PiezoConfig":
        """The stage-v1 creep (10 % at 1/29 s, 1 % at 1 s and 10 s), for comparisons and ablations."""
        return cls(creep_gains=_V1_CREEP_GAINS, creep_time_constants_s=_V1_CREEP_TAUS, **overrides)

    # -- derived quantities -------------------------------------------------
    def hysteresis_weights(self) -> tuple[float, np.ndarray]:
        """Effective ``(w0, w)`` after the optional loop-slope normalisation."""
        r = np.asarray(self.pi_thresholds_V, dtype=float)
        w = np.asarray(self.pi_weights, dtype=float)
        w0 = self.pi_linear_weight
        if self.normalize_loop_slope:
            peak = self.loop_peak_V
            scale = peak / (w0 * peak + float(np.maximum(peak - r, 0.0) @ w))
            w0, w = w0 * scale, w * scale
        return float(w0), w

    def loop_slope(self, peak_piezo_V: float = DEFAULT_LOOP_PEAK_PIEZO_V) -> float:
        """Secant ``h(peak) / peak`` of the virgin (initial loading) curve.

        This is the average slope of a slow ``0 -> peak -> 0`` loop started from
        rest (hysteresis only, creep excluded) and the DC gain seen by a step
        of ``peak`` volts from rest. Equals 1 at ``loop_peak_V`` when
        ``normalize_loop_slope``. Returns 1 if hysteresis is off.
        """
        peak = float(peak_piezo_V)
        if not np.isfinite(peak) or peak <= 0:
            raise ValueError(f"peak_piezo_V: expected a finite value > 0, got {peak_piezo_V}")
        if not self.hysteresis:
            return 1.0
        w0, w = self.hysteresis_weights()
        r = np.asarray(self.pi_thresholds_V)
        return float((w0 * peak + np.maximum(peak - r, 0.0) @ w) / peak)

    def small_signal_gain(self, amplitude_piezo_V: float = 0.0) -> float:
        """Secant gain of a minor loop of ``amplitude_piezo_V`` peak-to-peak.

        By the Masing property of the PI model the branch after a reversal is
        ``w0 * d + sum_i w_i * max(d - 2 r_i, 0)`` for an excursion ``d``, at any
        operating point. ``amplitude_piezo_V = 0`` gives the tangent gain ``w0``
        (exact for loops below ``2 * min(r_i)`` peak-to-peak). Hysteresis only;
        returns 1 if hysteresis is off.
        """
        a = float(amplitude_piezo_V)
        if not np.isfinite(a) or a < 0:
            raise ValueError(f"amplitude_piezo_V: expected a finite value >= 0, got {amplitude_piezo_V}")
        if not self.hysteresis:
            return 1.0
        w0, w = self.hysteresis_weights()
        if a == 0.0:
            return w0
        r = np.asarray(self.pi_thresholds_V)
        return float((w0 * a + np.maximum(a - 2.0 * r, 0.0) @ w) / a)

    def creep_dc_gain(self) -> float:
        """DC gain of the creep filter (1 if normalised or creep off)."""
        if not self.creep:
            return 1.0
        return 1.0 if self.normalize_creep_dc else 1.0 + float(sum(self.creep_gains))

    def creep_step_response(self, t_s) -> np.ndarray:
        """Creep-filter output at times ``t_s`` (s) after a unit step of ``h`` from rest (continuous time)."""
        t = as_finite_array("t_s", t_s)
        if not self.creep:
            return np.ones_like(t)
        c = np.asarray(self.creep_gains)
        tau = np.asarray(self.creep_time_constants_s)
        y = 1.0 + (c * (1.0 - np.exp(-np.maximum(t, 0.0)[..., None] / tau))).sum(-1)
        return y / (1.0 + c.sum()) if self.normalize_creep_dc else y

    def creep_instant_gain(self) -> float:
        """High-frequency (instantaneous) gain of the creep filter."""
        if not self.creep:
            return 1.0
        return 1.0 / (1.0 + float(sum(self.creep_gains))) if self.normalize_creep_dc else 1.0


class PrandtlIshlinskii:
    """Vectorised Prandtl-Ishlinskii hysteresis for several independent channels.

    Parameters
    ----------
    thresholds_V : sequence of float
        Play thresholds ``r_i`` (> 0), volts.
    weights : sequence of float
        Play weights ``w_i`` (>= 0).
    linear_weight : float
        Weight ``w0`` of the linear term.
    n_channels : int
        Number of independent channels.

    Notes
    -----
    State ``z`` has shape ``(n_channels, n_operators)``; ``reset`` puts it in the
    virgin state ``z = 0`` (demagnetised piezo at 0 V). ``run`` advances the
    state exactly as repeated ``step`` calls would (bit-identical outputs).
    """

    def __init__(self, thresholds_V: Sequence[float], weights: Sequence[float],
                 linear_weight: float = 0.0, n_channels: int = 3):
        r = as_finite_array("thresholds_V", thresholds_V, ndim=1)
        w = as_finite_array("weights", weights, shape=(r.size,))
        if np.any(r < 0):
            raise ValueError("thresholds_V: expected values >= 0")
        if not np.isfinite(linear_weight):
            raise ValueError("linear_weight: expected a finite value")
        if int(n_channels) < 1:
            raise ValueError(f"n_channels: expected >= 1, got {n_channels}")
        self.n_channels = int(n_channels)
        self._r = r.copy()
        self._w = w.copy()
        self._w0 = float(linear_weight)
        self._z = np.zeros((self.n_channels, r.size))

    @property
    def operator_state(self) -> np.ndarray:
        """Copy of the play-operator outputs, shape ``(n_channels, n_operators)``."""
        return self._z.copy()

    def reset(self) -> None:
        """Return to the virgin state (all play outputs 0)."""
        self._z[...] = 0.0

    def step(self, v_V) -> np.ndarray:
        """Advance one sample. ``v_V`` shape ``(n_channels,)``; returns ``h`` (same shape)."""
        v = as_finite_array("v_V", v_V, shape=(self.n_channels,))
        return self._step(v)

    def _step(self, v: np.ndarray) -> np.ndarray:
        vc = v[:, None]
        z = np.minimum(np.maximum(self._z, vc - self._r), vc + self._r)
        self._z = z
        return self._w0 * v + np.add.reduce(z * self._w, axis=-1)

    def run(self, v_V) -> np.ndarray:
        """Advance over a sequence. ``v_V`` shape ``(N, n_channels)``; returns ``h``."""
        v = as_finite_array("v_V", v_V, shape=(None, self.n_channels))
        return self._run(v)

    def _run(self, v: np.ndarray) -> np.ndarray:
        n = v.shape[0]
        out = np.empty_like(v)
        if self._r.size == 0:
            out[...] = self._w0 * v
            return out
        z = self._z
        for start in range(0, n, _RUN_BLOCK):
            vb = v[start:start + _RUN_BLOCK]
            lo = vb[:, :, None] - self._r
            hi = vb[:, :, None] + self._r
            zb = np.empty_like(lo)
            maximum, minimum = np.maximum, np.minimum
            for m in range(vb.shape[0]):
                zm = zb[m]
                maximum(z, lo[m], out=zm)
                minimum(zm, hi[m], out=zm)
                z = zm
            out[start:start + vb.shape[0]] = self._w0 * vb + np.add.reduce(zb * self._w, axis=-1)
            z = z.copy()
        self._z = z
        return out


class KelvinVoigtCreep:
    """Linear creep: ``y = s * (h + sum_k c_k x_k)``, ``tau_k x_k' = h - x_k``.

    Parameters
    ----------
    gains : sequence of float
        Stage gains ``c_k`` (>= 0).
    time_constants_s : sequence of float
        Stage time constants ``tau_k`` (> 0), seconds.
    dt_s : float
        Sample period, seconds (input is zero-order held).
    n_channels : int
        Number of independent channels.
    normalize_dc : bool
        Use ``s = 1 / (1 + sum c_k)`` (unit DC gain) instead of ``s = 1``.

    Notes
    -----
    For a step of height ``H`` applied at sample 0 from rest the output is
    exactly ``s * H * (1 + sum_k c_k (1 - exp(-n dt / tau_k)))``.
    """

    def __init__(self, gains: Sequence[float], time_constants_s: Sequence[float], dt_s: float,
                 n_channels: int = 3, normalize_dc: bool = True):
        c = as_finite_array("gains", gains, ndim=1)
        tau = as_finite_array("time_constants_s", time_constants_s, shape=(c.size,))
        if np.any(tau <= 0):
            raise ValueError("time_constants_s: expected values > 0")
        if not np.isfinite(dt_s) or dt_s <= 0:
            raise ValueError(f"dt_s: expected a finite value > 0, got {dt_s}")
        self.n_channels = int(n_channels)
        self.dt_s = float(dt_s)
        self._c = c.copy()
        self._a = np.exp(-self.dt_s / tau)
        self._b = 1.0 - self._a
        self._a_col = self._a[:, None]
        self._b_col = self._b[:, None]
        self._scale = 1.0 / (1.0 + float(c.sum())) if normalize_dc else 1.0
        # Output y = s*h + sum_k (s*c_k) x_k, accumulated in stage order (step and run alike).
        self._sc = [self._scale * float(ck) for ck in c]
        self._x = np.zeros((c.size, self.n_channels))

    @property
    def stage_state(self) -> np.ndarray:
        """Copy of the stage states ``x_k``, shape ``(n_stages, n_channels)``."""
        return self._x.copy()

    def reset(self) -> None:
        """Zero all stage states (no creep history)."""
        self._x[...] = 0.0

    def step(self, h) -> np.ndarray:
        """Advance one sample; ``h`` shape ``(n_channels,)``."""
        return self._step(as_finite_array("h", h, shape=(self.n_channels,)))

    def _step(self, h: np.ndarray) -> np.ndarray:
        x = self._x
        acc = self._scale * h
        for k, sck in enumerate(self._sc):
            acc += sck * x[k]
        self._x = self._a_col * x + self._b_col * h
        return acc

    def run(self, h) -> np.ndarray:
        """Advance over a sequence; ``h`` shape ``(N, n_channels)``."""
        return self._run(as_finite_array("h", h, shape=(None, self.n_channels)))

    def _run(self, h: np.ndarray) -> np.ndarray:
        acc = self._scale * h
        xf = np.empty_like(self._x)
        for k, sck in enumerate(self._sc):
            # x_k[n+1] = a x_k[n] + b h[n]; lfilter's output is x_k[n] (state before sample n).
            xk, zf = lfilter([0.0, self._b[k]], [1.0, -self._a[k]], h, axis=0,
                             zi=self._x[k][None, :])
            acc += sck * xk
            xf[k] = zf[0]
        self._x = xf
        return acc


class PiezoModel:
    """Hysteresis followed by creep for ``n_channels`` actuators.

    Parameters
    ----------
    config : PiezoConfig
        Model parameters and switches.
    dt_s : float
        Sample period in seconds (controller: 1/4000 s).
    n_channels : int
        Number of actuators.
    """

    def __init__(self, config: PiezoConfig | None = None, dt_s: float = C.CONTROL_PERIOD_S, n_channels: int = 3):
        self.config = PiezoConfig() if config is None else config
        self.n_channels = int(n_channels)
        self.dt_s = float(dt_s)
        w0, w = self.config.hysteresis_weights()
        self.hysteresis = (PrandtlIshlinskii(self.config.pi_thresholds_V, w, w0, self.n_channels)
                           if self.config.hysteresis else None)
        self.creep = (KelvinVoigtCreep(self.config.creep_gains, self.config.creep_time_constants_s,
                                       self.dt_s, self.n_channels, self.config.normalize_creep_dc)
                      if self.config.creep else None)

    def reset(self) -> None:
        """Virgin hysteresis state and no creep history."""
        if self.hysteresis is not None:
            self.hysteresis.reset()
        if self.creep is not None:
            self.creep.reset()

    def step(self, v_piezo_V) -> np.ndarray:
        """Free-strain voltage for one sample; ``v_piezo_V`` shape ``(n_channels,)``."""
        return self._step(as_finite_array("v_piezo_V", v_piezo_V, shape=(self.n_channels,)))

    def _step(self, v: np.ndarray) -> np.ndarray:
        h = self.hysteresis._step(v) if self.hysteresis is not None else v
        if self.creep is not None:
            return self.creep._step(h)
        return h if self.hysteresis is not None else h.copy()

    def run(self, v_piezo_V) -> np.ndarray:
        """Free-strain voltage over a sequence; ``v_piezo_V`` shape ``(N, n_channels)``."""
        return self._run(as_finite_array("v_piezo_V", v_piezo_V, shape=(None, self.n_channels)))

    def _run(self, v: np.ndarray) -> np.ndarray:
        h = self.hysteresis._run(v) if self.hysteresis is not None else v
        if self.creep is not None:
            return self.creep._run(h)
        return h if self.hysteresis is not None else h.copy()
