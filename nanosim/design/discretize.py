"""Controller discretization (paper: 4 kHz) and its frequency-response check below 500 Hz.

* :func:`discretize_controller` -- Tustin, or a better method when Tustin misses
  the tolerance (:data:`DISCRETIZATION_METHODS`);
* :func:`discretization_error`, :func:`error_rel_to_peak` -- the check;
* :func:`discrete_closed_loop` -- stability of the sampled loop;
* :func:`dc_gain_discrete` -- ``Kd(z = 1)``.

Controllers map the tracking error [sensor V] to controller volts; sample times
are in s, frequencies in Hz.

**Which method is exact.** A design made on a continuous model that is the Tustin
d2c of an identified discrete model (the project's design models, as the paper's:
``identification.d2c.d2c_tustin``) is brought back exactly by Tustin: with
s = (2 / dt) (z - 1) / (z + 1), Kd(z) = K(s(z)), so a controller zero that cancels a
pole s_p of the design model lands on the identified discrete pole z_p with
s(z_p) = s_p. Pole matching, and Tustin prewarped at the mode, put it at the angle of
exp(s_p dt) instead: at the design model's warped frequency f_w = (fs / pi) tan(pi f / fs)
(:func:`nanosim.paper.tustin_warp_hz`) rather than at the plant's f. The frequency-response check against K(j w)
measures the warp, not an error of the loop: for such designs use ``"tustin_round_trip"``,
Tustin checked against K at the frequency the design model put the plant's response,
Kd(e^{j w dt}) against K(j (2 / dt) tan(w dt / 2)) (the identified discrete loop at w is
the design loop there, so the check measures only the arithmetic).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from nanosim import constants
from nanosim.design.lti import analysis_grid_hz, as_ss, freqresp, sigma_max, single_threaded_blas

__all__ = ["Discretization", "DISCRETIZATION_METHODS", "discretize_controller", "discretization_error",
           "round_trip_error",
           "discrete_closed_loop", "error_rel_to_peak", "dc_gain_discrete"]

DISCRETIZATION_METHODS = ("auto", "tustin", "tustin_round_trip", "tustin_prewarp", "tustin_modal", "foh", "zoh",
                          "matched_fit")


@dataclass(frozen=True, eq=False)
class Discretization:
    """Result of :func:`discretize_controller`.

    Attributes
    ----------
    Kd : control.StateSpace
        Discrete controller (sample time ``dt``), error sensor V -> controller V.
    dt : float
        Sample time [s].
    method : str
        Method used (see :func:`discretize_controller`).
    f_check_hz : float
        Upper edge of the checked band [Hz].
    max_rel_error : float
        ``max_{f <= f_check} sigma_max(Kd(e^{j w dt}) - K(j w)) / sigma_max(K(j w))``.
    worst_freq_hz : float
        Frequency of that maximum [Hz].
    rtol : float
        Requested tolerance; ``within_tol = max_rel_error <= rtol``.
    errors_by_method : dict
        ``max_rel_error`` of every method tried (always includes ``"tustin"``).
    """

    Kd: Any
    dt: float
    method: str
    f_check_hz: float
    max_rel_error: float
    worst_freq_hz: float
    rtol: float
    within_tol: bool
    errors_by_method: dict

    @property
    def tustin_max_rel_error(self) -> float:
        """Plain Tustin's ``max_rel_error`` (NaN if it was not tried)."""
        return float(self.errors_by_method.get("tustin", float("nan")))


def _check_grid_hz(K, f_max_hz: float) -> np.ndarray:
    parts = [np.array([0.0]), np.logspace(-3, np.log10(f_max_hz), 1500), np.linspace(0.5, f_max_hz, 3000)]
    parts.append(analysis_grid_hz([K], 1e-3, f_max_hz, n=10))
    f = np.unique(np.concatenate(parts))
    return f[f <= f_max_hz]


def discretization_error(K, Kd, f_max_hz: float = 500.0):
    """Relative frequency-response error of a discretized controller.

    Parameters
    ----------
    K : control.StateSpace
        Continuous controller, ``nu x ny`` (sensor V -> controller V).
    Kd : control.StateSpace
        Its discretization (sample time ``Kd.dt`` [s]).
    f_max_hz : float, default 500
        Upper edge of the checked band [Hz], below Nyquist.

    Returns
    -------
    max_rel_error : float
        ``max sigma_max(Kd(e^{j w dt}) - K(j w)) / sigma_max(K(j w))`` over
        ``0 <= f <= f_max_hz`` (grid incl. f = 0 and dense points near
        lightly damped controller poles).
    worst_freq_hz : float
        Where it occurs [Hz].
    freq_hz, rel_error : ndarray, shape (F,)
        The whole curve ([Hz], dimensionless).
    """
    f = _check_grid_hz(K, f_max_hz)
    Hc, Hd = freqresp(K, f), freqresp(Kd, f)
    e = sigma_max(Hd - Hc) / np.maximum(sigma_max(Hc), 1e-300)
    i = int(np.argmax(e))
    return float(e[i]), float(f[i]), f, e


def round_trip_error(K, Kd, f_max_hz: float = 500.0):
    """Relative error of ``Kd`` against ``K`` at the Tustin-warped frequency.

    ``max sigma_max(Kd(e^{j w dt}) - K(j w_w)) / sigma_max(K(j w_w))`` over ``0 <= f <= f_max_hz``,
    ``w_w = (2 / dt) tan(w dt / 2)``: zero (to rounding) when ``Kd`` is the Tustin image of ``K``.
    Returns ``(max_rel_error, worst_freq_hz)``.
    """
    f = _check_grid_hz(K, f_max_hz)
    dt = float(Kd.dt)
    f_w = np.tan(np.pi * f * dt) / (np.pi * dt)
    Hc = freqresp(K, f_w)
    e = sigma_max(freqresp(Kd, f) - Hc) / np.maximum(sigma_max(Hc), 1e-300)
    i = int(np.argmax(e))
    return float(e[i]), float(f[i])


def _tustin_blocks(K, dt, prewarp: bool):
    """Tustin in block-diagonal (modal) coordinates; with ``prewarp`` each real
    Schur block (one real pole or one complex pair, |p| below 0.8 x Nyquist) gets
    its own prewarp frequency ``|p|``, so lightly damped controller poles keep
    their exact frequency.
    """
    import control as ct
    A, B, C, D = (np.asarray(getattr(K, k), float) for k in "ABCD")
    Am, Tm, blk = ct.bdschur(A)
    Bm, Cm = np.linalg.solve(Tm, B), C @ Tm
    n = A.shape[0]
    Ad, Bd, Dd = np.zeros((n, n)), np.zeros_like(Bm), D.copy()
    wN = np.pi / dt
    i = 0
    for b in np.asarray(blk, int):
        sl = slice(i, i + b)
        Ai = Am[sl, sl]
        lam = np.abs(np.linalg.eigvals(Ai))
        w0 = float(lam.max())
        if prewarp and 0 < w0 < 0.8 * wN and np.ptp(lam) <= 1e-3 * w0:
            alpha = w0 / math.tan(w0 * dt / 2)
        else:
            alpha = 2.0 / dt
        Mi = np.linalg.inv(alpha * np.eye(b) - Ai)
        Ad[sl, sl] = Mi @ (alpha * np.eye(b) + Ai)
        Bd[sl] = 2 * alpha * Mi @ Mi @ Bm[sl]
        Dd = Dd + Cm[:, sl] @ Mi @ Bm[sl]
        i += b
    return ct.ss(Ad, Bd, Cm, Dd, dt)


def _matched_fit(K, dt, f_fit_hz):
    """Exact pole mapping ``Ad = expm(A dt)``, ``Cd = C``; ``Bd`` and ``Dd`` by
    linear least squares on the frequency response over ``0..f_fit_hz``, each
    frequency weighted by ``1 / sigma_max(K(jw))`` (relative error).
    """
    import control as ct
    from scipy.linalg import expm
    A, B, C = (np.asarray(getattr(K, k), float) for k in "ABC")
    n, nu, ny = A.shape[0], B.shape[1], C.shape[0]
    Ad, Cd = expm(A * dt), C.copy()
    f = np.unique(np.concatenate([[0.0], np.logspace(-3, np.log10(f_fit_hz), 1500),
                                  np.linspace(0.5, f_fit_hz, 3000), analysis_grid_hz([K], 1e-3, f_fit_hz, n=10)]))
    H = freqresp(K, f)                                         # (F, ny, nu)
    wgt = 1.0 / np.maximum(sigma_max(H), 1e-300)
    z = np.exp(2j * np.pi * f * dt)
    R = np.empty((f.size, ny, n), complex)
    I = np.eye(n)
    for k0 in range(0, f.size, 512):
        zz = z[k0:k0 + 512]
        X = np.linalg.solve(zz[:, None, None] * I - Ad, np.broadcast_to(I, (zz.size, n, n)))
        R[k0:k0 + 512] = Cd @ X
    Mx = np.concatenate([R, np.broadcast_to(np.eye(ny), (f.size, ny, ny))], axis=2) * wgt[:, None, None]
    Mr = np.concatenate([Mx.real.reshape(-1, n + ny), Mx.imag.reshape(-1, n + ny)])
    sc = np.linalg.norm(Mr, axis=0)
    sc[sc == 0] = 1.0
    Bd, Dd = np.zeros((n, nu)), np.zeros((ny, nu))
    for j in range(nu):
        y = H[:, :, j] * wgt[:, None]
        yr = np.concatenate([y.real.ravel(), y.imag.ravel()])
        sol = np.linalg.lstsq(Mr / sc, yr, rcond=None)[0] / sc
        Bd[:, j], Dd[:, j] = sol[:n], sol[n:]
    return ct.ss(Ad, Bd, Cd, Dd, dt)


def _discretize_one(K, dt, method, f_check_hz, prewarp_hz):
    import control as ct
    nyq = 0.5 / dt
    if method in ("tustin", "tustin_round_trip"):
        return ct.c2d(K, dt, "tustin")
    if method == "tustin_prewarp":
        fp = f_check_hz if prewarp_hz is None else prewarp_hz
        return ct.c2d(K, dt, "tustin", prewarp_frequency=2 * np.pi * fp)
    if method == "tustin_modal":
        return _tustin_blocks(K, dt, prewarp=True)
    if method in ("foh", "zoh"):
        return ct.c2d(K, dt, method)
    if method == "matched_fit":
        return _matched_fit(K, dt, min(2.0 * f_check_hz, 0.5 * nyq))
    raise ValueError(f"method: expected one of {DISCRETIZATION_METHODS}, got {method!r}")


@single_threaded_blas
def discretize_controller(K, dt: float = constants.CONTROL_PERIOD_S, method: str = "auto", *,
                          f_check_hz: float = 500.0, rtol: float = 0.01,
                          prewarp_hz: float | None = None) -> Discretization:
    """Discretize the controller and check its frequency response below ``f_check_hz``.

    Parameters
    ----------
    K : control.StateSpace
        Continuous controller (sensor V -> controller V).
    dt : float, default 1/4000
        Sample time [s] (paper: 4 kHz).
    method : str, default "auto"
        ``"tustin"`` -- ``control.c2d(K, dt, 'tustin')``;
        ``"tustin_round_trip"`` -- the same, for a ``K`` designed on a model that is the Tustin
        d2c of a discrete one: the check is :func:`round_trip_error` (see the module docstring);
        ``"tustin_prewarp"`` -- Tustin prewarped at ``prewarp_hz`` (default ``f_check_hz``);
        ``"tustin_modal"`` -- Tustin in modal coordinates, each mode prewarped at its
        own natural frequency;
        ``"foh"``, ``"zoh"`` -- hold equivalents (``control.c2d``);
        ``"matched_fit"`` -- exact poles ``exp(p dt)`` with B, D fitted to K(jw) up to
        ``2 f_check_hz`` (least squares, relative weighting);
        ``"auto"`` -- Tustin if it meets ``rtol``; otherwise the method with the smallest
        error among ``tustin_modal``, ``foh`` and ``matched_fit``.
    f_check_hz : float, default 500
        Checked band ``0..f_check_hz`` [Hz]; must be below Nyquist.
    rtol : float, default 0.01
        Tolerance on the max relative error (1 %).
    prewarp_hz : float, optional
        Prewarp frequency for ``"tustin_prewarp"`` [Hz].

    Returns
    -------
    Discretization
        Tustin's own error is always computed and reported in ``errors_by_method``.
    """
    K = as_ss("K", K)
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: expected a positive sample time in s, got {dt!r}")
    if not 0 < f_check_hz < 0.5 / dt:
        raise ValueError(f"f_check_hz={f_check_hz} must be in (0, Nyquist = {0.5 / dt:g}) Hz")
    if method not in DISCRETIZATION_METHODS:
        raise ValueError(f"method: expected one of {DISCRETIZATION_METHODS}, got {method!r}")
    errors: dict[str, float] = {}
    cands: dict[str, tuple] = {}

    def attempt(m):
        Kd = _discretize_one(K, dt, m, f_check_hz, prewarp_hz)
        if m == "tustin_round_trip":
            err, fw = round_trip_error(K, Kd, f_check_hz)
        else:
            err, fw, _, _ = discretization_error(K, Kd, f_check_hz)
        errors[m] = err
        cands[m] = (Kd, err, fw)

    attempt("tustin")
    if method == "auto":
        chosen = "tustin"
        if errors["tustin"] > rtol:
            for m in ("tustin_modal", "foh", "matched_fit"):
                attempt(m)
            chosen = min(errors, key=errors.get)
    else:
        if method != "tustin":
            attempt(method)
        chosen = method
    Kd, err, fw = cands[chosen]
    return Discretization(Kd=Kd, dt=float(dt), method=chosen, f_check_hz=float(f_check_hz), max_rel_error=err,
                          worst_freq_hz=fw, rtol=float(rtol), within_tol=bool(err <= rtol),
                          errors_by_method=dict(errors))


def error_rel_to_peak(K, Kd, f_max_hz: float) -> float:
    """Discretization error relative to the controller's peak gain (for ``K`` with ``K(0) = 0``).

    Parameters
    ----------
    K : control.StateSpace
        Continuous controller (sensor V -> controller V).
    Kd : control.StateSpace
        Its discretization (sample time ``Kd.dt`` [s]).
    f_max_hz : float
        Upper edge of the checked band ``0..f_max_hz`` [Hz].

    Returns
    -------
    float
        ``max_f sigma_max(Kd - K) / max_f sigma_max(K)`` [dimensionless].
    """
    f = _check_grid_hz(K, f_max_hz)
    Hc = freqresp(K, f)
    return float(sigma_max(freqresp(Kd, f) - Hc).max() / max(sigma_max(Hc).max(), 1e-300))


def dc_gain_discrete(Kd) -> np.ndarray:
    """DC gain ``Kd(z = 1) = D + C (I - A)^-1 B`` of a discrete model.

    Parameters
    ----------
    Kd : control.StateSpace
        Discrete model without a pole at ``z = 1``.

    Returns
    -------
    ndarray, shape (ny, nu)
        In the model's units (controller: controller V / sensor V).
    """
    A = np.asarray(Kd.A, float)
    return np.asarray(Kd.D, float) + np.asarray(Kd.C) @ np.linalg.solve(np.eye(A.shape[0]) - A, np.asarray(Kd.B))


def discrete_closed_loop(Gd, Kd):
    """Stability of the sampled closed loop ``u(k) = Kd e(k)``, ``e = r - y``.

    Parameters
    ----------
    Gd : control.StateSpace
        Discrete plant, ``ny x nu`` (controller V -> sensor V), sample time ``dt`` [s].
    Kd : control.StateSpace
        Discrete controller, ``nu x ny`` (error sensor V -> controller V), same ``dt``.

    Returns
    -------
    stable : bool
        Spectral radius below 1.
    spectral_radius : float
        Largest pole magnitude of the discrete ``S = (I + Gd Kd)^-1`` [dimensionless].
    """
    import control as ct
    I = ct.ss(np.zeros((0, 0)), np.zeros((0, Gd.noutputs)), np.zeros((Gd.noutputs, 0)), np.eye(Gd.noutputs), Gd.dt)
    S = ct.feedback(I, ct.series(Kd, Gd), sign=-1)
    rho = float(np.max(np.abs(np.linalg.eigvals(S.A)))) if S.nstates else 0.0
    return bool(rho < 1.0), rho
