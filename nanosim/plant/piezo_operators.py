"""The piezo model's operators: the compiled play kernels, the play-operator states and the linear creep.

:func:`play_channel` / :func:`play_run` advance one channel's thermally activated play operators by one
sample / a run (exact relaxation between samples); :class:`PlayOperators` (and its athermal special case
:class:`PrandtlIshlinskii`) hold the operator states of several channels, :class:`KelvinVoigtCreep` the
creep stages of :func:`log_creep_stages`. The physics and the calibration are described in
:mod:`nanosim.plant.piezo`, which assembles these into :class:`~nanosim.plant.piezo.PiezoModel` and
re-exports these names.
"""
from __future__ import annotations

from math import exp, log
from typing import Sequence

import numpy as np
from scipy.signal import lfilter

from nanosim import constants as C
from nanosim.validation import as_finite_array

try:                                   # pragma: no cover - exercised where numba is installed
    from numba import njit
except ImportError:                    # pragma: no cover
    def njit(*args, **kwargs):
        """Stand-in decorator without numba (the same arithmetic in Python)."""
        return (lambda f: f) if not args or not callable(args[0]) else args[0]

__all__ = ["play_channel", "play_run", "relaxation_rates", "log_creep_stages", "PlayOperators", "PrandtlIshlinskii",
           "KelvinVoigtCreep"]


@njit(cache=True, error_model="numpy")
def play_channel(v, z, r, w, om, pp):
    """One sample of one channel's operators: clamp, output, then the exact thermal relaxation.

    Parameters
    ----------
    v : float
        Input (piezo volts), held over the sample.
    z : ndarray, shape (n_operators,)
        Operator outputs, updated in place to their values at the next sample.
    r, w : ndarray, shape (n_operators,)
        Thresholds (V) and weights.
    om : ndarray, shape (n_operators,)
        ``1 - q = -expm1(-k dt)``, ``k = 2 nu exp(-r / V_a) / V_a``.
    pp : ndarray, shape (2,)
        ``(w0, V_a)``; ``V_a <= 0`` is the athermal (PI) operator.

    Returns
    -------
    float
        ``w0 v + sum_i w_i z_i`` with the clamped ``z`` (sum left to right).
    """
    w0, va = pp[0], pp[1]
    acc = 0.0
    for j in range(r.shape[0]):
        rj = r[j]
        zj = min(max(z[j], v - rj), v + rj)
        acc += w[j] * zj
        if va > 0.0:
            e = v - zj
            if e != 0.0:
                p0 = exp(-abs(e) / va)
                omj = om[j]
                omt = omj + (1.0 - omj) * (2.0 * p0 / (1.0 + p0))      # 1 - T
                if omt > 0.0:
                    ae1 = -va * log(omt / (2.0 - omt))                   # |e1| = -V_a ln p1
                    zj = v - ae1 if e > 0.0 else v + ae1
        z[j] = zj
    return w0 * v + acc


@njit(cache=True, error_model="numpy")
def play_run(v, z, r, w, om, pp, out):
    """:func:`play_channel` over samples and channels.

    ``v``, ``out``: ``(N, channels)``; ``z``: ``(channels, n_operators)``, updated in place.
    """
    for k in range(v.shape[0]):
        for ch in range(v.shape[1]):
            out[k, ch] = play_channel(v[k, ch], z[ch], r, w, om, pp)


def relaxation_rates(thresholds_V, activation_V: float, attempt_rate_V_per_s: float) -> np.ndarray:
    """``k = 2 nu exp(-r / V_a) / V_a`` (1/s) of each operator (zeros if ``V_a = 0``): ``1 / tau_r`` near ``z = v``."""
    r = np.asarray(thresholds_V, dtype=float)
    if activation_V <= 0.0:
        return np.zeros_like(r)
    return 2.0 * attempt_rate_V_per_s * np.exp(-r / activation_V) / activation_V


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

class PlayOperators:
    """Play operators, athermal or thermally activated, for several independent channels.

    Parameters
    ----------
    thresholds_V : sequence of float
        Thresholds ``r_i`` (>= 0), volts.
    weights : sequence of float
        Weights ``w_i`` (>= 0).
    linear_weight : float
        Weight ``w0`` of the linear term.
    n_channels : int
        Number of independent channels.
    activation_V : float
        Activation voltage ``V_a`` (>= 0; 0: athermal play operators).
    attempt_rate_V_per_s : float
        Attempt rate ``nu`` (> 0 when ``activation_V > 0``).
    dt_s : float
        Sample period (input zero-order held), seconds.

    Notes
    -----
    State ``z`` has shape ``(n_channels, n_operators)``; ``reset`` puts it in
    the virgin state ``z = 0`` (demagnetised piezo at 0 V). ``step`` and
    ``run`` call the same compiled routine (:func:`play_run`), so a run equals
    repeated steps bit for bit.
    """

    def __init__(self, thresholds_V: Sequence[float], weights: Sequence[float], linear_weight: float = 0.0,
                 n_channels: int = 3, activation_V: float = 0.0, attempt_rate_V_per_s: float = 0.0,
                 dt_s: float = C.CONTROL_PERIOD_S):
        r = as_finite_array("thresholds_V", thresholds_V, ndim=1)
        w = as_finite_array("weights", weights, shape=(r.size,))
        if np.any(r < 0):
            raise ValueError("thresholds_V: expected values >= 0")
        if not np.isfinite(linear_weight):
            raise ValueError("linear_weight: expected a finite value")
        if int(n_channels) < 1:
            raise ValueError(f"n_channels: expected >= 1, got {n_channels}")
        va, nu, dt = float(activation_V), float(attempt_rate_V_per_s), float(dt_s)
        if not np.isfinite(va) or va < 0:
            raise ValueError(f"activation_V: expected a finite value >= 0, got {activation_V}")
        if va > 0 and (not np.isfinite(nu) or nu <= 0):
            raise ValueError(f"attempt_rate_V_per_s: expected a finite value > 0, got {attempt_rate_V_per_s}")
        if not np.isfinite(dt) or dt <= 0:
            raise ValueError(f"dt_s: expected a finite value > 0, got {dt_s}")
        self.n_channels = int(n_channels)
        self._r = np.ascontiguousarray(r, dtype=float)
        self._w = np.ascontiguousarray(w, dtype=float)
        self._w0 = float(linear_weight)
        self._om = np.ascontiguousarray(-np.expm1(-relaxation_rates(self._r, va, nu) * dt))
        self._pp = np.array([self._w0, va])
        self._z = np.zeros((self.n_channels, r.size))

    @property
    def operator_state(self) -> np.ndarray:
        """Copy of the operator outputs, shape ``(n_channels, n_operators)``."""
        return self._z.copy()

    def reset(self) -> None:
        """Return to the virgin state (all operator outputs 0)."""
        self._z[...] = 0.0

    def step(self, v_V) -> np.ndarray:
        """Advance one sample. ``v_V`` shape ``(n_channels,)``; returns ``h`` (same shape)."""
        return self._step(as_finite_array("v_V", v_V, shape=(self.n_channels,)))

    def _step(self, v: np.ndarray) -> np.ndarray:
        out = np.empty((1, self.n_channels))
        play_run(np.ascontiguousarray(v, dtype=float).reshape(1, -1), self._z, self._r, self._w, self._om, self._pp,
                 out)
        return out[0]

    def run(self, v_V) -> np.ndarray:
        """Advance over a sequence. ``v_V`` shape ``(N, n_channels)``; returns ``h``."""
        return self._run(as_finite_array("v_V", v_V, shape=(None, self.n_channels)))

    def _run(self, v: np.ndarray) -> np.ndarray:
        v = np.ascontiguousarray(v, dtype=float)
        out = np.empty_like(v)
        play_run(v, self._z, self._r, self._w, self._om, self._pp, out)
        return out


class PrandtlIshlinskii(PlayOperators):
    """Rate-independent (athermal) play operators: :class:`PlayOperators` with ``V_a = 0``.

    ``z_i = clamp(z_i, v - r_i, v + r_i)``, ``h = w0 v + sum_i w_i z_i``.
    """

    def __init__(self, thresholds_V: Sequence[float], weights: Sequence[float], linear_weight: float = 0.0,
                 n_channels: int = 3):
        super().__init__(thresholds_V, weights, linear_weight, n_channels)


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
