"""Model reduction and H-infinity mixed-sensitivity design (paper Sec. 4).

Pipeline (paper = DOI 10.1115/1.2936861, Sec. 4.1-4.2, Appendix B):

1. :func:`reduce_model` -- balanced truncation with matched DC gain (singular
   perturbation of the balanced realization, slycot ``ab09nd``) of the
   identified 39-state model to 10 states (paper Figs. 8-9).
2. :func:`multiplicative_uncertainty` -- ``sigma_max(E_o)``,
   ``E_o = (G_P - G) G^-1`` (paper Fig. 10).
3. :func:`design_hinf` -- mixed-sensitivity S / KS / T synthesis
   (``control.augw`` + ``control.hinfsyn`` = ``control.mixsyn``) with the weights
   of :mod:`nanosim.weights`; the generalized plant is checked first by
   :func:`check_assumptions` (paper Figs. 11-13, 21-22).
3b. :func:`damping_loop` (optional, beyond the paper) -- an inner active-damping
   loop for the lightly damped first modes; the H-infinity design is then done
   on the damped plant (two-degree-of-freedom controller, see below).
4. :func:`discretize_controller` -- 4 kHz discrete controller and its
   frequency-response error below 500 Hz.
5. :func:`run_design` -- all of the above from ``model.npz``, writing
   ``controller.npz``, ``design.json``, ``design.mat`` and the figures.

Units and signals
-----------------
Plant ``G``: inputs = controller volts for actuators A, B, C (before the x20
amplifier); outputs = sensor volts X, Y, Z (5 um/V). Controller ``K``: input =
tracking error in sensor volts, output = controller volts. Frequencies are in
Hz in every public argument and result (``*_hz``); state-space models use
``s`` in rad/s.

Sign convention (pinned, tested)
--------------------------------
Negative feedback: ``e = r - y``, ``u = +K e``, ``L = G K``,
``S = (I + G K)^-1`` (r -> e), ``T = G K (I + G K)^-1`` (r -> y),
``KS = K (I + G K)^-1`` (r -> u). The controller returned by
``control.hinfsyn``/``mixsyn`` for the ``augw`` plant is used with exactly this
sign (its measured signal is ``v = r - G u = e``).

Active damping (two degrees of freedom)
---------------------------------------
A mixed-sensitivity S/KS/T design inverts the plant: its controller has
zeros on the lightly damped plant poles (176/178 Hz, zeta ~ 0.004), so the
closed loop keeps them with their open-loop damping. Any input disturbance
there (the piezo's hysteresis, DAC noise) then rings for ``1/(zeta w)`` ~ 0.25 s.
With ``damping`` the loop is ``u = K e + Ky y``: ``Ky`` is a band-limited
velocity feedback (:func:`damping_loop`) closed first, ``Gd = (I - G Ky)^-1 G``,
and ``K`` is the H-infinity controller for ``Gd`` with the same weights. Then
``r -> y`` is exactly ``T = Gd K (I + Gd K)^-1`` and ``r -> e`` is
``S = (I + Gd K)^-1``, so every weight bound of the design holds for the
tracking loop; the feedback operator is ``K - Ky`` (``u = K r - (K - Ky) y``).
The reference never passes through ``Ky`` (no derivative kick on steps).
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import os
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from nanosim import constants
from nanosim import fileio
from nanosim.design.weights import PAPER_WEIGHTS, WeightSpec, Weights, paper_weights  # noqa: F401  (re-export)

__all__ = [
    "SIGN_CONVENTION", "Weights", "WeightSpec", "PAPER_WEIGHTS", "paper_weights",
    "Reduction", "reduce_model", "multiplicative_uncertainty",
    "AssumptionReport", "check_assumptions", "generalized_plant",
    "Design", "design_hinf", "loop_functions",
    "DampingLoop", "damping_loop", "damped_plant", "stack_inputs", "feedback_operator",
    "Discretization", "discretize_controller", "discretization_error",
    "discrete_closed_loop", "run_design",
    "plot_hankel", "plot_reduction_bode", "plot_uncertainty", "plot_weights",
    "plot_sensitivity", "plot_T_KS", "plot_closed_loop_bode", "plot_controller_bode",
]

SIGN_CONVENTION = ("negative feedback: e = r - y [sensor V]; u = +K e [controller V]; L = G K; "
                   "S = (I + G K)^-1 (r -> e); T = G K (I + G K)^-1 (r -> y); KS = K (I + G K)^-1 (r -> u)")
UNITS = {
    "plant_G": "input controller V (actuators A,B,C, before the x20 amplifier) -> output sensor V (X,Y,Z; 5 um/V)",
    "controller_K": "input tracking error e = r - y in sensor V -> output controller V",
    "state_space_time": "continuous models: s in rad/s, time in s; discrete models: sample time dt in s",
    "frequencies": "Hz (keys ending in _hz)",
    "magnitudes": "singular values are dimensionless ratios for S and T, controller V / sensor V for K and KS",
}
INV_SQRT2 = 1.0 / math.sqrt(2.0)
BANDWIDTH_DEFINITIONS = {
    "bandwidth_S_hz": "lowest frequency where sigma_max(S) first rises to 1/sqrt(2) (-3 dB) from below "
                      "(Skogestad & Postlethwaite omega_B); nominal (reduced) model",
    "bandwidth_T_hz": "lowest frequency where sigma_max(T) first falls below 1/sqrt(2) (-3 dB), i.e. the "
                      "closed-loop -3 dB bandwidth of the worst direction; nominal model",
    "bandwidth_T_last_hz": "highest frequency where sigma_max(T) crosses 1/sqrt(2) from above "
                           "(Skogestad & Postlethwaite omega_BT); can sit at a resonance",
}
# A pole counts as "on the imaginary axis" if |Re p| <= rtol * max(1, |p|).
AXIS_RTOL = 1e-9


# =====================================================================================
# small helpers
# =====================================================================================
def _ct():
    import control as ct
    return ct


def _as_ss(name: str, sys_, *, continuous: bool = True):
    """Return ``sys_`` as a ``control.StateSpace`` with finite matrices."""
    ct = _ct()
    if isinstance(sys_, ct.TransferFunction):
        sys_ = ct.ss(sys_)
    if not isinstance(sys_, ct.StateSpace):
        raise ValueError(f"{name}: expected a control.StateSpace or TransferFunction, got {type(sys_).__name__}")
    for part in ("A", "B", "C", "D"):
        m = np.asarray(getattr(sys_, part), dtype=float)
        if not np.all(np.isfinite(m)):
            raise ValueError(f"{name}: matrix {part} has NaN/inf entries")
    if continuous and sys_.isdtime(strict=True):
        raise ValueError(f"{name}: expected a continuous-time model (dt = 0), got dt = {sys_.dt}")
    return sys_


def _static(D):
    ct = _ct()
    D = np.atleast_2d(np.asarray(D, dtype=float))
    return ct.ss(np.zeros((0, 0)), np.zeros((0, D.shape[1])), np.zeros((D.shape[0], 0)), D)


def freqresp(sys_, freq_hz) -> np.ndarray:
    """Complex frequency response, shape ``(F, ny, nu)``, at ``freq_hz`` [Hz].

    Continuous models are evaluated at ``s = j 2 pi f``, discrete ones at
    ``z = exp(j 2 pi f dt)`` (keep ``f`` below the Nyquist frequency).
    """
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if sys_.nstates == 0:
        return np.broadcast_to(np.asarray(sys_.D, dtype=complex), (f.size,) + sys_.D.shape).copy()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        resp = sys_.frequency_response(2 * np.pi * f)
        data = resp.frdata if hasattr(resp, "frdata") else resp.fresp
    return np.moveaxis(np.asarray(data).reshape(sys_.noutputs, sys_.ninputs, f.size), -1, 0)


def _smax(H: np.ndarray) -> np.ndarray:
    """Largest singular value of each matrix in a ``(F, p, m)`` stack."""
    return np.linalg.svd(H, compute_uv=False)[:, 0]


def _svals(H: np.ndarray) -> np.ndarray:
    return np.linalg.svd(H, compute_uv=False)


def _db(x):
    with np.errstate(divide="ignore"):
        return 20 * np.log10(np.asarray(x, dtype=float))


def _max_real_pole(A) -> float:
    A = np.asarray(A, dtype=float)
    return float(np.max(np.linalg.eigvals(A).real)) if A.size else -np.inf


def _crossing(f, y, level, rising: bool, first: bool = True) -> float:
    """Frequency where ``y`` crosses ``level`` (log-log interpolation).

    ``rising``: crossing from below (S); else from above (T). Returns 0.0 when
    ``y`` starts already past the level for a rising crossing, NaN when no
    crossing exists.
    """
    y = np.asarray(y, dtype=float)
    above = y >= level
    if rising:
        idx = np.flatnonzero(~above[:-1] & above[1:])
        if above[0] and first:
            return 0.0
    else:
        idx = np.flatnonzero(above[:-1] & ~above[1:])
    if idx.size == 0:
        return float("nan")
    i = int(idx[0] if first else idx[-1])
    lf0, lf1 = np.log(f[i]), np.log(f[i + 1])
    ly0, ly1, ll = np.log(y[i]), np.log(y[i + 1]), np.log(level)
    t = 0.0 if ly1 == ly0 else (ll - ly0) / (ly1 - ly0)
    return float(np.exp(lf0 + t * (lf1 - lf0)))


def analysis_grid_hz(systems=(), f_min_hz: float = 0.01, f_max_hz: float = 5000.0, n: int = 2500) -> np.ndarray:
    """Log-spaced frequency grid [Hz] densified around lightly damped poles.

    Around every pole ``p`` of the given ``StateSpace`` models with damping
    ``zeta = -Re p / |p| < 0.3`` and ``f0 = |p| / 2 pi`` inside the range, 41 points
    span ``f0 (1 +/- 8 zeta)`` and 21 more span ``f0 (1 +/- 3 %)``, so that
    resonance peaks of ``zeta = 0.002`` are resolved.
    """
    parts = [np.logspace(np.log10(f_min_hz), np.log10(f_max_hz), n)]
    for s_ in systems:
        if s_ is None or s_.nstates == 0:
            continue
        for p in np.linalg.eigvals(np.asarray(s_.A, dtype=float)):
            w0 = abs(p)
            if w0 == 0:
                continue
            zeta = -p.real / w0
            f0 = w0 / (2 * np.pi)
            if f_min_hz < f0 < f_max_hz and abs(zeta) < 0.3 and p.imag >= 0:
                z = max(abs(zeta), 1e-4)
                parts.append(f0 * (1 + 8 * z * np.linspace(-1, 1, 41)))
                parts.append(f0 * (1 + 0.03 * np.linspace(-1, 1, 21)))
    f = np.unique(np.concatenate(parts))
    return f[(f >= f_min_hz) & (f <= f_max_hz)]


def _refine_peak(fun, f, y, n_peaks: int = 6, n_fine: int = 101, rounds: int = 3):
    """Refine the grid maximum of ``y = fun(f)`` around its largest local maxima
    (``rounds`` successive zooms of ``n_fine`` points between the neighbours)."""
    y = np.asarray(y)
    loc = np.flatnonzero(np.r_[True, y[1:] >= y[:-1]] & np.r_[y[:-1] >= y[1:], True])
    loc = loc[np.argsort(y[loc])[::-1][:n_peaks]]
    best_y, best_f = float(y.max()), float(f[int(np.argmax(y))])
    for i in loc:
        lo, hi = f[max(i - 1, 0)], f[min(i + 1, f.size - 1)]
        for _ in range(rounds):
            if hi <= lo:
                break
            ff = np.linspace(lo, hi, n_fine)
            yy = fun(ff)
            j = int(np.argmax(yy))
            if yy[j] > best_y:
                best_y, best_f = float(yy[j]), float(ff[j])
            lo, hi = ff[max(j - 1, 0)], ff[min(j + 1, n_fine - 1)]
    return best_y, best_f


# ------------------------------------------------------------------------------------
# BLAS threading. The matrices here are tiny (<= 60 states); on a loaded 2-core
# machine OpenBLAS's default threading made slycot sb10ad 3-40x slower (0.45 s with
# one thread vs 1.3-17 s with two, measured on the 19-state paper problem). The
# public entry points therefore run with the bundled OpenBLAS copies (slycot, numpy,
# scipy wheels) limited to one thread and restore the previous setting afterwards.
# Set LIMIT_BLAS_THREADS = False to disable. Best effort: silently a no-op if the
# libraries or symbols are not found.
# ------------------------------------------------------------------------------------
LIMIT_BLAS_THREADS = True
_BLAS_SYMBOLS = (("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
                 ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
                 ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
                 ("openblas_get_num_threads", "openblas_set_num_threads"))


@functools.lru_cache(maxsize=1)
def _blas_handles() -> tuple:
    handles = []
    try:
        import ctypes
        import importlib.util
        for pkg in ("slycot", "numpy", "scipy"):
            spec = importlib.util.find_spec(pkg)
            if spec is None or not spec.submodule_search_locations:
                continue
            libdir = Path(list(spec.submodule_search_locations)[0]).parent / f"{pkg}.libs"
            for so in sorted(libdir.glob("lib*openblas*.so*")):
                lib = ctypes.CDLL(str(so))
                for get, set_ in _BLAS_SYMBOLS:
                    if hasattr(lib, get) and hasattr(lib, set_):
                        handles.append((getattr(lib, get), getattr(lib, set_)))
                        break
    except Exception:  # pragma: no cover - platform dependent
        return ()
    return tuple(handles)


@contextlib.contextmanager
def _single_thread_blas():
    prev = []
    if LIMIT_BLAS_THREADS:
        for get, set_ in _blas_handles():
            try:
                n = int(get())
                set_(1)
                prev.append((set_, n))
            except Exception:  # pragma: no cover
                pass
    try:
        yield
    finally:
        for set_, n in prev:
            try:
                set_(n)
            except Exception:  # pragma: no cover
                pass


def _blas_single_threaded(fn):
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with _single_thread_blas():
            return fn(*args, **kwargs)
    return wrapper


class _Progress:
    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.t0 = time.perf_counter()

    def __call__(self, msg: str):
        if self.enabled:
            print(f"[nanosim.design {time.perf_counter() - self.t0:7.2f} s] {msg}", file=sys.stderr, flush=True)


# =====================================================================================
# 4.1 model reduction
# =====================================================================================
@dataclass(frozen=True, eq=False)
class Reduction:
    """Result of :func:`reduce_model` (paper Sec. 4.1, Figs. 8-9).

    Attributes
    ----------
    G_full, G_reduced : control.StateSpace
        Full and reduced models (controller V -> sensor V), continuous.
    full_order, order : int
        Number of states of the full and of the reduced model.
    hankel_sv : ndarray, shape (n_stable,)
        Hankel singular values of the (stable part of the) full model,
        descending; units of the plant gain (sensor V / controller V).
    n_unstable : int
        Poles with ``Re p >= alpha`` (unstable or within ``stability_margin`` of the
        imaginary axis) that were kept unreduced.
    unstable_poles : ndarray, complex, shape (n_unstable,)
        Those poles [rad/s].
    dc_gain_full, dc_gain_reduced : ndarray, shape (ny, nu)
        ``G(0) = D - C A^-1 B`` [sensor V / controller V].
    dc_gain_rel_error : float
        ``max|G_r(0) - G(0)| / max|G(0)|``.
    dc_gain_matched : bool
        ``dc_gain_rel_error <= dc_rtol``.
    error_bound_hinf : float
        Balanced-truncation/SPA bound ``2 * sum(dropped Hankel SVs)`` on
        ``||G - G_r||_inf`` (sensor V / controller V).
    reduced_stable : bool
        All reduced-model poles have negative real part (when the full model is stable).
    method : str
        Description of the algorithm.
    """

    G_full: Any
    G_reduced: Any
    full_order: int
    order: int
    hankel_sv: np.ndarray
    n_unstable: int
    unstable_poles: np.ndarray
    dc_gain_full: np.ndarray
    dc_gain_reduced: np.ndarray
    dc_gain_rel_error: float
    dc_gain_matched: bool
    error_bound_hinf: float
    reduced_stable: bool
    method: str = "balanced truncation with matched DC gain (singular perturbation), slycot ab09nd"

    @property
    def hsv_kept(self) -> np.ndarray:
        """Hankel singular values of the retained stable states."""
        return self.hankel_sv[: max(self.order - self.n_unstable, 0)]

    @property
    def hsv_dropped(self) -> np.ndarray:
        """Hankel singular values of the removed states."""
        return self.hankel_sv[max(self.order - self.n_unstable, 0):]


def _dc_gain(sys_) -> np.ndarray:
    A = np.asarray(sys_.A, dtype=float)
    if A.size == 0:
        return np.asarray(sys_.D, dtype=float).copy()
    return np.asarray(sys_.D, dtype=float) - sys_.C @ np.linalg.solve(A, sys_.B)


@_blas_single_threaded
def reduce_model(G, order: int = 10, *, stability_margin: float = 1e-8, dc_rtol: float = 1e-6) -> Reduction:
    """Balanced truncation with DC gain matched (paper Sec. 4.1).

    Calls ``control.balanced_reduction(G, order, method='matchdc')`` (slycot
    ``ab09nd``: square-root balancing, then singular perturbation of the weak
    states, so that ``G_r(0) = G(0)``) and ``control.hankel_singular_values``.

    Parameters
    ----------
    G : control.StateSpace
        Full continuous model, ``ny x nu`` (paper: 3x3, 39 states), controller V ->
        sensor V.
    order : int, default 10
        States of the reduced model (paper: 10).
    stability_margin : float, default 1e-8
        Poles with ``Re p >= -stability_margin * max(1, max|p|)`` are treated as the
        unstable part: they are kept unchanged (``ab09nd`` with
        ``alpha = -stability_margin * max(1, max|p|)``) and counted in ``order``.
    dc_rtol : float, default 1e-6
        Relative tolerance of the DC-gain check.

    Returns
    -------
    Reduction

    Raises
    ------
    ValueError
        Bad ``order``; a pole at (or numerically at) ``s = 0``, for which the DC gain
        is infinite and DC matching undefined; or more unstable/marginal poles than
        ``order``.

    Warns
    -----
    UserWarning
        When the full model has unstable or near-imaginary-axis poles (kept
        unreduced), when the DC gain is not matched to ``dc_rtol``, or when slycot
        returns fewer states than requested (the model is non-minimal).
    """
    ct = _ct()
    G = _as_ss("G", G)
    n = G.nstates
    if isinstance(order, bool) or not float(order).is_integer() or not 1 <= int(order) <= n:
        raise ValueError(f"order: expected an integer in [1, {n}] (full model order), got {order!r}")
    order = int(order)
    A = np.asarray(G.A, dtype=float)
    poles = np.linalg.eigvals(A)
    rho = max(1.0, float(np.max(np.abs(poles))) if n else 1.0)
    alpha = -stability_margin * rho
    at_origin = np.abs(poles) <= max(stability_margin * rho, 1e-12)
    if np.any(at_origin):
        raise ValueError(
            f"G: the full model has {int(at_origin.sum())} pole(s) at s ~ 0 (|p| <= {stability_margin * rho:.2g} rad/s), "
            f"e.g. an integrator or drift left by the identification. Its DC gain is infinite, so "
            f"DC-matched balanced truncation is undefined. Remove the pole (e.g. refit with a stable "
            f"model, or shift it to s = -eps) before reducing.")
    unstable = poles[poles.real >= alpha]
    n_unst = int(unstable.size)
    if n_unst:
        warnings.warn(
            f"G has {n_unst} unstable or near-imaginary-axis pole(s) (Re p >= {alpha:.3g} rad/s): "
            f"{np.array2string(unstable, precision=4)}; they are kept unreduced and only the stable part "
            f"is balanced and truncated. Check the identified model.", UserWarning, stacklevel=2)
        if n_unst > order:
            raise ValueError(
                f"G: the full model has {n_unst} unstable/marginal poles but order={order}; the reduced "
                f"order must be at least {n_unst} because unstable poles cannot be truncated")
    Gr = ct.balanced_reduction(G, order, method="matchdc", alpha=alpha)
    Gr = ct.ss(Gr.A, Gr.B, Gr.C, Gr.D)
    if Gr.nstates != order:
        warnings.warn(f"balanced_reduction returned {Gr.nstates} states instead of {order} (the full model is "
                      f"non-minimal: fewer than {order} Hankel singular values are nonzero)", UserWarning, stacklevel=2)
    if n_unst == 0:
        hsv = np.real(np.asarray(ct.hankel_singular_values(G), dtype=complex))
    else:
        from slycot import ab09nd
        m, p = G.ninputs, G.noutputs
        out = ab09nd("C", "B", "N", n, m, p, A, np.asarray(G.B, float), np.asarray(G.C, float),
                     np.asarray(G.D, float), alpha=alpha, nr=order, tol1=0.0, tol2=0.0)
        hsv = np.asarray(out[-1], dtype=float)[: n - n_unst]
    hsv = np.sort(np.clip(hsv, 0.0, None))[::-1]
    dc_full, dc_red = _dc_gain(G), _dc_gain(Gr)
    scale = float(np.max(np.abs(dc_full))) or 1.0
    rel = float(np.max(np.abs(dc_red - dc_full)) / scale)
    if rel > dc_rtol:
        warnings.warn(f"reduced DC gain differs from the full one by {rel:.3g} (relative) > {dc_rtol:g}",
                      UserWarning, stacklevel=2)
    kept_stable = max(Gr.nstates - n_unst, 0)
    bound = float(2.0 * np.sum(hsv[kept_stable:]))
    red_stable = bool(_max_real_pole(Gr.A) < 0) if Gr.nstates else True
    return Reduction(G_full=G, G_reduced=Gr, full_order=n, order=int(Gr.nstates), hankel_sv=hsv,
                     n_unstable=n_unst, unstable_poles=unstable, dc_gain_full=dc_full, dc_gain_reduced=dc_red,
                     dc_gain_rel_error=rel, dc_gain_matched=rel <= dc_rtol, error_bound_hinf=bound,
                     reduced_stable=red_stable)


@_blas_single_threaded
def multiplicative_uncertainty(G_full, G_nom, freq_hz) -> np.ndarray:
    """Largest singular value of the output multiplicative error (paper Fig. 10).

    ``G_P = (I + E_o) G``  =>  ``E_o = (G_P - G) G^-1`` with ``G_P = G_full`` (the
    "actual" plant) and ``G = G_nom`` (reduced, nominal).

    Parameters
    ----------
    G_full, G_nom : control.StateSpace
        Square ``n x n`` continuous models with the same dimensions.
    freq_hz : array_like, shape (F,)
        Frequencies [Hz].

    Returns
    -------
    ndarray, shape (F,)
        ``sigma_max(E_o(j 2 pi f))`` [dimensionless]; ``inf`` where ``G_nom`` is
        singular.
    """
    G_full = _as_ss("G_full", G_full)
    G_nom = _as_ss("G_nom", G_nom)
    if G_nom.noutputs != G_nom.ninputs:
        raise ValueError(f"G_nom: E_o needs a square plant, got {G_nom.noutputs}x{G_nom.ninputs}")
    if (G_full.noutputs, G_full.ninputs) != (G_nom.noutputs, G_nom.ninputs):
        raise ValueError(f"G_full is {G_full.noutputs}x{G_full.ninputs} but G_nom is {G_nom.noutputs}x{G_nom.ninputs}")
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if f.ndim != 1 or not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ValueError("freq_hz: expected a 1-D array of finite frequencies >= 0 Hz")
    Gp, G0 = freqresp(G_full, f), freqresp(G_nom, f)
    out = np.full(f.size, np.inf)
    for k in range(f.size):
        try:
            # E G0 = (Gp - G0)  =>  G0^T E^T = (Gp - G0)^T
            E = np.linalg.solve(G0[k].T, (Gp[k] - G0[k]).T).T
            out[k] = np.linalg.norm(E, 2)
        except np.linalg.LinAlgError:
            pass
    return out


# =====================================================================================
# 4.2 generalized plant and H-infinity assumptions
# =====================================================================================
@dataclass(frozen=True)
class AssumptionReport:
    """Outcome of :func:`check_assumptions`.

    Attributes
    ----------
    ok : bool
        All standard H-infinity assumptions hold.
    failures : tuple of str
        One plain-language sentence per failed assumption.
    """

    ok: bool
    failures: tuple[str, ...] = ()

    @property
    def message(self) -> str:
        if self.ok:
            return "all H-infinity assumptions hold"
        return "H-infinity assumptions violated:\n- " + "\n- ".join(self.failures)


def _fmt_s(p: complex) -> str:
    p = complex(p)
    if abs(p.imag) < 1e-12 * max(1.0, abs(p)):
        return f"s = {p.real:.4g} rad/s"
    return f"s = {p.real:.3g} {'+' if p.imag >= 0 else '-'} {abs(p.imag):.4g}j rad/s ({abs(p.imag) / (2 * np.pi):.4g} Hz)"


def _feedthrough_rank(M) -> int:
    """Numerical rank of a feedthrough block: singular values above ``sqrt(eps) * max(1, sigma_max)``."""
    sv = np.linalg.svd(M, compute_uv=False) if M.size else np.zeros(0)
    return int(np.sum(sv > np.sqrt(np.finfo(float).eps) * max(1.0, sv.max(initial=0.0))))


def _on_axis(p, rtol):
    return abs(p.real) <= rtol * max(1.0, abs(p))


def _axis_zeros(A, B2, C1, D12, axis_rtol, tol, smin) -> list:
    """Imaginary-axis zeros of ``[A - sI, B2; C1, D12]`` (D12 full column rank): the
    eigenvalues ``q`` (Im q >= 0) of ``A - B2 D12^+ C1`` on the axis where
    ``[A - B2 D12^+ C1 - qI; (I - D12 D12^+) C1]`` loses column rank."""
    n = A.shape[0]
    D12p = np.linalg.pinv(D12)
    At = A - B2 @ D12p @ C1
    Cp = C1 - D12 @ (D12p @ C1)          # (I - D12 D12^+) C1
    return [q for q in np.linalg.eigvals(At)
            if q.imag >= 0 and _on_axis(q, axis_rtol) and smin(np.vstack([At - q * np.eye(n), Cp])) <= tol]


def check_assumptions(P, nmeas: int, ncon: int, *, rtol: float = 1e-10, axis_rtol: float = 1e-8,
                      raise_on_failure: bool = True) -> AssumptionReport:
    """Check the standard H-infinity assumptions on a generalized plant.

    ``P`` maps ``[w; u] -> [z; v]`` with the last ``ncon`` inputs being the control
    ``u`` and the last ``nmeas`` outputs the measurements ``v``; partition
    ``B = [B1 B2]``, ``C = [C1; C2]``, ``D = [[D11, D12], [D21, D22]]``. The
    conditions are those of slycot ``sb10ad`` (Glover & Doyle, 1988):

    (A1) ``(A, B2)`` stabilizable and ``(C2, A)`` detectable;
    (A2) ``D12`` full column rank and ``D21`` full row rank;
    (A3) ``[A - jwI, B2; C1, D12]`` full column rank for all ``w`` (no
         imaginary-axis zeros of the ``u -> z`` block P12);
    (A4) ``[A - jwI, B1; C2, D21]`` full row rank for all ``w`` (no
         imaginary-axis zeros of the ``w -> v`` block P21).

    In the mixed-sensitivity plant of ``control.augw`` a plant or weight pole on
    the imaginary axis (e.g. a weight integrator) breaks (A1) detectability and/or
    (A4), and a strictly proper plant without a constant ``Wu`` breaks (A2).

    Parameters
    ----------
    P : control.StateSpace
        Generalized plant (continuous).
    nmeas, ncon : int
        Number of measurements (controller inputs) and controls (controller outputs).
    rtol : float, default 1e-10
        Rank tolerance relative to the norm of ``[A B; C D]`` for the PBH tests.
    axis_rtol : float, default 1e-8
        ``p`` is on the imaginary axis when ``|Re p| <= axis_rtol * max(1, |p|)``.
    raise_on_failure : bool, default True
        Raise ``ValueError`` with :attr:`AssumptionReport.message` on failure.

    Returns
    -------
    AssumptionReport
    """
    P = _as_ss("P", P)
    A, B, C, D = (np.asarray(getattr(P, k), dtype=float) for k in ("A", "B", "C", "D"))
    n, m, p = A.shape[0], B.shape[1], C.shape[0]
    for nm, v in (("nmeas", nmeas), ("ncon", ncon)):
        if isinstance(v, bool) or not float(v).is_integer() or v < 1:
            raise ValueError(f"{nm}: expected a positive integer, got {v!r}")
    nmeas, ncon = int(nmeas), int(ncon)
    nw, nz = m - ncon, p - nmeas
    if nw < nmeas or nz < ncon:
        raise ValueError(f"P: {m} inputs / {p} outputs cannot hold ncon={ncon} controls and nmeas={nmeas} "
                         f"measurements (need m - ncon >= nmeas and p - nmeas >= ncon)")
    B1, B2 = B[:, :nw], B[:, nw:]
    C1, C2 = C[:nz], C[nz:]
    D12, D21 = D[:nz, nw:], D[nz:, :nw]
    scale = max(1.0, float(np.linalg.norm(np.block([[A, B], [C, D]]), 2)))
    tol = rtol * scale
    fails: list[str] = []

    def smin(M):
        return float(np.linalg.svd(M, compute_uv=False)[-1]) if M.size else 0.0

    eig = np.linalg.eigvals(A) if n else np.zeros(0, complex)
    axis_poles = [q for q in eig if _on_axis(q, axis_rtol)]
    note = ""
    if axis_poles:
        note = (" It lies on the imaginary axis: a plant or weight pole there (e.g. an integrator 1/s in a "
                "weight) makes the H-infinity problem ill-posed; shift it slightly into the left half plane.")
    # (A1) stabilizability / detectability: PBH at closed-RHP eigenvalues
    for q in eig:
        if q.imag < 0 or not (q.real >= 0 or _on_axis(q, axis_rtol)):
            continue
        I = np.eye(n)
        if smin(np.hstack([A - q * I, B2])) <= tol:
            fails.append(f"(A1) (A, B2) is not stabilizable: the mode at {_fmt_s(q)} cannot be moved by the "
                         f"control inputs u." + (note if _on_axis(q, axis_rtol) else ""))
        if smin(np.vstack([A - q * I, C2])) <= tol:
            fails.append(f"(A1) (C2, A) is not detectable: the mode at {_fmt_s(q)} is invisible in the measured "
                         f"signals (weights act only on the performance outputs z, so an unstable or "
                         f"imaginary-axis weight pole is never seen by the controller)."
                         + (note if _on_axis(q, axis_rtol) else ""))
    # (A2) rank of D12, D21
    r12 = _feedthrough_rank(D12)
    if r12 < ncon:
        fails.append(f"(A2) D12 (high-frequency gain from u to z) has rank {r12} < {ncon} controls, i.e. not full "
                     f"column rank: some control direction is not penalized at high frequency. Give Wu a "
                     f"nonzero high-frequency gain (e.g. a constant such as the paper's Wu = 0.15).")
    r21 = _feedthrough_rank(D21)
    if r21 < nmeas:
        fails.append(f"(A2) D21 (feedthrough from w to the measurements) has rank {r21} < {nmeas} measurements, "
                     f"i.e. not full row rank: every measurement must be corrupted directly by an exogenous "
                     f"input (in mixed sensitivity, the reference in e = r - y).")
    # (A3) zeros of P12 on the imaginary axis (needs D12 full column rank)
    if r12 == ncon and n:
        for q in _axis_zeros(A, B2, C1, D12, axis_rtol, tol, smin):
            fails.append(f"(A3) the block P12 (u -> z) has a zero on the imaginary axis at {_fmt_s(q)}: "
                         f"[A - jwI, B2; C1, D12] loses column rank (a plant zero or an undamped pole/zero "
                         f"of Wp/Wt/Wu there).")
    # (A4) zeros of P21 on the imaginary axis (needs D21 full row rank)
    if r21 == nmeas and n:      # the dual of (A3): [A - jwI, B1; C2, D21]^T
        for q in _axis_zeros(A.T, C2.T, B1.T, D21.T, axis_rtol, tol, smin):
            fails.append(f"(A4) the block P21 (w -> v) has a zero on the imaginary axis at {_fmt_s(q)}: "
                         f"[A - jwI, B1; C2, D21] loses row rank. In mixed sensitivity this is a plant or "
                         f"weight pole on the imaginary axis (e.g. an integrator in Wp or in G).")
    report = AssumptionReport(ok=not fails, failures=tuple(fails))
    if fails and raise_on_failure:
        raise ValueError(report.message)
    return report


def generalized_plant(G, weights: Weights | Mapping | str | os.PathLike | None = None):
    """Mixed-sensitivity generalized plant ``P = augw(G, Wp I, Wu I, Wt I)``.

    Inputs ``[r (ny); u (nu)]``, outputs ``[Wp e; Wu u; Wt y; e]`` with
    ``e = r - G u``; see ``control.augw``. Weights are checked first
    (``ValueError`` naming a bad weight).
    """
    ct = _ct()
    G = _as_ss("G", G)
    W = Weights.coerce(weights)
    W.check()
    wp, wu, wt = W.statespace(G.noutputs, G.ninputs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        warnings.simplefilter("ignore", DeprecationWarning)
        return ct.augw(G, wp, wu, wt)


# =====================================================================================
# active damping (inner loop)
# =====================================================================================
@dataclass(frozen=True, eq=False)
class DampingLoop:
    """Inner active-damping loop ``u = Ky y`` (positive-feedback convention).

    ``Ky(s) = -c s wf^2 / (s^2 + 2 zeta_f wf s + wf^2) * G(0)^-1``: velocity
    feedback in decoupled (sensor) coordinates, low-passed at ``lowpass_hz``.
    For a mode ``G0 w1^2 / (s^2 + 2 zeta w1 s + w1^2)`` the feedback
    ``-c s`` adds ``c w1 / 2`` to its damping ratio (``s^2 + (2 zeta w1 + c w1^2) s
    + w1^2``), so ``c = 2 zeta_added / w1``. The low-pass lag (90 deg at
    ``lowpass_hz``) turns the feedback of the non-collocated second mode set
    (460-475 Hz) from destabilizing into damping. ``Ky(0) = 0``: no effect on
    static gain or creep.

    Attributes
    ----------
    Ky : control.StateSpace
        ``ny -> nu``, sensor V -> controller V.
    zeta_added : float
        Damping ratio added to the first mode (design value, dimensionless).
    mode_hz : float
        First lightly damped plant mode the gain is scaled for [Hz].
    lowpass_hz, lowpass_zeta : float
        Second-order low-pass corner [Hz] and its damping ratio.
    gain_c_s : float
        ``c`` in ``-c s`` [s].
    """

    Ky: Any
    zeta_added: float
    mode_hz: float
    lowpass_hz: float
    lowpass_zeta: float
    gain_c_s: float

    def to_dict(self) -> dict:
        return {"type": "band-limited velocity feedback, u = Ky y, Ky = -c s wf^2/(s^2 + 2 zf wf s + wf^2) G(0)^-1",
                "zeta_added": self.zeta_added, "mode_hz": self.mode_hz, "lowpass_hz": self.lowpass_hz,
                "lowpass_zeta": self.lowpass_zeta, "gain_c_s": self.gain_c_s}


def _first_lightly_damped_hz(G, zeta_max: float = 0.05, f_min_hz: float = 20.0) -> float:
    p = np.linalg.eigvals(np.asarray(G.A, float)) if G.nstates else np.array([])
    w = np.abs(p)
    ok = (p.imag > 0) & (w > 2 * np.pi * f_min_hz) & (-p.real < zeta_max * w)
    if not np.any(ok):
        raise ValueError(f"G: no lightly damped mode (zeta < {zeta_max}) above {f_min_hz} Hz to damp")
    return float(w[ok].min() / (2 * np.pi))


def damping_loop(G, zeta_added: float = 0.1, *, mode_hz: float | None = None, lowpass_hz: float = 400.0,
                 lowpass_zeta: float = 0.7) -> DampingLoop:
    """Band-limited velocity feedback that damps the first plant modes.

    Parameters
    ----------
    G : control.StateSpace
        Plant (controller V -> sensor V), square, stable DC gain.
    zeta_added : float, default 0.1
        Damping ratio to add to the first mode (> 0, <= 0.5).
    mode_hz : float, optional
        First mode [Hz]; default the lowest pole of ``G`` above 20 Hz with ``zeta < 0.05``.
    lowpass_hz : float, default 400
        Low-pass corner [Hz] (between the first and the second mode set).
    lowpass_zeta : float, default 0.7

    Returns
    -------
    DampingLoop
    """
    ct = _ct()
    G = _as_ss("G", G)
    if G.noutputs != G.ninputs:
        raise ValueError(f"G: expected a square plant, got {G.noutputs}x{G.ninputs}")
    for nm, v, lo, hi in (("zeta_added", zeta_added, 0.0, 0.5), ("lowpass_hz", lowpass_hz, 0.0, np.inf),
                          ("lowpass_zeta", lowpass_zeta, 0.0, 2.0)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and lo < v <= hi):
            raise ValueError(f"{nm}: expected a number in ({lo}, {hi}], got {v!r}")
    f1 = _first_lightly_damped_hz(G) if mode_hz is None else float(mode_hz)
    if not (math.isfinite(f1) and f1 > 0):
        raise ValueError(f"mode_hz: expected a positive frequency in Hz, got {mode_hz!r}")
    G0 = _dc_gain(G)
    cond = np.linalg.cond(G0)
    if cond > 1e8:
        raise ValueError(f"G: DC gain is singular (condition number {cond:.3g}); cannot decouple")
    w1, wf = 2 * np.pi * f1, 2 * np.pi * float(lowpass_hz)
    c = 2.0 * float(zeta_added) / w1
    n = G.noutputs
    Af = np.array([[0.0, 1.0], [-wf * wf, -2 * lowpass_zeta * wf]])     # x1' = x2; F = wf^2 x1 / ...
    A = np.kron(np.eye(n), Af)
    B = np.kron(np.eye(n), np.array([[0.0], [1.0]]))
    Cv = np.kron(np.eye(n), np.array([[0.0, -c * wf * wf]]))           # -c s wf^2 / (...)
    Ky = ct.ss(A, B, np.linalg.inv(G0) @ Cv, np.zeros((n, n)))
    return DampingLoop(Ky=Ky, zeta_added=float(zeta_added), mode_hz=f1, lowpass_hz=float(lowpass_hz),
                       lowpass_zeta=float(lowpass_zeta), gain_c_s=float(c))


def damped_plant(G, damping: DampingLoop | None):
    """``Gd = (I - G Ky)^-1 G``: the plant seen by the outer loop (``G`` if no damping)."""
    if damping is None or G is None:
        return G
    ct = _ct()
    G = _as_ss("G", G)
    Gd = ct.feedback(G, damping.Ky, sign=+1)
    Gd = ct.ss(np.asarray(Gd.A), np.asarray(Gd.B), np.asarray(Gd.C), np.asarray(Gd.D))
    if _max_real_pole(G.A) < 0 <= _max_real_pole(Gd.A):
        p = np.linalg.eigvals(np.asarray(Gd.A))
        bad = p[(p.real >= 0) & (p.imag >= 0)]
        raise ValueError(f"damping loop: it destabilizes the plant (closed-loop poles at "
                         f"{', '.join(f'{abs(q) / (2 * np.pi):.1f} Hz' for q in bad)}); the low-pass at "
                         f"{damping.lowpass_hz:g} Hz gives the wrong phase there -- move lowpass_hz or lower zeta_added")
    return Gd


# =====================================================================================
# loop functions and the Design result
# =====================================================================================
def loop_functions(G, K):
    """State-space ``S, T, KS`` for ``u = +K e``, ``e = r - y`` (see module docstring).

    Returns
    -------
    S, T, KS : control.StateSpace
        ``(I + GK)^-1``, ``GK (I + GK)^-1`` (ny x ny) and ``K (I + GK)^-1`` (nu x ny).
        Each realization contains all plant and controller states, so its poles are
        the closed-loop poles.
    """
    ct = _ct()
    I = _static(np.eye(G.noutputs))
    L = ct.series(K, G)                     # L = G K
    S = ct.feedback(I, L, sign=-1)          # (I + L)^-1
    T = ct.feedback(L, I, sign=-1)          # L (I + L)^-1
    KS = ct.feedback(K, G, sign=-1)         # K (I + G K)^-1
    return S, T, KS


def _loop_freq(Gf, Kf):
    """Frequency-domain S, T, KS from stacks ``G(jw)`` (F, ny, nu), ``K(jw)`` (F, nu, ny)."""
    ny = Gf.shape[1]
    I = np.eye(ny)
    S = np.linalg.inv(I + Gf @ Kf)
    return S, I - S, Kf @ S


@dataclass(frozen=True, eq=False)
class LoopAnalysis:
    """Closed-loop figures of one plant with the designed controller.

    Attributes
    ----------
    stable : bool
        All closed-loop poles have ``Re < 0``.
    max_real_pole : float
        Largest closed-loop pole real part [rad/s].
    S_peak : float
        ``max_f sigma_max(S)`` on the refined grid [dimensionless].
    S_peak_hz : float
        Where it occurs [Hz].
    bandwidth_S_hz, bandwidth_T_hz, bandwidth_T_last_hz : float
        See ``BANDWIDTH_DEFINITIONS``.
    sigma_S, sigma_T, sigma_KS : ndarray, shape (F, ny)
        All singular values on ``Design.freq_hz``.
    T_f : ndarray, complex, shape (F, ny, ny)
        ``T(j 2 pi f)`` on the grid (for Bode plots).
    min_damping, min_damping_hz : float
        Smallest damping ratio ``-Re p / |p|`` of the closed-loop poles between
        ``MODE_BAND_HZ`` and its frequency [Hz] (how long a disturbance rings).
    """

    stable: bool
    max_real_pole: float
    S_peak: float
    S_peak_hz: float
    bandwidth_S_hz: float
    bandwidth_T_hz: float
    bandwidth_T_last_hz: float
    sigma_S: np.ndarray
    sigma_T: np.ndarray
    sigma_KS: np.ndarray
    T_f: np.ndarray
    min_damping: float = float("nan")
    min_damping_hz: float = float("nan")


MODE_BAND_HZ = (50.0, 1000.0)


def _min_damping(A, band_hz=MODE_BAND_HZ) -> tuple[float, float]:
    p = np.linalg.eigvals(np.asarray(A, float)) if np.size(A) else np.array([])
    f = np.abs(p) / (2 * np.pi)
    sel = (p.imag > 0) & (f >= band_hz[0]) & (f <= band_hz[1])
    if not np.any(sel):
        return float("nan"), float("nan")
    z = -p.real[sel] / np.abs(p[sel])
    i = int(np.argmin(z))
    return float(z[i]), float(f[sel][i])


def _analyse(G, K, f, S_ss=None) -> LoopAnalysis:
    if S_ss is None:
        S_ss = loop_functions(G, K)[0]
    mrp = _max_real_pole(S_ss.A)
    zmin, zmin_hz = _min_damping(S_ss.A)
    Gf, Kf = freqresp(G, f), freqresp(K, f)
    Sf, Tf, KSf = _loop_freq(Gf, Kf)
    sS, sT, sKS = _svals(Sf), _svals(Tf), _svals(KSf)

    def smax_S(ff):
        return _smax(_loop_freq(freqresp(G, ff), freqresp(K, ff))[0])

    peak, fpk = _refine_peak(smax_S, f, sS[:, 0])
    return LoopAnalysis(stable=bool(mrp < 0), max_real_pole=mrp, S_peak=peak, S_peak_hz=fpk,
                        bandwidth_S_hz=_crossing(f, sS[:, 0], INV_SQRT2, rising=True),
                        bandwidth_T_hz=_crossing(f, sT[:, 0], INV_SQRT2, rising=False),
                        bandwidth_T_last_hz=_crossing(f, sT[:, 0], INV_SQRT2, rising=False, first=False),
                        sigma_S=sS, sigma_T=sT, sigma_KS=sKS, T_f=Tf, min_damping=zmin, min_damping_hz=zmin_hz)


def stack_inputs(K, Ky):
    """``[K, Ky]`` with inputs ``[e; y]`` and summed outputs (block-diagonal states);
    continuous or discrete (``K.dt``)."""
    from scipy.linalg import block_diag
    A = block_diag(np.asarray(K.A), np.asarray(Ky.A))
    B = block_diag(np.asarray(K.B), np.asarray(Ky.B))
    C = np.hstack([np.asarray(K.C), np.asarray(Ky.C)])
    D = np.hstack([np.asarray(K.D), np.asarray(Ky.D)])
    return _ct().ss(A, B, C, D, K.dt)


def feedback_operator(K2, n_error: int):
    """Error-sign feedback operator ``K - Ky`` of a stacked ``[K, Ky]`` (``u = K r - (K - Ky) y``);
    ``K2`` itself if it has no measurement inputs."""
    if K2.ninputs == n_error:
        return K2
    B, D = np.asarray(K2.B), np.asarray(K2.D)
    return _ct().ss(K2.A, B[:, :n_error] - B[:, n_error:], K2.C, D[:, :n_error] - D[:, n_error:], K2.dt)


@dataclass(frozen=True, eq=False)
class Design:
    """Result of :func:`design_hinf` (paper Sec. 4.2, Figs. 11-13, 18, 21-22).

    Attributes
    ----------
    K : control.StateSpace
        Continuous controller, ``nu x ny`` (error sensor V -> controller V), used
        as ``u = +K e`` with ``e = r - y``.
    gamma : float
        Bound ``|| [Wp S; Wu KS; Wt T] ||_inf <= gamma`` of the returned controller
        (slycot ``sb10ad``; paper: 1.34). Equals ``gamma_opt`` unless ``gamma_relax > 0``.
    gamma_opt : float
        Smallest gamma found by the ``sb10ad`` bisection.
    gamma_grid : float
        Same norm evaluated on ``freq_hz`` (a check; ``<= gamma`` up to grid error).
    controller_order : int
        States of K (= plant order + weight states; paper 10 + 9 = 19).
    weights : Weights
    G_nominal, G_full, G_twin : control.StateSpace or None
        Design (reduced) model, full model and optional independent "twin" plant.
    P : control.StateSpace
        Generalized plant passed to ``hinfsyn``.
    S, T, KS : control.StateSpace
        Nominal loop functions (see :func:`loop_functions`). Their realizations
        contain the controller's fastest pole (~4e11 rad/s for the optimal
        paper-like design), which makes slycot ``tb05ad`` frequency responses of
        these closed-loop models inaccurate (seen: 2.7 instead of 3.5 at a peak).
        All frequency data in ``nominal``/``full``/``twin`` are therefore computed
        from ``G(jw)`` and ``K(jw)`` as ``(I + G K)^-1``; use ``gamma_relax`` for a
        better-conditioned controller.
    freq_hz : ndarray, shape (F,)
        Analysis grid [Hz] (log grid densified near lightly damped poles).
    nominal, full, twin : LoopAnalysis or None
        Closed-loop analysis with each plant.
    rcond : ndarray, shape (4,)
        sb10ad reciprocal condition numbers (control/measurement transformations,
        X- and Y-Riccati equations).
    sign_convention : str
    reduction : Reduction or None
        Set by :func:`run_design`.
    discretization : Discretization or None
        Set by :func:`run_design`.
    damping : DampingLoop or None
        Inner damping loop; then ``G_nominal``, ``G_full`` and ``G_twin`` are the
        damped plants ``(I - G Ky)^-1 G`` and ``K`` is the outer (tracking) controller.
    """

    K: Any
    gamma: float
    gamma_opt: float
    gamma_grid: float
    controller_order: int
    weights: Weights
    G_nominal: Any
    G_full: Any
    G_twin: Any
    P: Any
    S: Any
    T: Any
    KS: Any
    freq_hz: np.ndarray
    nominal: LoopAnalysis
    full: LoopAnalysis | None
    twin: LoopAnalysis | None
    rcond: np.ndarray
    sign_convention: str = SIGN_CONVENTION
    reduction: "Reduction | None" = None
    discretization: "Discretization | None" = None
    damping: "DampingLoop | None" = None

    def feedback_controller(self):
        """``u = -K_fb y`` part of the loop (``K - Ky``; ``K`` without damping), error sign."""
        return feedback_operator(self.controller_2dof(), self.K.ninputs)

    def controller_2dof(self):
        """``[K, Ky]``: inputs ``[e; y]`` (sensor V) -> ``u`` (controller V); ``K`` without damping."""
        return self.K if self.damping is None else stack_inputs(self.K, self.damping.Ky)

    # convenience accessors (paper quantities)
    @property
    def S_peak_nominal(self) -> float:
        """``||S||_inf`` with the nominal model (paper: < 1.45)."""
        return self.nominal.S_peak

    @property
    def S_peak_full(self) -> float:
        """``||S||_inf`` with the full model (paper: < 1.85); NaN without ``G_full``."""
        return self.full.S_peak if self.full is not None else float("nan")

    @property
    def bandwidth_S_hz(self) -> float:
        """Nominal S bandwidth [Hz] (paper: 32 Hz)."""
        return self.nominal.bandwidth_S_hz

    @property
    def bandwidth_T_hz(self) -> float:
        """Nominal T bandwidth [Hz] (paper: 59 Hz)."""
        return self.nominal.bandwidth_T_hz

    @property
    def stable_nominal(self) -> bool:
        return self.nominal.stable

    @property
    def stable_full(self) -> bool | None:
        return None if self.full is None else self.full.stable

    @property
    def stable_twin(self) -> bool | None:
        return None if self.twin is None else self.twin.stable

    def sigma_S_at(self, freq_hz: float, which: str = "nominal") -> float:
        """``sigma_max(S(j 2 pi f))`` for the nominal or full plant."""
        G = self.G_nominal if which == "nominal" else self.G_full
        f = np.array([float(freq_hz)])
        return float(_smax(_loop_freq(freqresp(G, f), freqresp(self.K, f))[0])[0])

    def summary(self) -> dict:
        """JSON-ready scalars."""
        def la(a: LoopAnalysis | None, key):
            return None if a is None else getattr(a, key)
        return {
            "gamma": self.gamma, "gamma_opt": self.gamma_opt, "gamma_grid_check": self.gamma_grid,
            "controller_fastest_pole_rad_s": float(np.max(np.abs(np.linalg.eigvals(self.K.A))))
            if self.K.nstates else 0.0,
            "controller_order": self.controller_order,
            "plant_order_nominal": int(self.G_nominal.nstates),
            "S_peak_nominal": self.S_peak_nominal, "S_peak_nominal_hz": self.nominal.S_peak_hz,
            "S_peak_full": la(self.full, "S_peak"), "S_peak_full_hz": la(self.full, "S_peak_hz"),
            "S_peak_twin": la(self.twin, "S_peak"), "S_peak_twin_hz": la(self.twin, "S_peak_hz"),
            "bandwidth_S_hz": self.bandwidth_S_hz, "bandwidth_T_hz": self.bandwidth_T_hz,
            "bandwidth_T_last_hz": self.nominal.bandwidth_T_last_hz,
            "bandwidth_S_full_hz": la(self.full, "bandwidth_S_hz"),
            "bandwidth_T_full_hz": la(self.full, "bandwidth_T_hz"),
            "sigma_S_1hz_nominal": self.sigma_S_at(1.0),
            "stable_nominal": self.stable_nominal, "stable_full": self.stable_full, "stable_twin": self.stable_twin,
            "max_real_pole_nominal_rad_s": self.nominal.max_real_pole,
            "max_real_pole_full_rad_s": la(self.full, "max_real_pole"),
            "max_real_pole_twin_rad_s": la(self.twin, "max_real_pole"),
            "sb10ad_rcond": [float(x) for x in self.rcond],
            "damping_loop": None if self.damping is None else self.damping.to_dict(),
            "closed_loop_min_damping_nominal": self.nominal.min_damping,
            "closed_loop_min_damping_nominal_hz": self.nominal.min_damping_hz,
            "closed_loop_min_damping_twin": la(self.twin, "min_damping"),
            "closed_loop_min_damping_twin_hz": la(self.twin, "min_damping_hz"),
            "sign_convention": self.sign_convention,
            "bandwidth_definitions": BANDWIDTH_DEFINITIONS,
        }


@_blas_single_threaded
def design_hinf(G_nominal, weights: Weights | Mapping | str | os.PathLike | None = None, G_full=None, G_twin=None,
                *, gamma_relax: float = 0.0, f_min_hz: float = 0.01, f_max_hz: float = 5000.0) -> Design:
    """Mixed-sensitivity H-infinity design (paper Sec. 4.2).

    Minimizes ``gamma = || [Wp S; Wu K S; Wt T] ||_inf`` over stabilizing K with
    ``control.augw`` + ``control.hinfsyn`` (slycot ``sb10ad``; identical to
    ``control.mixsyn(G, w1=Wp, w2=Wu, w3=Wt)``) after checking weights, plant and
    the generalized plant (:func:`check_assumptions`).

    Parameters
    ----------
    G_nominal : control.StateSpace
        Design model, ``ny x nu`` (paper: reduced 10-state 3x3), controller V ->
        sensor V.
    weights : Weights, mapping, path or None
        ``None`` = paper weights.
    G_full : control.StateSpace, optional
        Full model for the "perturbed" S (paper Fig. 12b) and stability check.
    G_twin : control.StateSpace, optional
        Independent plant (e.g. the simulator's linearization) for a stability check.
    gamma_relax : float, default 0.0
        0 returns the (near-)optimal central controller of ``hinfsyn``/``mixsyn``.
        ``r > 0`` re-runs slycot ``sb10ad`` in "suboptimal" mode (``job=4``) at
        ``gamma = (1 + r) * gamma_opt``. Near the optimum the central controller has
        a pole racing to infinity (about 4e11 rad/s on the paper-like plant); with
        ``r = 0.01`` its fastest pole drops to ~2e4 rad/s and the full-model S peak
        roughly halves, at the price of 1 % in gamma.
    f_min_hz, f_max_hz : float
        Analysis range [Hz].

    Returns
    -------
    Design

    Raises
    ------
    ValueError
        Bad weight (named), plant pole on the imaginary axis, or a violated
        H-infinity assumption (plain-language message), all before slycot is called.
    RuntimeError
        slycot fails for another (numerical) reason.
    """
    ct = _ct()
    G = _as_ss("G_nominal", G_nominal)
    ny, nu = G.noutputs, G.ninputs
    for nm, g in (("G_full", G_full), ("G_twin", G_twin)):
        if g is not None:
            g = _as_ss(nm, g)
            if (g.noutputs, g.ninputs) != (ny, nu):
                raise ValueError(f"{nm} is {g.noutputs}x{g.ninputs} but G_nominal is {ny}x{nu}")
    G_full = None if G_full is None else _as_ss("G_full", G_full)
    G_twin = None if G_twin is None else _as_ss("G_twin", G_twin)
    W = Weights.coerce(weights)
    W.check()
    for q in (np.linalg.eigvals(np.asarray(G.A, float)) if G.nstates else []):
        if _on_axis(q, AXIS_RTOL * 10):
            raise ValueError(
                f"G_nominal has a pole on the imaginary axis at {_fmt_s(q)}. In the mixed-sensitivity "
                f"set-up the reference does not drive the plant states, so this pole becomes an "
                f"imaginary-axis zero of P21 (assumption A4 fails). Shift it slightly into the left half "
                f"plane (e.g. 1/s -> 1/(s + eps)) before designing.")
    P = generalized_plant(G, W)
    check_assumptions(P, nmeas=ny, ncon=nu)
    try:
        from slycot.exceptions import SlycotError
    except ImportError:  # pragma: no cover
        SlycotError = Exception
    if not (isinstance(gamma_relax, (int, float)) and math.isfinite(gamma_relax) and gamma_relax >= 0):
        raise ValueError(f"gamma_relax: expected a finite number >= 0, got {gamma_relax!r}")
    try:
        K, CL, gamma_opt, rcond = ct.hinfsyn(P, ny, nu)
        gamma = gamma_opt
        if gamma_relax > 0:
            from slycot import sb10ad
            gamma = (1.0 + float(gamma_relax)) * float(gamma_opt)
            out = sb10ad(P.nstates, P.ninputs, P.noutputs, nu, ny, gamma, np.asarray(P.A, float),
                         np.asarray(P.B, float), np.asarray(P.C, float), np.asarray(P.D, float), job=4)
            K = ct.ss(out[1], out[2], out[3], out[4])
            rcond = out[9]
    except SlycotError as exc:
        raise RuntimeError(f"H-infinity synthesis (slycot sb10ad) failed although the assumption check passed: "
                           f"{exc}") from None
    K = ct.ss(np.asarray(K.A), np.asarray(K.B), np.asarray(K.C), np.asarray(K.D))
    S, T, KS = loop_functions(G, K)
    S_full = loop_functions(G_full, K)[0] if G_full is not None else None
    S_twin = loop_functions(G_twin, K)[0] if G_twin is not None else None
    # grid densified near open- and closed-loop lightly damped poles of every plant
    f = analysis_grid_hz([G, G_full, G_twin, K, S, S_full, S_twin], f_min_hz, f_max_hz)
    nominal = _analyse(G, K, f, S)
    full = _analyse(G_full, K, f, S_full) if G_full is not None else None
    twin = _analyse(G_twin, K, f, S_twin) if G_twin is not None else None
    # gamma check on the grid: sigma_max of the stacked weighted closed loop
    Gf, Kf = freqresp(G, f), freqresp(K, f)
    Sf, Tf, KSf = _loop_freq(Gf, Kf)
    blocks = [getattr(W, nm).freqresp(f)[:, None, None] * X
              for nm, X in (("Wp", Sf), ("Wu", KSf), ("Wt", Tf)) if getattr(W, nm) is not None]
    gamma_grid = float(_smax(np.concatenate(blocks, axis=1)).max())
    return Design(K=K, gamma=float(gamma), gamma_opt=float(gamma_opt), gamma_grid=gamma_grid,
                  controller_order=int(K.nstates), weights=W,
                  G_nominal=G, G_full=G_full, G_twin=G_twin, P=P, S=S, T=T, KS=KS, freq_hz=f,
                  nominal=nominal, full=full, twin=twin, rcond=np.asarray(rcond, dtype=float))


# =====================================================================================
# discretization
# =====================================================================================
DISCRETIZATION_METHODS = ("auto", "tustin", "tustin_prewarp", "tustin_modal", "foh", "zoh", "matched_fit")


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
        return float(self.errors_by_method.get("tustin", float("nan")))


def _check_grid_hz(K, f_max_hz: float) -> np.ndarray:
    parts = [np.array([0.0]), np.logspace(-3, np.log10(f_max_hz), 1500), np.linspace(0.5, f_max_hz, 3000)]
    parts.append(analysis_grid_hz([K], 1e-3, f_max_hz, n=10))
    f = np.unique(np.concatenate(parts))
    return f[f <= f_max_hz]


def discretization_error(K, Kd, f_max_hz: float = 500.0):
    """Relative frequency-response error of a discretized controller.

    Returns
    -------
    max_rel_error : float
        ``max sigma_max(Kd(e^{j w dt}) - K(j w)) / sigma_max(K(j w))`` over
        ``0 <= f <= f_max_hz`` (grid incl. f = 0 and dense points near
        lightly damped controller poles).
    worst_freq_hz : float
    freq_hz, rel_error : ndarray, shape (F,)
        The whole curve.
    """
    f = _check_grid_hz(K, f_max_hz)
    Hc, Hd = freqresp(K, f), freqresp(Kd, f)
    e = _smax(Hd - Hc) / np.maximum(_smax(Hc), 1e-300)
    i = int(np.argmax(e))
    return float(e[i]), float(f[i]), f, e


def _tustin_blocks(K, dt, prewarp: bool):
    """Tustin in block-diagonal (modal) coordinates; with ``prewarp`` each real
    Schur block (one real pole or one complex pair, |p| below 0.8 x Nyquist) gets
    its own prewarp frequency ``|p|``, so lightly damped controller poles keep
    their exact frequency."""
    ct = _ct()
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
    frequency weighted by ``1 / sigma_max(K(jw))`` (relative error)."""
    ct = _ct()
    from scipy.linalg import expm
    A, B, C = (np.asarray(getattr(K, k), float) for k in "ABC")
    n, nu, ny = A.shape[0], B.shape[1], C.shape[0]
    Ad, Cd = expm(A * dt), C.copy()
    f = np.unique(np.concatenate([[0.0], np.logspace(-3, np.log10(f_fit_hz), 1500),
                                  np.linspace(0.5, f_fit_hz, 3000), analysis_grid_hz([K], 1e-3, f_fit_hz, n=10)]))
    H = freqresp(K, f)                                         # (F, ny, nu)
    wgt = 1.0 / np.maximum(_smax(H), 1e-300)
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
    ct = _ct()
    nyq = 0.5 / dt
    if method == "tustin":
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


@_blas_single_threaded
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
    K = _as_ss("K", K)
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


def _error_rel_to_peak(K, Kd, f_max_hz: float) -> float:
    """``max_f sigma_max(Kd - K) / max_f sigma_max(K)`` on ``0..f_max_hz`` (for K with K(0) = 0)."""
    f = _check_grid_hz(K, f_max_hz)
    Hc = freqresp(K, f)
    return float(_smax(freqresp(Kd, f) - Hc).max() / max(_smax(Hc).max(), 1e-300))


def _dc_gain_discrete(Kd) -> np.ndarray:
    A = np.asarray(Kd.A, float)
    return np.asarray(Kd.D, float) + np.asarray(Kd.C) @ np.linalg.solve(np.eye(A.shape[0]) - A, np.asarray(Kd.B))


def discrete_closed_loop(Gd, Kd):
    """Sampled closed loop ``u(k) = Kd e(k)``, ``e = r - y``: returns
    ``(stable, spectral_radius)`` of the discrete ``S = (I + Gd Kd)^-1``."""
    ct = _ct()
    I = ct.ss(np.zeros((0, 0)), np.zeros((0, Gd.noutputs)), np.zeros((Gd.noutputs, 0)), np.eye(Gd.noutputs), Gd.dt)
    S = ct.feedback(I, ct.series(Kd, Gd), sign=-1)
    rho = float(np.max(np.abs(np.linalg.eigvals(S.A)))) if S.nstates else 0.0
    return bool(rho < 1.0), rho


# =====================================================================================
# figures (matplotlib Figure objects, no pyplot state; saved by nanosim.fileio.save_figure)
# =====================================================================================
_IO = ("A", "B", "C")
_OUT = ("X", "Y", "Z")


def _fig(nrows=1, ncols=1, size=(8, 5), **kw):
    from matplotlib.figure import Figure
    fig = Figure(figsize=size, layout="constrained")
    axs = fig.subplots(nrows, ncols, squeeze=False, **kw)
    return fig, axs


def _names(n, base):
    return base if n == len(base) else tuple(f"{i + 1}" for i in range(n))


def plot_hankel(red: Reduction):
    """Hankel singular values, kept vs removed (paper Fig. 8)."""
    fig, ax = _fig(size=(8, 4.5))
    ax = ax[0, 0]
    h = red.hankel_sv
    k = len(red.hsv_kept)
    idx = np.arange(1, h.size + 1)
    hp = np.where(h > 0, h, np.nan)
    ax.bar(idx[:k], hp[:k], color="tab:blue", label=f"kept ({red.order} states)")
    ax.bar(idx[k:], hp[k:], color="tab:gray", label=f"removed ({h.size - k} states)")
    ax.set_yscale("log")
    ax.axvline(k + 0.5, color="k", ls="--", lw=1)
    ax.set_xlabel("state index of the balanced realization")
    ax.set_ylabel("Hankel singular value [sensor V / controller V]")
    ax.set_title(f"Hankel singular values of the {red.full_order}-state model (cf. paper Fig. 8)")
    pos = h[h > 0]
    if pos.size:
        ax.set_ylim(max(pos.min(), pos.max() * 1e-8) / 3, pos.max() * 3)
    ax.grid(True, which="both", alpha=0.3)
    txt = []
    if red.hsv_kept.size:
        txt.append(f"smallest kept: {red.hsv_kept.min():.3g}")
    if red.hsv_dropped.size:
        txt.append(f"largest removed: {red.hsv_dropped.max():.3g}")
    txt.append(f"H-inf error bound 2*sum(removed): {red.error_bound_hinf:.3g}")
    ax.text(0.98, 0.80, "\n".join(txt), transform=ax.transAxes, ha="right", va="top", fontsize=9,
            bbox=dict(boxstyle="round", fc="white", ec="0.7"))
    ax.legend(loc="upper right")
    return fig


def _bode_grid(title, curves, f, ylabel="magnitude [dB]", in_names=None, out_names=None, ylim=None, vlines=()):
    """3x3 magnitude grid; ``curves`` = list of (label, H (F, ny, nu), style dict)."""
    ny, nu = curves[0][1].shape[1:]
    fig, axs = _fig(ny, nu, size=(3.6 * nu + 1, 2.7 * ny + 0.8), sharex=True)
    in_names = in_names or _names(nu, _IO)
    out_names = out_names or _names(ny, _OUT)
    for i in range(ny):
        for j in range(nu):
            ax = axs[i, j]
            for label, H, st in curves:
                ax.semilogx(f, _db(np.abs(H[:, i, j])), label=label, **st)
            for v in vlines:
                ax.axvline(v, color="gray", ls=":", lw=0.8)
            ax.set_title(f"{in_names[j]} -> {out_names[i]}", fontsize=10)
            ax.grid(True, which="both", alpha=0.3)
            if ylim is not None:
                ax.set_ylim(*ylim)
            if j == 0:
                ax.set_ylabel(ylabel)
            if i == ny - 1:
                ax.set_xlabel("frequency [Hz]")
    axs[0, 0].legend(fontsize=8, loc="best")
    fig.suptitle(title)
    return fig


def plot_reduction_bode(red: Reduction, f=None):
    """Full vs reduced model magnitude, 3x3 grid (paper Fig. 9)."""
    f = analysis_grid_hz([red.G_full], 1.0, 2000.0, 1200) if f is None else f
    return _bode_grid(f"Full ({red.full_order} states, solid) vs reduced ({red.order} states, dashed) model; "
                      f"controller V -> sensor V (cf. paper Fig. 9)",
                      [("full", freqresp(red.G_full, f), dict(color="tab:blue", lw=1.2)),
                       ("reduced", freqresp(red.G_reduced, f), dict(color="tab:red", ls="--", lw=1.2))],
                      f, ylabel="|G| [dB, sensor V/controller V]")


def plot_uncertainty(red: Reduction, f=None):
    """sigma_max(E_o) of the reduction error (paper Fig. 10b)."""
    f = analysis_grid_hz([red.G_full, red.G_reduced], 1.0, 2000.0, 1500) if f is None else f
    e = multiplicative_uncertainty(red.G_full, red.G_reduced, f)
    fig, ax = _fig(size=(8, 4.5))
    ax = ax[0, 0]
    ax.semilogx(f, _db(e), color="tab:blue", label=r"$\bar\sigma(E_o)$, $E_o=(G_P-G)G^{-1}$")
    ax.axhline(-20, color="tab:green", ls="--", lw=1, label="-20 dB (paper: below this under 140 Hz)")
    ax.axhline(0, color="tab:red", ls="--", lw=1, label="0 dB (paper: above this over 600 Hz)")
    for v in (140, 600):
        ax.axvline(v, color="gray", ls=":", lw=0.8)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("largest singular value [dB]")
    ax.set_title("Output multiplicative uncertainty from model reduction (cf. paper Fig. 10)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    finite = e[np.isfinite(e) & (e > 0)]
    if finite.size:
        ax.set_ylim(max(_db(finite.min()) - 5, -120), _db(finite.max()) + 10)
    return fig


def plot_weights(W: Weights, f=None):
    """|Wp|, |Wt|, |Wu| and the bounds 1/|W| (paper Fig. 11b)."""
    f = np.logspace(-3, 6, 900) if f is None else f
    fig, axs = _fig(1, 2, size=(12, 4.5))
    cols = {"Wp": "tab:blue", "Wt": "tab:red", "Wu": "tab:green"}
    for nm in ("Wp", "Wt", "Wu"):
        if getattr(W, nm) is None:
            continue
        m = np.abs(getattr(W, nm).freqresp(f))
        axs[0, 0].semilogx(f, _db(m), color=cols[nm], label=f"|{nm}|")
        axs[0, 1].semilogx(f, -_db(m), color=cols[nm], label=f"1/|{nm}|")
    axs[0, 0].set_title("weights")
    axs[0, 1].set_title("inverse weights = bounds on S, T, KS (at gamma = 1)")
    for ax in axs[0]:
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("magnitude [dB]")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.suptitle("Mixed-sensitivity weights (cf. paper Fig. 11b)")
    return fig


def _sv_panel(ax, f, sv, weight, gamma, label, bound_label, colors=("tab:blue", "tab:orange", "tab:green")):
    """Singular values (sigma_max thick) and, if ``weight`` is given, 1/|W| and gamma/|W|."""
    for k in range(sv.shape[1]):
        ax.semilogx(f, _db(sv[:, k]), color=colors[k % len(colors)], lw=2.2 if k == 0 else 1.0,
                    alpha=1.0 if k == 0 else 0.8, zorder=3 if k == 0 else 2,
                    label=(f"{label} sigma_{k + 1}" + (" (max)" if k == 0 else "")) if sv.shape[1] > 1 else label)
    if weight is not None:
        bound = 1.0 / np.abs(weight.freqresp(f))
        ax.semilogx(f, _db(bound), "k--", lw=1.2, label=f"1/|{bound_label}|")
        ax.semilogx(f, _db(gamma * bound), "k:", lw=1.2, label=f"gamma/|{bound_label}| (gamma = {gamma:.3g})")
    ax.set_xlabel("frequency [Hz]")
    ax.grid(True, which="both", alpha=0.3)


def plot_sensitivity(d: Design):
    """sigma(S) with nominal and full model vs the bound 1/|Wp| (paper Fig. 12)."""
    n = 2 if d.full is not None else 1
    fig, axs = _fig(1, n, size=(6.5 * n, 4.8), sharey=True)
    f = d.freq_hz
    panels = [("(a) nominal (reduced) model", d.nominal)]
    if d.full is not None:
        panels.append(("(b) full model", d.full))
    for ax, (ttl, la) in zip(axs[0], panels):
        _sv_panel(ax, f, la.sigma_S, d.weights.Wp, d.gamma, "S", "Wp")
        ax.axhline(_db(INV_SQRT2), color="gray", lw=0.8, ls="-.", label="-3 dB")
        ax.set_title(f"{ttl}: ||S||inf = {la.S_peak:.3f} ({_db(la.S_peak):.2f} dB) at {la.S_peak_hz:.0f} Hz",
                     fontsize=10)
        ax.set_ylim(-100, 20)
    axs[0, 0].set_ylabel("singular values of S [dB]")
    axs[0, 0].legend(fontsize=8, loc="lower right")
    fig.suptitle("Sensitivity S = (I + GK)^-1 (cf. paper Fig. 12)")
    return fig


def plot_T_KS(d: Design):
    """sigma(T) vs 1/|Wt| and sigma(KS) vs 1/|Wu| (paper Fig. 18a-b / 11b)."""
    fig, axs = _fig(1, 2, size=(13, 4.8))
    f = d.freq_hz
    _sv_panel(axs[0, 0], f, d.nominal.sigma_T, d.weights.Wt, d.gamma, "T nominal", "Wt")
    if d.full is not None:
        axs[0, 0].semilogx(f, _db(d.full.sigma_T[:, 0]), color="tab:purple", lw=1, alpha=0.8,
                           label="T full model sigma_max")
    axs[0, 0].set_ylim(-100, 30)
    axs[0, 0].set_ylabel("singular values of T [dB]")
    axs[0, 0].set_title("(a) complementary sensitivity T = GK(I+GK)^-1", fontsize=10)
    _sv_panel(axs[0, 1], f, d.nominal.sigma_KS, d.weights.Wu, d.gamma, "KS nominal", "Wu")
    axs[0, 1].set_ylabel("singular values of KS [dB, controller V / sensor V]")
    axs[0, 1].set_title("(b) control sensitivity KS = K(I+GK)^-1", fontsize=10)
    for ax in axs[0]:
        ax.legend(fontsize=8, loc="lower left")
    fig.suptitle("Closed-loop T and KS with their weight bounds (cf. paper Figs. 11b, 18)")
    return fig


def plot_closed_loop_bode(d: Design, f=None):
    """|T_ij| of the closed loop r -> y, 3x3 grid (paper Figs. 13, 21)."""
    f = analysis_grid_hz([d.G_nominal, d.G_full, d.K], 0.1, 2000.0, 1200) if f is None else f
    curves = [("nominal model", _loop_freq(freqresp(d.G_nominal, f), freqresp(d.K, f))[1],
               dict(color="tab:blue", lw=1.2))]
    if d.G_full is not None:
        curves.append(("full model", _loop_freq(freqresp(d.G_full, f), freqresp(d.K, f))[1],
                       dict(color="tab:red", ls="--", lw=1.0)))
    on = _names(d.G_nominal.noutputs, _OUT)
    return _bode_grid("Closed loop T: reference -> output (cf. paper Figs. 13, 21)", curves, f,
                      ylabel="|T| [dB]", in_names=tuple(f"r{x}" for x in on), out_names=on, ylim=(-100, 10))


def plot_controller_bode(d: Design, disc: Discretization | None = None, f=None):
    """|K_ij| continuous (and discrete), 3x3 grid (paper Fig. 22)."""
    nyq = 0.5 / disc.dt if disc is not None else 2000.0
    f = analysis_grid_hz([d.K], 0.01, 0.999 * nyq, 1500) if f is None else f
    curves = [("continuous K", freqresp(d.K, f), dict(color="tab:blue", lw=1.2))]
    if disc is not None:
        ny = d.G_nominal.noutputs
        curves.append((f"discrete ({disc.method}, {1 / disc.dt:.0f} Hz)", freqresp(disc.Kd, f)[:, :, :ny],
                       dict(color="tab:orange", ls="--", lw=1.0)))
    if d.damping is not None:
        curves.append(("damping loop Ky (y -> u)", freqresp(d.damping.Ky, f), dict(color="tab:green", lw=1.0)))
    on = _names(d.G_nominal.noutputs, _OUT)
    inn = _names(d.G_nominal.ninputs, _IO)
    return _bode_grid(f"Controller K ({d.controller_order} states): error -> command (cf. paper Fig. 22)", curves, f,
                      ylabel="|K| [dB, controller V/sensor V]", in_names=tuple(f"e{x}" for x in on),
                      out_names=tuple(f"u{x}" for x in inn), vlines=(500.0,))


# =====================================================================================
# run_design
# =====================================================================================
def _write_mat(path: Path, data: dict) -> Path:
    from scipy.io import savemat
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".mat", dir=path.parent)
    os.close(fd)
    try:
        savemat(tmp, data, do_compression=True, oned_as="row")
        os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)
    return path


def _load_model(path, name="model_npz"):
    ct = _ct()
    z = fileio.load_npz(path, required=("A", "B", "C", "D"))
    A, B, C, D = (np.atleast_2d(np.asarray(z[k], dtype=float)) for k in "ABCD")
    n = A.shape[0]
    if A.shape != (n, n) or B.shape[0] != n or C.shape[1] != n or D.shape != (C.shape[0], B.shape[1]):
        raise ValueError(f"{path}: inconsistent shapes A{A.shape} B{B.shape} C{C.shape} D{D.shape}")
    for k, v in (("A", A), ("B", B), ("C", C), ("D", D)):
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{path}: array {k} has NaN/inf entries")
    G = ct.ss(A, B, C, D)
    Gd = None
    if all(k in z for k in ("Ad", "Bd", "Cd", "Dd", "dt")):
        dt = float(np.asarray(z["dt"]).ravel()[0])
        Gd = ct.ss(*(np.atleast_2d(np.asarray(z[k], float)) for k in ("Ad", "Bd", "Cd", "Dd")), dt)
    return G, Gd


@_blas_single_threaded
def run_design(model_npz, out_dir, weights: Weights | Mapping | str | os.PathLike | None = None,
               reduced_order: int = 10, twin=None, progress: bool = True, *,
               dt: float | None = None, discretization: str = "auto", gamma_relax: float = 0.0,
               damping_zeta: float | None = None, damping_lowpass_hz: float = 400.0) -> Design:
    """Reduce, design, discretize and export (paper Sec. 4).

    Parameters
    ----------
    model_npz : path
        Identified model: continuous ``A, B, C, D`` (required; controller V ->
        sensor V) and optionally discrete ``Ad, Bd, Cd, Dd, dt``.
    out_dir : path
        Output directory (created). Files are written atomically.
    weights : Weights, mapping, .json/.toml path or None (paper weights)
    reduced_order : int, default 10
    twin : control.StateSpace or path to an ``.npz`` with ``A, B, C, D``, optional
        Independent plant for a closed-loop stability check.
    progress : bool, default True
        Print stage messages to stderr.
    dt : float, optional
        Controller sample time [s]; default the model's ``dt`` or 1/4000.
    discretization : str, default "auto"
        See :func:`discretize_controller`.
    gamma_relax : float, default 0.0
        See :func:`design_hinf` (0 = optimal central controller, as ``mixsyn``).
    damping_zeta : float, optional
        Add an inner damping loop (:func:`damping_loop`, built on the reduced model)
        that adds this damping ratio to the first mode; ``None`` = the paper's
        single loop. The controller then has inputs ``[e; y]`` (``n_error = 3``).
    damping_lowpass_hz : float, default 400
        Low-pass corner of the damping loop [Hz].

    Returns
    -------
    Design

    Writes
    ------
    ``controller.npz`` (``Ak, Bk, Ck, Dk`` continuous; ``Akd, Bkd, Ckd, Dkd, dt``
    discrete; string arrays ``units``, ``sign_convention``, ``method``),
    ``reduced_model.npz``, ``design.json``, ``design.mat`` and PNG figures
    ``fig08_hankel_sv``, ``fig09_reduction_bode``, ``fig10_uncertainty``,
    ``fig11b_weights``, ``fig12_sensitivity``, ``fig18_T_KS``,
    ``fig21_closed_loop_bode``, ``fig22_controller_bode``.
    """
    ct = _ct()
    say = _Progress(progress)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    G_full, Gd_full = _load_model(model_npz)
    say(f"loaded {model_npz}: {G_full.nstates} states, {G_full.noutputs}x{G_full.ninputs}")
    W = Weights.coerce(weights)
    W.check()
    G_twin = None
    if twin is not None:
        G_twin = _load_model(twin)[0] if isinstance(twin, (str, os.PathLike)) else _as_ss("twin", twin)
    if dt is None:
        dt = Gd_full.dt if Gd_full is not None else constants.CONTROL_PERIOD_S
    timings = {}
    t = time.perf_counter()
    red = reduce_model(G_full, reduced_order)
    timings["reduction_s"] = time.perf_counter() - t
    say(f"reduced to {red.order} states; DC gain rel. error {red.dc_gain_rel_error:.2e}; "
        f"HSV kept >= {red.hsv_kept.min() if red.hsv_kept.size else float('nan'):.3g}, "
        f"dropped <= {red.hsv_dropped.max() if red.hsv_dropped.size else 0:.3g}")
    dl = None
    if damping_zeta is not None:
        dl = damping_loop(red.G_reduced, damping_zeta, lowpass_hz=damping_lowpass_hz)
        say(f"damping loop: +{dl.zeta_added:g} damping at {dl.mode_hz:.1f} Hz, low-pass {dl.lowpass_hz:g} Hz")
    t = time.perf_counter()
    d = design_hinf(damped_plant(red.G_reduced, dl), W, G_full=damped_plant(G_full, dl),
                    G_twin=damped_plant(G_twin, dl), gamma_relax=gamma_relax)
    d = dataclasses.replace(d, damping=dl)
    timings["synthesis_and_analysis_s"] = time.perf_counter() - t
    say(f"H-infinity: gamma = {d.gamma:.4f}, controller order {d.controller_order}, "
        f"||S|| nominal {d.S_peak_nominal:.3f}, full {d.S_peak_full:.3f}, "
        f"BW S {d.bandwidth_S_hz:.1f} Hz, BW T {d.bandwidth_T_hz:.1f} Hz, stable full: {d.stable_full}")
    t = time.perf_counter()
    K2 = d.controller_2dof()
    disc = discretize_controller(d.K, dt, discretization)
    disc_y = None
    Kd2 = disc.Kd
    if dl is not None:
        # Tustin (per-mode prewarp) maps s = 0 to z = 1, so Ky_d(1) = Ky(0) = 0 exactly: a constant
        # reading (the Z probe's offset at home) must not leak into u through the damping loop.
        disc_y = discretize_controller(dl.Ky, dt, "tustin_modal")
        Kd2 = stack_inputs(disc.Kd, disc_y.Kd)
    timings["discretization_s"] = time.perf_counter() - t
    say(f"discretized at {1 / dt:.0f} Hz with {disc.method}: max rel. error below {disc.f_check_hz:.0f} Hz "
        f"= {disc.max_rel_error:.3g} (Tustin: {disc.tustin_max_rel_error:.3g})")
    Gd = Gd_full if (Gd_full is not None and abs(Gd_full.dt - dt) <= 1e-12 * dt) else ct.c2d(G_full, dt, "zoh")
    ny = G_full.noutputs
    stable_d, rho_d = discrete_closed_loop(Gd, feedback_operator(Kd2, ny))
    stable_d_tustin = None
    if disc.method != "tustin":
        stable_d_tustin = discrete_closed_loop(Gd, feedback_operator(ct.c2d(K2, dt, "tustin"), ny))[0]

    # --- uncertainty summary (paper Fig. 10 statements)
    fe = analysis_grid_hz([G_full, red.G_reduced], 1.0, 2000.0, 1500)
    eo = multiplicative_uncertainty(G_full, red.G_reduced, fe)
    eo_db = _db(eo)

    # --- artifacts
    Kd = Kd2
    io_units = (["u = Ck x + Dk e (continuous: dx/dt = Ak x + Bk e; discrete: x[k+1] = Akd x[k] + Bkd e[k])"]
                if dl is None else
                ["inputs [e; y]: e = r - y (n_error = 3 columns), then the measurement y in sensor volts",
                 "u = Ck x + Dk [e; y] (continuous: dx/dt = Ak x + Bk [e; y]; discrete likewise with Akd..Dkd)"])
    units = np.array(["e: tracking error r - y in sensor volts (X,Y,Z), 5 um/V",
                      "u: controller volts for actuators A,B,C (before the x20 amplifier)", *io_units,
                      "dt in seconds"])
    fileio.write_npz(out / "controller.npz", Ak=K2.A, Bk=K2.B, Ck=K2.C, Dk=K2.D,
                  Akd=Kd.A, Bkd=Kd.B, Ckd=Kd.C, Dkd=Kd.D, dt=np.float64(dt), gamma=np.float64(d.gamma),
                  n_error=np.int64(ny), units=units, sign_convention=np.array(SIGN_CONVENTION),
                  method=np.array(disc.method))
    fileio.write_npz(out / "reduced_model.npz", A=red.G_reduced.A, B=red.G_reduced.B, C=red.G_reduced.C,
                  D=red.G_reduced.D, hankel_sv=red.hankel_sv, units=np.array(UNITS["plant_G"]))
    mat = {"G_A": G_full.A, "G_B": G_full.B, "G_C": G_full.C, "G_D": G_full.D,
           "Gr_A": red.G_reduced.A, "Gr_B": red.G_reduced.B, "Gr_C": red.G_reduced.C, "Gr_D": red.G_reduced.D,
           "K_A": K2.A, "K_B": K2.B, "K_C": K2.C, "K_D": K2.D, "K_n_error": ny,
           "Kd_A": Kd.A, "Kd_B": Kd.B, "Kd_C": Kd.C, "Kd_D": Kd.D, "Ts": float(dt), "gamma": d.gamma,
           "hankel_sv": red.hankel_sv,
           "units": UNITS["plant_G"] + "; K: " + UNITS["controller_K"], "sign_convention": SIGN_CONVENTION}
    for nm in ("Wp", "Wt", "Wu"):
        w = getattr(W, nm)
        if w is not None:   # W(s) = (num/den)^power, descending powers of s
            mat.update({f"{nm}_num": np.array(w.num), f"{nm}_den": np.array(w.den), f"{nm}_power": w.power})
    _write_mat(out / "design.mat", mat)

    summary = d.summary()
    summary.update({
        "reduced_order": red.order, "full_order": red.full_order, "hankel_sv": red.hankel_sv,
        "hankel_sv_kept_min": float(red.hsv_kept.min()) if red.hsv_kept.size else None,
        "hankel_sv_dropped_max": float(red.hsv_dropped.max()) if red.hsv_dropped.size else None,
        "reduction_error_bound_hinf": red.error_bound_hinf,
        "dc_gain_rel_error": red.dc_gain_rel_error, "dc_gain_full": red.dc_gain_full,
        "dc_gain_reduced": red.dc_gain_reduced, "full_model_unstable_poles": int(red.n_unstable),
        "Eo_max_dB_below_140Hz": float(eo_db[fe <= 140].max()),
        "Eo_min_dB_above_600Hz": float(eo_db[fe >= 600].min()) if np.any(fe >= 600) else None,
        "Eo_max_dB": float(eo_db.max()), "Eo_peak_hz": float(fe[int(np.argmax(eo_db))]),
        "weights": W.to_dict(),
        "dt_s": float(dt), "discretization_method": disc.method,
        "discretization_max_rel_error_below_500hz": disc.max_rel_error if disc.f_check_hz == 500.0 else None,
        "discretization_max_rel_error": disc.max_rel_error, "discretization_check_band_hz": disc.f_check_hz,
        "discretization_worst_freq_hz": disc.worst_freq_hz,
        "discretization_errors_by_method": disc.errors_by_method,
        "tustin_max_rel_error_below_500hz": disc.tustin_max_rel_error,
        "discretization_within_1_percent": disc.within_tol,
        "damping_loop_discretization": None if disc_y is None else {
            "method": disc_y.method,
            "max_error_rel_to_peak_below_500hz": _error_rel_to_peak(dl.Ky, disc_y.Kd, 500.0),
            "dc_gain_abs_max": float(np.abs(_dc_gain_discrete(disc_y.Kd)).max())},
        "stable_discrete_full": stable_d, "spectral_radius_discrete_full": rho_d,
        "stable_discrete_full_with_plain_tustin": stable_d_tustin,
        "units": UNITS,
        "paper_targets": {"gamma": constants.PAPER_GAMMA, "controller_order": constants.PAPER_CONTROLLER_ORDER,
                          "S_peak_nominal_max": 1.45, "S_peak_full_model_max": 1.85,
                          "bandwidth_S_hz": 32.0, "bandwidth_T_hz": 59.0},
        "timings_s": timings, "gamma_relax": float(gamma_relax),
        "inputs": {"model_npz": str(model_npz),
                   "twin": None if twin is None else (str(twin) if isinstance(twin, (str, os.PathLike))
                                                      else f"StateSpace, {G_twin.nstates} states")},
    })
    try:
        import control as _c
        import slycot as _s
        summary["versions"] = {"control": _c.__version__, "slycot": _s.__version__, "numpy": np.__version__}
    except Exception:  # pragma: no cover
        pass
    fileio.write_json(out / "design.json", summary)

    say("writing figures")
    figs = {
        "fig08_hankel_sv.png": plot_hankel(red),
        "fig09_reduction_bode.png": plot_reduction_bode(red),
        "fig10_uncertainty.png": plot_uncertainty(red),
        "fig11b_weights.png": plot_weights(W),
        "fig12_sensitivity.png": plot_sensitivity(d),
        "fig18_T_KS.png": plot_T_KS(d),
        "fig21_closed_loop_bode.png": plot_closed_loop_bode(d),
        "fig22_controller_bode.png": plot_controller_bode(d, disc),
    }
    for name, fig in figs.items():
        fileio.save_figure(fig, out / name)
    say(f"done in {time.perf_counter() - t_start:.1f} s -> {out}")
    return dataclasses.replace(d, reduction=red, discretization=disc)
