"""Loop analysis of a MIMO feedback loop: closed-loop maps, disk margins, structured
singular value (mu) bounds, a parametric robust-stability check and pole damping.

Pure computation: imports only numpy, scipy and python-control (``import control as
ct``); no other ``nanosim`` module, so it can move into a subpackage unchanged.

Conventions
-----------
Plant and controller
    ``G`` is ``ny x nu`` (controller volts in, sensor volts out).  Negative feedback,
    ``e = r - y``.  The controller may be two-degree-of-freedom::

        u = K e + Ky y          K, Ky: nu x ny  (Ky may be None, i.e. zero)

    The *feedback operator* is ``Kfb = K - Ky``, so ``u = K r - Kfb y``.  Only ``Kfb``
    decides stability and margins; ``K`` alone enters the reference paths.
Loops
    ``Lo = G Kfb`` (broken at the plant output, ``ny x ny``) and ``Li = Kfb G`` (broken
    at the plant input, ``nu x nu``).
Closed-loop maps (all with the delayed plant ``Gd``, see *Delay*)
    ``S_o = (I + Lo)^-1``, ``T_o = Lo S_o = I - S_o``, ``S_i = (I + Li)^-1``,
    ``T_i = Li S_i = I - S_i``.
    ``KS = S_i K = (I + Kfb G)^-1 K``: reference ``r`` -> control ``u``.
    ``KS_fb = Kfb S_o``: output disturbance / sensor noise ``n`` -> ``-u``.
    ``SG = S_o G = G S_i``: input disturbance (added to ``u``) -> ``y``.
    ``T_ry = S_o G K``: reference -> output (equals ``T_o`` when ``Ky`` is None).
Shapes and units
    Frequency responses are complex arrays of shape ``(F, rows, cols)``, frequency
    first, everywhere.  Frequencies are in Hz (``freq_hz``); ``s = j 2 pi f``,
    ``z = exp(j 2 pi f dt)``.  Angles are in degrees, gains are factors unless a name
    ends in ``_db``.
Time base
    Systems may be continuous or discrete (``dt`` = control period, 250e-6 s on the
    stage).  All LTI arguments of one call must share the time base; static gains
    (arrays, scalars, state-less systems) fit either.  Discrete frequency grids must not
    exceed the Nyquist frequency ``1 / (2 dt)``.
Delay
    ``delay_samples = d`` (0, 1, ...) is a computation delay at the plant input, the
    same in every input channel: ``Gd = G z^-d`` for discrete plants and
    ``Gd = G exp(-s d dt)`` for continuous ones.  In *frequency responses* it is the
    exact factor ``exp(-j 2 pi f d dt)`` in both cases.  In *state space*
    (:func:`loop_transfer_ss`, stability checks, :func:`perturbed_plant`) a discrete
    plant gets ``d`` exact unit-delay states per input; a continuous plant gets a
    Pade approximant of order ``pade_order`` per input (an approximation).
Disk margins
    Seiler, Packard & Gahinet, "An Introduction to Disk Margins", IEEE Control Systems
    Magazine 40(5), 2020; MATLAB ``diskmargin``.  A loop factor ``f`` in the disk
    ``D(alpha, sigma) = {(1 + (1 - sigma)/2 delta) / (1 - (1 + sigma)/2 delta), |delta| <
    alpha}`` (skew ``sigma``, default 0 = symmetric) multiplies each broken channel.
    ``alpha = 1 / sup_f mu_Delta(S + (sigma - 1)/2 I)`` with ``Delta`` diagonal complex.
Structured singular value
    Blocks follow MATLAB's ``mussv`` convention: block ``(r, c)`` is a complex full
    ``Delta_i`` of size ``r x c``; ``M`` is ``(sum c) x (sum r)``; ``(1, 1)`` is a complex
    scalar.  Repeated scalar blocks are not supported.
"""
from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import control as ct
import numpy as np
import scipy.linalg
import scipy.optimize

__all__ = [
    "DiskMargin",
    "DiskMarginReport",
    "LeastDampedPole",
    "LoopResponse",
    "LoopStateSpace",
    "MuBounds",
    "RobustStabilityResult",
    "closed_loop_poles",
    "disk_gain_phase",
    "disk_margins",
    "frequency_response",
    "least_damped_pole",
    "loop_transfer_response",
    "loop_transfer_ss",
    "mu_lower_bound",
    "mu_upper_bound",
    "perturbed_plant",
    "robust_stability_mu",
    "robustness_summary",
    "sigma_max",
]

_LTI = (ct.StateSpace, ct.TransferFunction)


# =====================================================================================
# argument checking and time base
# =====================================================================================
def _is_lti(x) -> bool:
    return isinstance(x, _LTI)


def _is_static_lti(x) -> bool:
    """An LTI object without dynamics (fits either time base)."""
    if isinstance(x, ct.StateSpace):
        return x.nstates == 0
    return all(np.size(np.trim_zeros(np.atleast_1d(d), "f")) <= 1 and np.size(np.trim_zeros(np.atleast_1d(n), "f")) <= 1
               for row_n, row_d in zip(x.num, x.den) for n, d in zip(row_n, row_d))


def _describe(x) -> str:
    if _is_lti(x):
        return f"{type(x).__name__} with {x.noutputs} outputs, {x.ninputs} inputs, dt={x.dt!r}"
    if isinstance(x, np.ndarray):
        return f"ndarray of shape {x.shape} and dtype {x.dtype}"
    return f"{type(x).__name__} {x!r}"[:200]


def _check_system(name: str, x, *, allow_none: bool = False, allow_stack: bool = True):
    """Reject anything that is not an LTI system, a static gain or (optionally) a
    stack of frequency responses, before any computation.
    """
    if x is None:
        if allow_none:
            return
        raise TypeError(f"{name}: expected a control.StateSpace/TransferFunction or a gain "
                        f"matrix, got None")
    if _is_lti(x):
        return
    if isinstance(x, numbers.Number) and not isinstance(x, bool):
        return
    if isinstance(x, (np.ndarray, list, tuple)):
        a = np.asarray(x)
        if a.dtype.kind not in "biufc" or a.dtype.kind == "b":
            raise TypeError(f"{name}: expected numeric values, got {_describe(a)}")
        ok_dims = (0, 2, 3) if allow_stack else (0, 2)
        if a.ndim not in ok_dims:
            raise ValueError(f"{name}: expected a scalar, a 2-D gain matrix"
                             + (" or a (F, rows, cols) frequency-response stack" if allow_stack else "")
                             + f", got an array of shape {a.shape}")
        return
    raise TypeError(f"{name}: expected a control.StateSpace/TransferFunction or a gain matrix, "
                    f"got {_describe(x)}")


def _io_shape(x) -> tuple[int, int]:
    if _is_lti(x):
        return x.noutputs, x.ninputs
    a = np.asarray(x)
    if a.ndim == 0:
        return 1, 1
    return a.shape[-2], a.shape[-1]


def _check_delay(delay_samples) -> int:
    if isinstance(delay_samples, bool) or not isinstance(delay_samples, numbers.Integral):
        if isinstance(delay_samples, numbers.Real) and float(delay_samples).is_integer() \
                and not isinstance(delay_samples, bool):
            delay_samples = int(delay_samples)
        else:
            raise TypeError(f"delay_samples: expected a non-negative integer number of samples, "
                            f"got {delay_samples!r}")
    if delay_samples < 0:
        raise ValueError(f"delay_samples: expected >= 0, got {delay_samples}")
    return int(delay_samples)


def _timebase(systems: dict, dt) -> tuple[str | None, float | None]:
    """Common time base of the LTI entries of ``systems`` and the ``dt`` argument.

    Returns ``(kind, T)`` with ``kind`` in {'discrete', 'continuous', None} (None: only
    static gains) and ``T`` the sample period (or the ``dt`` argument) [s].
    """
    if dt is not None:
        if isinstance(dt, bool) or not isinstance(dt, numbers.Real) or not (dt > 0) \
                or not math.isfinite(dt):
            raise ValueError(f"dt: expected a positive sample period in seconds or None, got {dt!r}")
        dt = float(dt)
    kinds: dict[str, str] = {}
    sample: dict[str, float] = {}
    for name, x in systems.items():
        if not _is_lti(x):
            continue
        if x.dt is None or _is_static_lti(x):
            continue
        if ct.isdtime(x, strict=True):
            if x.dt is True:
                raise ValueError(f"{name}: discrete system with unspecified sample period (dt=True); "
                                 f"expected a numeric dt in seconds")
            kinds[name] = "discrete"
            sample[name] = float(x.dt)
        else:
            kinds[name] = "continuous"
    if len(set(kinds.values())) > 1:
        raise ValueError("mixed time bases: " + ", ".join(f"{k} is {v}" for k, v in kinds.items())
                         + "; expected all continuous or all discrete with one dt")
    if not kinds:
        return None, dt
    kind = next(iter(kinds.values()))
    if kind == "continuous":
        return kind, dt
    T = next(iter(sample.values()))
    for name, t in sample.items():
        if not math.isclose(t, T, rel_tol=1e-9):
            raise ValueError(f"{name}: sample period {t} s differs from {T} s of the other systems")
    if dt is not None and not math.isclose(dt, T, rel_tol=1e-9):
        raise ValueError(f"dt: {dt} s given but the discrete systems have dt = {T} s")
    return kind, T


def _check_freq(freq_hz, kind, T, *, increasing: bool = False) -> np.ndarray:
    try:
        f = np.asarray(freq_hz, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(f"freq_hz: expected a 1-D array of frequencies in Hz, got "
                        f"{_describe(freq_hz)}") from None
    if f.ndim == 0:
        f = f.reshape(1)
    if f.ndim != 1 or f.size == 0:
        raise ValueError(f"freq_hz: expected a non-empty 1-D array in Hz, got shape {f.shape}")
    if not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ValueError(f"freq_hz: expected finite frequencies >= 0 Hz, got min {np.nanmin(f)!r}, "
                         f"max {np.nanmax(f)!r}")
    if increasing and f.size > 1 and np.any(np.diff(f) <= 0):
        raise ValueError("freq_hz: expected strictly increasing frequencies (peaks are refined "
                         "between grid neighbours)")
    if kind == "discrete":
        nyq = 0.5 / T
        if f.max() > nyq * (1 + 1e-9):
            raise ValueError(f"freq_hz: discrete systems (dt={T} s) are defined up to the Nyquist "
                             f"frequency {nyq} Hz, got up to {f.max()} Hz")
    return f


# =====================================================================================
# frequency responses
# =====================================================================================
def _freqresp(x, f: np.ndarray, kind, T, name: str) -> np.ndarray:
    """``x`` on the grid ``f`` [Hz] as a complex (F, rows, cols) stack."""
    F = f.size
    if _is_lti(x):
        if ct.isdtime(x, strict=True):
            arg = np.exp(2j * np.pi * f * float(x.dt))
        else:
            arg = 2j * np.pi * f
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            H = np.asarray(x(arg, squeeze=False), dtype=complex)
        H = np.moveaxis(H.reshape(x.noutputs, x.ninputs, F), -1, 0)
    else:
        a = np.asarray(x)
        if a.ndim == 0:
            H = np.full((F, 1, 1), complex(a))
        elif a.ndim == 2:
            H = np.broadcast_to(a.astype(complex), (F,) + a.shape).copy()
        else:
            if a.shape[0] != F:
                raise ValueError(f"{name}: frequency-response stack has {a.shape[0]} frequencies, "
                                 f"expected {F} (one per freq_hz entry)")
            H = a.astype(complex)
    bad = ~np.all(np.isfinite(H), axis=(1, 2))
    if np.any(bad):
        raise ValueError(f"{name}: response is not finite at {f[bad][:5].tolist()} Hz "
                         f"(a pole on the evaluation grid?); move the grid off the pole")
    return H


def frequency_response(sys, freq_hz) -> np.ndarray:
    """Frequency response of an LTI system or static gain, frequency first.

    Parameters
    ----------
    sys : control.StateSpace, control.TransferFunction, array_like or float
        Continuous systems are evaluated at ``s = j 2 pi f``, discrete ones at
        ``z = exp(j 2 pi f dt)``.  A 2-D array is a static gain.
    freq_hz : array_like, shape (F,)
        Frequencies [Hz], >= 0 (and <= Nyquist for discrete systems).

    Returns
    -------
    ndarray, complex, shape (F, noutputs, ninputs)
    """
    _check_system("sys", sys, allow_stack=False)
    kind, T = _timebase({"sys": sys}, None)
    f = _check_freq(freq_hz, kind, T)
    return _freqresp(sys, f, kind, T, "sys")


def sigma_max(H) -> np.ndarray:
    """Largest singular value of each matrix of a stack.

    Parameters
    ----------
    H : array_like, shape (F, rows, cols) or (rows, cols)

    Returns
    -------
    ndarray, shape (F,) (or a 0-d array for a single matrix)
    """
    a = np.asarray(H)
    if a.ndim not in (2, 3):
        raise ValueError(f"H: expected shape (F, rows, cols) or (rows, cols), got {a.shape}")
    return np.linalg.norm(a, ord=2, axis=(-2, -1))


def _delay_factor(f: np.ndarray, d: int, T) -> np.ndarray:
    if d == 0:
        return np.ones(f.size, dtype=complex)
    return np.exp(-2j * np.pi * f * d * T)


# =====================================================================================
# frequency-domain loop functions
# =====================================================================================
_MAPS = ("S_o", "T_o", "S_i", "T_i", "KS", "KS_fb", "SG", "T_ry", "Lo", "Li")


@dataclass(frozen=True, eq=False)
class LoopResponse:
    """Closed-loop frequency responses (see the module docstring for the definitions).

    Attributes
    ----------
    freq_hz : ndarray, shape (F,)
        Frequencies [Hz].
    S_o, T_o : ndarray, complex, shape (F, ny, ny)
        Output sensitivity and complementary sensitivity.
    S_i, T_i : ndarray, complex, shape (F, nu, nu)
        Input sensitivity and complementary sensitivity.
    KS : ndarray, complex, shape (F, nu, ny)
        Reference to control, ``S_i K`` [V/V].
    KS_fb : ndarray, complex, shape (F, nu, ny)
        Feedback-loop ``Kfb S_o``: sensor noise / output disturbance to ``-u`` [V/V].
    SG : ndarray, complex, shape (F, ny, nu)
        Input disturbance to output, ``S_o Gd``.
    T_ry : ndarray, complex, shape (F, ny, ny)
        Reference to output, ``S_o Gd K``.
    Lo, Li : ndarray, complex, shapes (F, ny, ny), (F, nu, nu)
        Loop transfers ``Gd Kfb`` and ``Kfb Gd``.
    delay_samples : int
        Computation delay included in ``Gd`` [samples].
    """

    freq_hz: np.ndarray
    S_o: np.ndarray
    T_o: np.ndarray
    S_i: np.ndarray
    T_i: np.ndarray
    KS: np.ndarray
    KS_fb: np.ndarray
    SG: np.ndarray
    T_ry: np.ndarray
    Lo: np.ndarray
    Li: np.ndarray
    delay_samples: int = 0

    def __post_init__(self):
        for name in ("freq_hz",) + _MAPS:
            getattr(self, name).setflags(write=False)

    def sigma_max(self, name: str) -> np.ndarray:
        """``sigma_max`` of the map ``name`` (one of ``S_o, T_o, S_i, T_i, KS, KS_fb, SG,
        T_ry, Lo, Li``) at each grid frequency, shape (F,).
        """
        if name not in _MAPS:
            raise ValueError(f"name: expected one of {_MAPS}, got {name!r}")
        return sigma_max(getattr(self, name))

    def peak(self, name: str) -> tuple[float, float]:
        """``(max_f sigma_max, frequency [Hz])`` of the map ``name`` on the grid (not
        refined; :func:`robustness_summary` refines).
        """
        s = self.sigma_max(name)
        i = int(np.argmax(s))
        return float(s[i]), float(self.freq_hz[i])


def _loop_from_stacks(f, Gf, Kf, Kyf, d, T) -> LoopResponse:
    ny, nu = Gf.shape[1:]
    Gd = Gf * _delay_factor(f, d, T)[:, None, None] if d else Gf
    Kfb = Kf if Kyf is None else Kf - Kyf
    Iy, Iu = np.eye(ny), np.eye(nu)
    Lo = Gd @ Kfb
    Li = Kfb @ Gd
    S_o = np.linalg.inv(Iy + Lo)
    S_i = np.linalg.inv(Iu + Li)
    SG = S_o @ Gd
    return LoopResponse(freq_hz=f.copy(), S_o=S_o, T_o=Iy - S_o, S_i=S_i, T_i=Iu - S_i,
                        KS=S_i @ Kf, KS_fb=Kfb @ S_o, SG=SG, T_ry=SG @ Kf, Lo=Lo, Li=Li,
                        delay_samples=d)


def _check_loop_shapes(G, K, Ky):
    ny, nu = _io_shape(G)
    for name, x in (("K", K), ("Ky", Ky)):
        if x is None:
            continue
        r, c = _io_shape(x)
        if (r, c) != (nu, ny):
            raise ValueError(f"{name}: expected {nu} outputs x {ny} inputs (nu x ny for a plant G "
                             f"with {ny} outputs and {nu} inputs), got {r} x {c}")
    return ny, nu


class _Loop:
    """Prepared loop: validated arguments, evaluates :class:`LoopResponse` at any grid."""

    def __init__(self, G, K, Ky, delay_samples, dt, *, allow_stack=True):
        _check_system("G", G, allow_stack=allow_stack)
        _check_system("K", K, allow_stack=allow_stack)
        _check_system("Ky", Ky, allow_none=True, allow_stack=allow_stack)
        self.ny, self.nu = _check_loop_shapes(G, K, Ky)
        self.d = _check_delay(delay_samples)
        self.kind, self.T = _timebase({"G": G, "K": K, "Ky": Ky}, dt)
        if self.d and self.T is None:
            raise ValueError(f"dt: delay_samples={self.d} needs the sample period dt [s] "
                             f"(none of G, K, Ky is discrete)")
        self.G, self.K, self.Ky = G, K, Ky
        self.has_stack = any(isinstance(x, (np.ndarray, list, tuple)) and np.ndim(x) == 3
                             for x in (G, K, Ky) if x is not None)
        self.all_lti = all(_is_lti(x) or np.ndim(x) in (0, 2) for x in (G, K, Ky) if x is not None)

    def check_freq(self, freq_hz, increasing=False):
        f = _check_freq(freq_hz, self.kind, self.T, increasing=increasing)
        for name, x in (("G", self.G), ("K", self.K), ("Ky", self.Ky)):
            if x is not None and not _is_lti(x) and np.ndim(x) == 3 and np.shape(x)[0] != f.size:
                raise ValueError(f"{name}: frequency-response stack has {np.shape(x)[0]} frequencies, "
                                 f"expected {f.size} (one per freq_hz entry)")
        return f

    def response(self, f) -> LoopResponse:
        Gf = _freqresp(self.G, f, self.kind, self.T, "G")
        Kf = _freqresp(self.K, f, self.kind, self.T, "K")
        Kyf = None if self.Ky is None else _freqresp(self.Ky, f, self.kind, self.T, "Ky")
        try:
            return _loop_from_stacks(f, Gf, Kf, Kyf, self.d, self.T)
        except np.linalg.LinAlgError as exc:
            raise ValueError("the loop is singular (I + G Kfb not invertible) at some grid "
                             "frequency; move the grid off that point") from exc


def loop_transfer_response(G, K, freq_hz, Ky=None, delay_samples: int = 0, dt=None) -> LoopResponse:
    """Closed-loop frequency responses of ``u = K e + Ky y``, ``e = r - y``.

    Parameters
    ----------
    G : control.StateSpace, control.TransferFunction, array_like
        Plant, ``ny x nu`` [V/V]; a 2-D array is a static gain, a 3-D array a response
        stack of shape (F, ny, nu) on ``freq_hz``.
    K : same kinds as ``G``
        Controller on the error, ``nu x ny``.
    freq_hz : array_like, shape (F,)
        Frequencies [Hz], >= 0, <= Nyquist for discrete systems.
    Ky : same kinds as ``G`` or None
        Controller on the measurement, ``nu x ny``; None means zero.
    delay_samples : int
        Computation delay at the plant input [samples]; the factor
        ``exp(-j 2 pi f d dt)`` multiplies ``G`` (exact ``z^-d`` for discrete plants,
        the exact transport delay for continuous ones).
    dt : float or None
        Control period [s]; taken from the discrete systems when None; required for a
        delay with continuous or static systems.

    Returns
    -------
    LoopResponse

    Raises
    ------
    TypeError, ValueError
        Before any computation, naming the offending argument.
    """
    loop = _Loop(G, K, Ky, delay_samples, dt)
    f = loop.check_freq(freq_hz)
    return loop.response(f)


# =====================================================================================
# state-space loop functions
# =====================================================================================
def _names(base: str, n: int) -> list[str]:
    return [f"{base}[{i}]" for i in range(n)]


def _as_ss(x, dt_sys, name: str) -> ct.StateSpace:
    """State-space form of an LTI system or static gain with time base ``dt_sys``."""
    if _is_lti(x):
        s = ct.ss(x)
        A, B, C, D = (np.asarray(m, dtype=float) for m in (s.A, s.B, s.C, s.D))
        return ct.ss(A, B, C, D, dt_sys)
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        a = a.reshape(1, 1)
    if a.ndim != 2:
        raise ValueError(f"{name}: a state-space loop needs LTI systems or 2-D gains, got shape {a.shape}")
    return ct.ss(np.zeros((0, 0)), np.zeros((0, a.shape[1])), np.zeros((a.shape[0], 0)), a, dt_sys)


def _delay_ss(n: int, d: int, kind, T, pade_order: int, dt_sys) -> ct.StateSpace | None:
    if d == 0:
        return None
    if kind == "discrete":
        one = ct.ss(ct.tf([1.0], [1.0] + [0.0] * d, T))
    else:
        num, den = ct.pade(d * T, pade_order)
        one = ct.ss(ct.tf(num, den))
    blocks = [one] * n
    A = scipy.linalg.block_diag(*[b.A for b in blocks])
    B = scipy.linalg.block_diag(*[b.B for b in blocks])
    C = scipy.linalg.block_diag(*[b.C for b in blocks])
    D = scipy.linalg.block_diag(*[b.D for b in blocks])
    return ct.ss(A, B, C, D, dt_sys)


def _two_dof_controller(Ks: ct.StateSpace, Kys: ct.StateSpace | None, dt_sys) -> ct.StateSpace:
    """Controller with inputs ``[r; y]`` and output ``u = K (r - y) + Ky y``; every
    state of ``K`` and ``Ky`` appears once.
    """
    nu, ny = Ks.noutputs, Ks.ninputs
    if Kys is None:
        Kys = ct.ss(np.zeros((0, 0)), np.zeros((0, ny)), np.zeros((nu, 0)), np.zeros((nu, ny)), dt_sys)
    A = scipy.linalg.block_diag(Ks.A, Kys.A)
    B = np.block([[Ks.B, -Ks.B], [np.zeros((Kys.nstates, ny)), Kys.B]])
    C = np.hstack([Ks.C, Kys.C])
    D = np.hstack([Ks.D, Kys.D - Ks.D])
    return ct.ss(A, B, C, D, dt_sys)


def _feedback_operator_ss(Ks: ct.StateSpace, Kys: ct.StateSpace | None, dt_sys) -> ct.StateSpace:
    """The feedback operator ``Kfb = K - Ky`` as one realization (input ``y``; the loop
    is ``u = -Kfb y``).
    """
    C2 = _two_dof_controller(Ks, Kys, dt_sys)
    ny = Ks.ninputs
    return ct.ss(C2.A, -C2.B[:, ny:], C2.C, -C2.D[:, ny:], dt_sys)


def _closed_loop_A(Gs: ct.StateSpace, Kfb: ct.StateSpace) -> np.ndarray:
    """State matrix of ``u = -Kfb y`` around ``Gs`` (states ``[x_G; x_K]``)."""
    A, B, C, D = Gs.A, Gs.B, Gs.C, Gs.D
    Ak, Bk, Ck, Dk = Kfb.A, Kfb.B, Kfb.C, Kfb.D
    nu = B.shape[1]
    W = np.eye(nu) + Dk @ D
    if np.linalg.cond(W) > 1e12:
        raise ValueError("the loop is not well posed: I + Kfb(inf) G(inf) is singular")
    E = np.linalg.inv(W)
    Cy = C - D @ E @ Dk @ C
    return np.block([[A - B @ E @ Dk @ C, B @ E @ Ck],
                     [-Bk @ Cy, Ak - Bk @ D @ E @ Ck]])


@dataclass(frozen=True, eq=False)
class LoopStateSpace:
    """State-space closed-loop maps (definitions as in :class:`LoopResponse`).

    Every map is a sub-block of one realization, ``closed_loop``, that contains each
    state of the plant, the delay, ``K`` and ``Ky`` once, so its poles are the
    closed-loop poles (sub-blocks may carry uncontrollable/unobservable copies of them).

    Attributes
    ----------
    S_o, T_o, S_i, T_i, KS, KS_fb, SG, T_ry : control.StateSpace
    closed_loop : control.StateSpace
        Inputs ``[r (ny); d_i (nu); d_o (ny)]``, outputs ``[y (ny); u (nu); u_p (nu);
        y_p (ny)]`` with ``u_p = u + d_i`` the plant input and ``y = y_p + d_o``.
    stable : bool
        All closed-loop poles strictly inside the stability region.
    stability_measure : float
        Largest pole real part [1/s] (continuous) or spectral radius (discrete).
    delay_samples : int
    """

    S_o: ct.StateSpace
    T_o: ct.StateSpace
    S_i: ct.StateSpace
    T_i: ct.StateSpace
    KS: ct.StateSpace
    KS_fb: ct.StateSpace
    SG: ct.StateSpace
    T_ry: ct.StateSpace
    closed_loop: ct.StateSpace
    stable: bool
    stability_measure: float
    delay_samples: int = 0


def _stability(A: np.ndarray, discrete: bool) -> tuple[bool, float]:
    if A.size == 0:
        return True, (0.0 if discrete else -math.inf)
    p = np.linalg.eigvals(A)
    if discrete:
        m = float(np.max(np.abs(p)))
        return bool(m < 1.0), m
    m = float(np.max(p.real))
    return bool(m < 0.0), m


def _plant_ss(G, d, kind, T, pade_order, dt_sys, nu):
    Gs = _as_ss(G, dt_sys, "G")
    Dl = _delay_ss(nu, d, kind if kind else "continuous", T, pade_order, dt_sys)
    if Dl is not None:
        Gs = ct.series(Dl, Gs)
        Gs = ct.ss(Gs.A, Gs.B, Gs.C, Gs.D, dt_sys)
    return Gs


def loop_transfer_ss(G, K, Ky=None, delay_samples: int = 0, dt=None, *, pade_order: int = 3) -> LoopStateSpace:
    """State-space closed-loop maps of ``u = K e + Ky y``, ``e = r - y``.

    Built as the lower LFT (``control.StateSpace.lft``, exact algebra including
    feedthrough terms) of a generalised plant with one 2-DOF controller realization
    (inputs ``[r; y]``); signs are those of :func:`loop_transfer_response` and of
    ``control.feedback`` (pinned by tests).

    Parameters
    ----------
    G : control.StateSpace or control.TransferFunction or 2-D array
        Plant ``ny x nu``.
    K, Ky : like ``G`` (``Ky`` may be None)
        ``nu x ny`` controllers.
    delay_samples : int
        Computation delay at the plant input: ``d`` unit-delay states per input
        (discrete) or a Pade approximant of ``exp(-s d dt)`` of order ``pade_order``
        per input (continuous).
    dt : float or None
        Control period [s] (taken from the discrete systems when None).
    pade_order : int
        Order of the Pade approximant for continuous delays.

    Returns
    -------
    LoopStateSpace
    """
    loop = _Loop(G, K, Ky, delay_samples, dt, allow_stack=False)
    if isinstance(pade_order, bool) or not isinstance(pade_order, numbers.Integral) or pade_order < 1:
        raise ValueError(f"pade_order: expected a positive integer, got {pade_order!r}")
    ny, nu, d = loop.ny, loop.nu, loop.d
    dt_sys = loop.T if loop.kind == "discrete" else 0
    Gs = _plant_ss(G, d, loop.kind, loop.T, pade_order, dt_sys, nu)
    Ks = _as_ss(K, dt_sys, "K")
    Kys = None if Ky is None else _as_ss(Ky, dt_sys, "Ky")
    C2 = _two_dof_controller(Ks, Kys, dt_sys)
    W = np.eye(ny) + Gs.D @ (Ks.D - (0 if Kys is None else Kys.D))
    if np.linalg.cond(W) > 1e12:
        raise ValueError("the loop is not well posed: I + G(inf) Kfb(inf) is singular")
    # generalised plant: inputs [r; d_i; d_o; u], outputs [y; u; u_p; y_p; r; y]
    Ag, Bg, Cg, Dg = Gs.A, Gs.B, Gs.C, Gs.D
    n_x = Ag.shape[0]
    Zyy, Zyu, Zuy, Zuu = (np.zeros(sh) for sh in ((ny, ny), (ny, nu), (nu, ny), (nu, nu)))
    Iy, Iu = np.eye(ny), np.eye(nu)
    B_gen = np.hstack([np.zeros((n_x, ny)), Bg, np.zeros((n_x, ny)), Bg])
    C_gen = np.vstack([Cg, np.zeros((nu, n_x)), np.zeros((nu, n_x)), Cg, np.zeros((ny, n_x)), Cg])
    D_gen = np.block([[Zyy, Dg, Iy, Dg],
                      [Zuy, Zuu, Zuy, Iu],
                      [Zuy, Iu, Zuy, Iu],
                      [Zyy, Dg, Zyy, Dg],
                      [Iy, Zyu, Zyy, Zyu],
                      [Zyy, Dg, Iy, Dg]])
    P_gen = ct.ss(Ag, B_gen, C_gen, D_gen, dt_sys)
    CL = P_gen.lft(C2, nu=nu, ny=2 * ny)
    CL = ct.ss(CL.A, CL.B, CL.C, CL.D, dt_sys)
    r, di, do = slice(0, ny), slice(ny, ny + nu), slice(ny + nu, 2 * ny + nu)
    y, u, up, yp = slice(0, ny), slice(ny, ny + nu), slice(ny + nu, ny + 2 * nu), \
        slice(ny + 2 * nu, 2 * ny + 2 * nu)

    def sub(o, i, sign=1.0):
        return ct.ss(CL.A, CL.B[:, i], sign * CL.C[o, :], sign * CL.D[o, i], dt_sys)

    stable, meas = _stability(CL.A, loop.kind == "discrete")
    return LoopStateSpace(S_o=sub(y, do), T_o=sub(yp, do, -1.0), S_i=sub(up, di), T_i=sub(u, di, -1.0),
                          KS=sub(u, r), KS_fb=sub(u, do, -1.0), SG=sub(y, di), T_ry=sub(y, r),
                          closed_loop=CL, stable=stable, stability_measure=meas, delay_samples=d)


# =====================================================================================
# structured singular value
# =====================================================================================
@dataclass(frozen=True, eq=False)
class MuBounds:
    """Bounds on the structured singular value at each frequency.

    Attributes
    ----------
    upper : ndarray, shape (F,)
        D-scaling upper bound ``min_D sigma_max(D_l M D_r^-1)`` (evaluated exactly at the
        returned scales, so it is a valid upper bound whatever the optimiser did).
    lower : ndarray, shape (F,)
        Lower bound ``max rho(M Delta)`` over the structured ``Delta`` found by a power
        iteration (NaN when not computed).
    d_scales : ndarray, shape (F, n_blocks)
        Optimal scalings ``d_i`` (last block normalised to 1).
    blocks : tuple of (int, int)
    """

    upper: np.ndarray
    lower: np.ndarray
    d_scales: np.ndarray
    blocks: tuple

    def __post_init__(self):
        for name in ("upper", "lower", "d_scales"):
            getattr(self, name).setflags(write=False)


def _check_blocks(blocks) -> tuple[tuple[int, int], ...]:
    try:
        bl = [tuple(int(v) for v in b) for b in blocks]
        ok = all(len(b) == 2 for b in bl) and len(bl) > 0
        raw_ok = all(all(isinstance(v, numbers.Integral) and not isinstance(v, bool) for v in b)
                     for b in blocks)
    except (TypeError, ValueError):
        ok = raw_ok = False
    if not ok or not raw_ok:
        raise ValueError(f"blocks: expected a non-empty list of (rows, cols) integer pairs, got {blocks!r}")
    if any(r < 1 or c < 1 for r, c in bl):
        raise ValueError(f"blocks: expected positive sizes (complex full blocks; repeated scalar "
                         f"blocks such as (k, 0) are not supported), got {blocks!r}")
    return tuple(bl)


def _check_M(M, blocks) -> np.ndarray:
    a = np.asarray(M)
    if a.dtype.kind not in "iufc":
        raise TypeError(f"M: expected a numeric array, got {_describe(a)}")
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3:
        raise ValueError(f"M: expected shape (F, n, m) or (n, m), got {np.shape(M)}")
    nr = sum(c for _, c in blocks)
    nc = sum(r for r, _ in blocks)
    if a.shape[1:] != (nr, nc):
        raise ValueError(f"M: the blocks {list(blocks)} need M of shape (F, {nr}, {nc}) "
                         f"(rows: sum of block cols, cols: sum of block rows), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError("M: contains non-finite values")
    return a.astype(complex)


class _Structure:
    def __init__(self, blocks):
        self.blocks = blocks
        self.nb = len(blocks)
        c = np.cumsum([0] + [c for _, c in blocks])
        r = np.cumsum([0] + [r for r, _ in blocks])
        self.rows = [slice(c[i], c[i + 1]) for i in range(self.nb)]   # rows of M: z-space
        self.cols = [slice(r[i], r[i + 1]) for i in range(self.nb)]   # cols of M: w-space
        self.lrep = np.concatenate([[i] * b[1] for i, b in enumerate(blocks)]).astype(int)
        self.rrep = np.concatenate([[i] * b[0] for i, b in enumerate(blocks)]).astype(int)

    def scale(self, M, x):
        d = np.exp(x)
        return (d[self.lrep][:, None] * M) / d[self.rrep][None, :]

    def block_sums(self, v2, rep):
        return np.bincount(rep, weights=v2, minlength=self.nb)


def _osborne(M, st: _Structure, sweeps: int = 30) -> np.ndarray:
    N = np.zeros((st.nb, st.nb))
    for i in range(st.nb):
        for j in range(st.nb):
            N[i, j] = np.linalg.norm(M[st.rows[i], st.cols[j]])
    N2 = N ** 2
    np.fill_diagonal(N2, 0.0)
    x = np.zeros(st.nb)
    for _ in range(sweeps):
        change = 0.0
        for i in range(st.nb):
            e = np.exp(2 * (x[i] - x))          # (d_i / d_j)^2
            row = float(np.sum(N2[i, :] * e))
            col = float(np.sum(N2[:, i] / e))
            if row > 0 and col > 0:
                step = 0.25 * math.log(col / row)
                x[i] += step
                change = max(change, abs(step))
        if change < 1e-6:
            break
    x = np.clip(x - x[-1], -30, 30)
    return x


def _mu_ub_one(M, st: _Structure, x0=None):
    """Upper bound at one frequency; returns ``(ub, x)`` with ``x = log d`` (last 0)."""
    if st.nb == 1:
        return float(np.linalg.norm(M, 2)), np.zeros(1)

    def true_ub(y):
        return float(np.linalg.norm(st.scale(M, np.append(y, 0.0)), 2))

    def f_and_g(y, p):
        A = st.scale(M, np.append(y, 0.0))
        U, s, Vh = np.linalg.svd(A, full_matrices=False)
        if s[0] == 0:
            return 0.0, np.zeros_like(y)
        q = (s / s[0]) ** (2 * p)
        Z = q.sum()
        w = q / Z
        gu = st.block_sums((U.real ** 2 + U.imag ** 2) @ w, st.lrep)
        gv = st.block_sums((Vh.real ** 2 + Vh.imag ** 2).T @ w, st.rrep)
        return math.log(s[0]) + math.log(Z) / (2 * p), (gu - gv)[:-1]

    cands = [_osborne(M, st)]
    if x0 is not None:
        cands.append(np.asarray(x0, float))
    ys = [np.clip(c[:-1] - c[-1], -30, 30) for c in cands]
    y = min(ys, key=true_ub)
    bounds = [(-30.0, 30.0)] * (st.nb - 1)
    for p in (8.0, 128.0, 1024.0):
        res = scipy.optimize.minimize(f_and_g, y, args=(p,), jac=True, method="L-BFGS-B", bounds=bounds,
                                      options={"maxiter": 100, "ftol": 1e-12, "gtol": 1e-9})
        y = res.x
    return true_ub(y), np.append(y, 0.0)


def _mu_lb_one(M, st: _Structure, x=None, ub=None, iters: int = 50, n_random: int = 2,
               rng=None) -> float:
    """Lower bound ``max rho(M Delta)`` over structured ``Delta`` with unit blocks, by a
    power-type fixed-point iteration (align each ``Delta_i`` with the left/right
    eigenvectors of the dominant eigenvalue of ``M Delta``).
    """
    n, m = M.shape
    if st.nb == 1:
        return float(np.linalg.norm(M, 2))
    A = st.scale(M, x) if x is not None else M
    U, _, Vh = np.linalg.svd(A)
    MH = M.conj().T

    def delta_from(g, h):
        ng = np.sqrt(st.block_sums(g.real ** 2 + g.imag ** 2, st.rrep))
        nh = np.sqrt(st.block_sums(h.real ** 2 + h.imag ** 2, st.lrep))
        ok = (ng > 0) & (nh > 0)
        gs = g / np.where(ok, ng, 1.0)[st.rrep]
        hs = h / np.where(ok, nh, 1.0)[st.lrep]
        D = np.outer(gs, hs.conj())
        D *= (st.rrep[:, None] == st.lrep[None, :]) & ok[st.rrep][:, None]
        return D

    def run(D):
        best = 0.0
        for _ in range(iters):
            lam, VL, VR = scipy.linalg.eig(M @ D, left=True, right=True)
            k = int(np.argmax(np.abs(lam)))
            r = float(abs(lam[k]))
            if r <= best * (1 + 1e-10):
                best = max(best, r)
                break
            best = r
            if ub is not None and r >= ub * (1 - 1e-9):
                break
            D = delta_from(MH @ VL[:, k], VR[:, k])
        return best

    best = run(delta_from(Vh[0].conj(), U[:, 0]))
    rng = np.random.default_rng(0) if rng is None else rng
    for _ in range(n_random):
        if ub is not None and best >= ub * (1 - 1e-3):
            break
        g = rng.standard_normal(m) + 1j * rng.standard_normal(m)
        h = rng.standard_normal(n) + 1j * rng.standard_normal(n)
        best = max(best, run(delta_from(g, h)))
    return best


def mu_upper_bound(M, blocks, *, lower: bool = True) -> MuBounds:
    """Structured singular value bounds of complex matrices (one per frequency).

    Upper bound: ``min over positive block-diagonal D of sigma_max(D_l M D_r^-1)``,
    started from Osborne balancing of the block-norm matrix and minimised over
    ``log d`` with L-BFGS-B on a smooth Schatten-``2p`` surrogate (``p = 4, 32, 256``);
    the returned value is the exact ``sigma_max`` at the final scales (a valid upper
    bound).  Lower bound: ``rho(M Delta)`` maximised over structured ``Delta`` with
    ``sigma_max(Delta_i) = 1`` by a power-type fixed-point iteration started from the
    upper bound's singular vectors (and a few random starts); ``lower <= mu <= upper``.

    Parameters
    ----------
    M : array_like, complex, shape (F, n, m) or (n, m)
        ``n = sum of block cols``, ``m = sum of block rows``.
    blocks : sequence of (int, int)
        ``(rows, cols)`` of each complex full block ``Delta_i`` (``(1, 1)``: complex
        scalar), MATLAB ``mussv`` convention.
    lower : bool
        Also compute the lower bound (else ``MuBounds.lower`` is NaN).

    Returns
    -------
    MuBounds
    """
    bl = _check_blocks(blocks)
    Ms = _check_M(M, bl)
    st = _Structure(bl)
    F = Ms.shape[0]
    ub = np.empty(F)
    lb = np.full(F, np.nan)
    ds = np.empty((F, st.nb))
    x_prev = None
    rng = np.random.default_rng(0)
    for k in range(F):
        ub[k], x = _mu_ub_one(Ms[k], st, x_prev)
        x_prev = x
        ds[k] = np.exp(x)
        if lower:
            lb[k] = min(_mu_lb_one(Ms[k], st, x, ub[k], rng=rng), ub[k])
    return MuBounds(upper=ub, lower=lb, d_scales=ds, blocks=bl)


def mu_lower_bound(M, blocks) -> np.ndarray:
    """Lower bound of the structured singular value (see :func:`mu_upper_bound`).

    Returns
    -------
    ndarray, shape (F,)
    """
    return mu_upper_bound(M, blocks, lower=True).lower.copy()


# =====================================================================================
# peak refinement
# =====================================================================================
def _refine_max(fun: Callable[[np.ndarray], np.ndarray], f: np.ndarray, y: np.ndarray, n_peaks: int = 3,
                n_sub: int = 16, xatol_rel: float = 1e-5) -> tuple[float, float]:
    """Refine the largest local maxima of ``y`` (sampled on increasing ``f``).

    ``fun`` maps an array of frequencies [Hz] to values.  Each of the ``n_peaks`` largest
    grid maxima is bracketed by its grid neighbours, resampled on ``n_sub`` points (a
    bracket may hold several resonances), and the best sub-sample is polished by a
    bounded scalar search between its sub-grid neighbours.  Returns ``(max value, its
    frequency [Hz])``, never below the grid maximum.
    """
    i_best = int(np.argmax(y))
    best = (float(y[i_best]), float(f[i_best]))
    if f.size < 2:
        return best
    yy = np.concatenate([[-np.inf], y, [-np.inf]])
    loc = np.nonzero((yy[1:-1] >= yy[:-2]) & (yy[1:-1] >= yy[2:]))[0]
    loc = loc[np.argsort(y[loc])[::-1]][:n_peaks]
    for i in loc:
        lo, hi = f[max(i - 1, 0)], f[min(i + 1, f.size - 1)]
        if hi <= lo:
            continue
        use_log = lo > 0
        sub = np.geomspace(lo, hi, n_sub) if use_log else np.linspace(lo, hi, n_sub)
        ys = np.asarray(fun(sub), dtype=float)
        j = int(np.argmax(ys))
        if ys[j] > best[0]:
            best = (float(ys[j]), float(sub[j]))
        a_, b_ = sub[max(j - 1, 0)], sub[min(j + 1, n_sub - 1)]
        a, b = (math.log(a_), math.log(b_)) if use_log else (a_, b_)
        if b <= a:
            continue

        def neg(t, use_log=use_log):
            return -float(np.asarray(fun(np.array([math.exp(t) if use_log else t])))[0])

        res = scipy.optimize.minimize_scalar(neg, bounds=(a, b), method="bounded",
                                             options={"xatol": xatol_rel * (abs(b - a) + 1e-300) + 1e-12,
                                                      "maxiter": 40})
        val = -float(res.fun)
        if val > best[0]:
            best = (val, float(math.exp(res.x) if use_log else res.x))
    return best


# =====================================================================================
# disk margins
# =====================================================================================
def _check_skew(skew) -> float:
    if isinstance(skew, bool) or not isinstance(skew, numbers.Real) or not math.isfinite(skew):
        raise ValueError(f"skew: expected a finite real number (0 = symmetric), got {skew!r}")
    return float(skew)


def disk_gain_phase(alpha: float, skew: float = 0.0) -> tuple[float, float, float]:
    """Gain interval and phase margin guaranteed by a disk margin.

    Parameters
    ----------
    alpha : float
        Disk size (>= 0).
    skew : float
        Skew ``sigma`` (0: symmetric, > 0 favours gain increase).

    Returns
    -------
    gmin, gmax : float
        Real-axis intercepts of ``D(alpha, sigma)`` [factor]: ``gmin = (2 - alpha (1 -
        sigma)) / (2 + alpha (1 + sigma))`` clipped at 0 and ``gmax = (2 + alpha (1 -
        sigma)) / (2 - alpha (1 + sigma))``, ``inf`` once ``alpha (1 + sigma) >= 2``.
    phase_margin_deg : float
        Largest ``phi`` with ``exp(+-j phi)`` in the disk: ``arccos((4 - alpha^2 (1 +
        sigma^2)) / (4 + alpha^2 (1 - sigma^2)))`` [deg].
    """
    if isinstance(alpha, bool) or not isinstance(alpha, numbers.Real) or not (alpha >= 0):
        raise ValueError(f"alpha: expected a real number >= 0, got {alpha!r}")
    s = _check_skew(skew)
    a = float(alpha)
    if math.isinf(a):
        return 0.0, math.inf, 180.0
    gmin = max(0.0, (2 - a * (1 - s)) / (2 + a * (1 + s))) if (2 + a * (1 + s)) > 0 else 0.0
    den = 2 - a * (1 + s)
    gmax = (2 + a * (1 - s)) / den if den > 0 else math.inf
    c = (4 - a * a * (1 + s * s)) / (4 + a * a * (1 - s * s)) if (4 + a * a * (1 - s * s)) > 0 else -1.0
    pm = math.degrees(math.acos(min(1.0, max(-1.0, c))))
    return gmin, gmax, pm


def _db(x: float) -> float:
    if x <= 0:
        return -math.inf
    return 20 * math.log10(x) if math.isfinite(x) else math.inf


@dataclass(frozen=True)
class DiskMargin:
    """One disk margin.

    Attributes
    ----------
    alpha : float
        Guaranteed disk size, ``1 / peak mu upper bound`` (0 if the nominal loop is
        unstable).
    alpha_upper_bound : float
        ``1 / peak mu lower bound``: the true disk margin lies in
        ``[alpha, alpha_upper_bound]`` (equal for scalar problems).
    skew : float
    gain_margin : tuple of float
        ``(gmin, gmax)`` factors (``gmax`` may be ``inf``).
    gain_margin_db : tuple of float
        The same in dB.
    phase_margin_deg : float
        Symmetric disk phase margin ``+-`` [deg].
    freq_hz : float
        Frequency of the critical (largest-mu) point [Hz].
    location : str
        'input[i]', 'output[i]', 'input', 'output' or 'input+output'.
    """

    alpha: float
    alpha_upper_bound: float
    skew: float
    gain_margin: tuple
    gain_margin_db: tuple
    phase_margin_deg: float
    freq_hz: float
    location: str


def _make_dm(mu_ub: float, mu_lb: float, f: float, skew: float, location: str, stable) -> DiskMargin:
    if stable is False:
        alpha = alpha_ub = 0.0
    else:
        alpha = 1.0 / mu_ub if mu_ub > 0 else math.inf
        alpha_ub = 1.0 / mu_lb if mu_lb > 0 else math.inf
        alpha_ub = max(alpha_ub, alpha)
    gmin, gmax, pm = disk_gain_phase(alpha, skew)
    return DiskMargin(alpha=alpha, alpha_upper_bound=alpha_ub, skew=skew, gain_margin=(gmin, gmax),
                      gain_margin_db=(_db(gmin), _db(gmax)), phase_margin_deg=pm, freq_hz=f,
                      location=location)


@dataclass(frozen=True, eq=False)
class DiskMarginReport:
    """Loop-at-a-time and multiloop disk margins of one loop.

    Attributes
    ----------
    input_loop_at_a_time : tuple of DiskMargin
        One per plant input, breaking that channel with the others closed (uses the
        diagonal of ``S_i``).
    output_loop_at_a_time : tuple of DiskMargin
        One per plant output (diagonal of ``S_o``).
    input, output : DiskMargin
        Multiloop: independent simultaneous disk factors in all inputs (outputs),
        ``mu`` of ``S + (sigma - 1)/2 I`` with diagonal complex ``Delta``.
    input_output : DiskMargin
        Independent factors in all inputs *and* outputs at once, ``mu`` of
        ``[[S_i + (sigma-1)/2 I, -Kfb S_o], [S_o G, S_o + (sigma-1)/2 I]]``.
    freq_hz : ndarray, shape (F,)
        Analysis grid [Hz].
    alpha_input_f, alpha_output_f, alpha_input_output_f : ndarray, shape (F,)
        Frequency-wise multiloop disk margins ``1 / mu_upper`` on the grid.
    closed_loop_stable : bool or None
        Nominal stability (None when the systems were given as response stacks).
    skew : float
    """

    input_loop_at_a_time: tuple
    output_loop_at_a_time: tuple
    input: DiskMargin
    output: DiskMargin
    input_output: DiskMargin
    freq_hz: np.ndarray
    alpha_input_f: np.ndarray
    alpha_output_f: np.ndarray
    alpha_input_output_f: np.ndarray
    closed_loop_stable: bool | None
    skew: float

    def worst(self) -> DiskMargin:
        """The smallest of the three multiloop margins."""
        return min((self.input, self.output, self.input_output), key=lambda m: m.alpha)


def _io_matrix(r: LoopResponse, c: float) -> np.ndarray:
    Iu, Iy = np.eye(r.S_i.shape[1]), np.eye(r.S_o.shape[1])
    top = np.concatenate([r.S_i + c * Iu, -r.KS_fb], axis=2)
    bot = np.concatenate([r.SG, r.S_o + c * Iy], axis=2)
    return np.concatenate([top, bot], axis=1)


def _loop_stable(loop: _Loop, pade_order: int = 3):
    if loop.has_stack or not loop.all_lti:
        return None
    dt_sys = loop.T if loop.kind == "discrete" else 0
    Gs = _plant_ss(loop.G, loop.d, loop.kind, loop.T, pade_order, dt_sys, loop.nu)
    Ks = _as_ss(loop.K, dt_sys, "K")
    Kys = None if loop.Ky is None else _as_ss(loop.Ky, dt_sys, "Ky")
    A = _closed_loop_A(Gs, _feedback_operator_ss(Ks, Kys, dt_sys))
    return _stability(A, loop.kind == "discrete")


def disk_margins(G, K, freq_hz, Ky=None, *, delay_samples: int = 0, dt=None, skew: float = 0.0,
                 refine: bool = True) -> DiskMarginReport:
    """Disk margins (Seiler, Packard & Gahinet 2020; MATLAB ``diskmargin(P, C)``).

    Loop-at-a-time margins use ``alpha_k = 1 / sup_f |S_kk + (sigma - 1)/2|`` (``S_i``
    for inputs, ``S_o`` for outputs); multiloop margins ``alpha = 1 / sup_f mu(...)``
    with the :func:`mu_upper_bound` on the grid, the largest peaks refined by a bounded
    scalar search between grid neighbours (when the systems are LTI or static).  A
    nominally unstable loop gets ``alpha = 0``.

    Parameters
    ----------
    G, K, Ky, delay_samples, dt
        As in :func:`loop_transfer_response`; only ``Kfb = K - Ky`` matters.  A
        continuous delay is exact in the responses and a Pade(3) approximant in the
        nominal-stability check.
    freq_hz : array_like, shape (F,)
        Strictly increasing analysis grid [Hz] (include 0 to catch a DC peak).
    skew : float
        Disk skew ``sigma`` (0: symmetric gain variation).
    refine : bool
        Refine the peaks between grid points.

    Returns
    -------
    DiskMarginReport
    """
    loop = _Loop(G, K, Ky, delay_samples, dt)
    s = _check_skew(skew)
    f = loop.check_freq(freq_hz, increasing=True)
    c = (s - 1.0) / 2.0
    st = _loop_stable(loop)
    stable = None if st is None else st[0]
    r = loop.response(f)
    can_refine = refine and not loop.has_stack

    out_i, out_o = [], []
    for kind_, S, n in (("input", r.S_i, loop.nu), ("output", r.S_o, loop.ny)):
        for k in range(n):
            y = np.abs(S[:, k, k] + c)
            if can_refine:
                def fun(fr, kind_=kind_, k=k):
                    rr = loop.response(fr)
                    return np.abs((rr.S_i if kind_ == "input" else rr.S_o)[:, k, k] + c)
                pk, fpk = _refine_max(fun, f, y)
            else:
                i = int(np.argmax(y))
                pk, fpk = float(y[i]), float(f[i])
            dm = _make_dm(pk, pk, fpk, s, f"{kind_}[{k}]", stable)
            (out_i if kind_ == "input" else out_o).append(dm)

    def multiloop(build, blocks, label):
        Mf = build(r)
        mb = mu_upper_bound(Mf, blocks, lower=True)
        if can_refine:
            pk, fpk = _refine_max(lambda fr: mu_upper_bound(build(loop.response(fr)), blocks, lower=False).upper,
                                  f, mb.upper)
            lb_pk = float(mu_upper_bound(build(loop.response(np.array([fpk]))), blocks, lower=True).lower[0])
        else:
            i = int(np.argmax(mb.upper))
            pk, fpk = float(mb.upper[i]), float(f[i])
            lb_pk = float(mb.lower[i])
        lb_pk = max(lb_pk, float(np.nanmax(mb.lower)))
        with np.errstate(divide="ignore"):
            curve = np.where(mb.upper > 0, 1.0 / mb.upper, np.inf)
        return _make_dm(pk, min(lb_pk, pk), fpk, s, label, stable), curve

    mi, ai = multiloop(lambda rr: rr.S_i + c * np.eye(loop.nu), [(1, 1)] * loop.nu, "input")
    mo, ao = multiloop(lambda rr: rr.S_o + c * np.eye(loop.ny), [(1, 1)] * loop.ny, "output")
    mio, aio = multiloop(lambda rr: _io_matrix(rr, c), [(1, 1)] * (loop.nu + loop.ny), "input+output")
    f_ro = f.copy()
    for a in (f_ro, ai, ao, aio):
        a.setflags(write=False)
    return DiskMarginReport(input_loop_at_a_time=tuple(out_i), output_loop_at_a_time=tuple(out_o),
                            input=mi, output=mo, input_output=mio, freq_hz=f_ro, alpha_input_f=ai,
                            alpha_output_f=ao, alpha_input_output_f=aio, closed_loop_stable=stable,
                            skew=s)


# =====================================================================================
# parametric perturbations of a modal plant
# =====================================================================================
def _check_scale(name, v, lo_ok=0.0):
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v) or not (v > lo_ok):
        raise ValueError(f"{name}: expected a finite real number > {lo_ok}, got {v!r}")
    return float(v)


def perturbed_plant(G, freq_scale: float = 1.0, damping_scale: float = 1.0, input_gain=1.0,
                    delay_samples: int = 0, *, dt=None, keep_dc_gain: bool = True,
                    pade_order: int = 3) -> ct.StateSpace:
    """Plant with scaled modal frequencies and damping, input gains and a delay.

    ``G`` is diagonalised, ``A = V diag(lambda) V^-1``.  Each pole, in continuous-time
    terms ``lambda = -zeta w_n +- j w_n sqrt(1 - zeta^2)`` (discrete poles are mapped
    with ``s = log(z) / dt`` and back with ``z = exp(s dt)``), becomes
    ``w_n' = freq_scale w_n``, ``zeta' = damping_scale zeta`` for complex poles
    (a pair turns real if ``zeta' >= 1``), and ``freq_scale lambda`` for real poles;
    poles at ``s = 0`` stay.  With ``keep_dc_gain`` each modal residue is scaled by
    ``lambda'/lambda`` (continuous) or ``(1 - z')/(1 - z)`` (discrete) so that every
    mode keeps its static contribution (a mass-like rather than stiffness-like change;
    the static gain uncertainty belongs to ``input_gain``).

    Parameters
    ----------
    G : control.StateSpace or control.TransferFunction
        Diagonalisable plant ``ny x nu``.
    freq_scale : float
        Factor on every modal natural frequency (> 0), e.g. 0.97 ... 1.03.
    damping_scale : float
        Factor on every modal damping ratio (> 0), e.g. 0.5 ... 2.
    input_gain : float or array_like, shape (nu,)
        Gain factor per input channel (``G diag(input_gain)``).
    delay_samples : int
        Extra delay at the plant input: unit delays (discrete) or a Pade approximant
        of ``exp(-s d dt)`` of order ``pade_order`` (continuous, needs ``dt``).
    dt : float or None
        Control period [s] for a continuous plant's delay.
    keep_dc_gain : bool
        Keep each mode's static contribution (see above).
    pade_order : int

    Returns
    -------
    control.StateSpace
        Same time base as ``G``; states ``[delay; modal]``.
    """
    if not _is_lti(G):
        raise TypeError(f"G: expected a control.StateSpace or TransferFunction, got {_describe(G)}")
    fs = _check_scale("freq_scale", freq_scale)
    zs = _check_scale("damping_scale", damping_scale)
    d = _check_delay(delay_samples)
    nu = G.ninputs
    g = np.asarray(input_gain, dtype=float)
    if g.ndim == 0:
        g = np.full(nu, float(g))
    if g.shape != (nu,) or not np.all(np.isfinite(g)):
        raise ValueError(f"input_gain: expected a scalar or {nu} finite factors (one per input), "
                         f"got {np.shape(input_gain)}")
    kind, T = _timebase({"G": G}, dt)
    if d and T is None:
        raise ValueError(f"dt: delay_samples={d} on a continuous plant needs the sample period dt [s]")
    discrete = kind == "discrete"
    dt_sys = T if discrete else 0
    Gs = ct.ss(G)
    A, B, C, D = (np.asarray(m, dtype=float) for m in (Gs.A, Gs.B, Gs.C, Gs.D))
    if A.shape[0]:
        lam, V = np.linalg.eig(A)
        if np.linalg.cond(V) > 1e10:
            raise ValueError("G: the state matrix is not (numerically) diagonalisable; "
                             "expected a plant with distinct modes")
        if discrete:
            with np.errstate(divide="ignore"):
                s = np.log(lam.astype(complex)) / T
        else:
            s = lam.astype(complex)
        s_new = s.copy()
        for k, sk in enumerate(s):
            if not np.isfinite(sk) or sk == 0:
                continue
            wn = abs(sk)
            if abs(sk.imag) > 1e-12 * wn:
                zeta = -sk.real / wn
                zn, wn2 = zeta * zs, wn * fs
                if zn < 1:
                    s_new[k] = wn2 * (-zn + 1j * math.copysign(math.sqrt(1 - zn * zn), sk.imag))
                else:
                    r = math.sqrt(zn * zn - 1)
                    s_new[k] = wn2 * (-zn + (r if sk.imag > 0 else -r))
            else:
                s_new[k] = sk * fs
        lam_new = np.exp(s_new * T) if discrete else s_new
        lam_new = np.where(np.isfinite(s), lam_new, lam)
        VinvB = np.linalg.solve(V, B.astype(complex))
        if keep_dc_gain:
            p0 = 1.0 if discrete else 0.0
            with np.errstate(divide="ignore", invalid="ignore"):
                fac = (p0 - lam_new) / (p0 - lam)
            fac = np.where(np.isfinite(fac) & (np.abs(p0 - lam) > 1e-12), fac, 1.0)
            VinvB = fac[:, None] * VinvB
        An = V @ np.diag(lam_new) @ np.linalg.inv(V)
        Bn = V @ VinvB
        scale = max(1.0, np.abs(A).max(), np.abs(B).max())
        if np.abs(An.imag).max() > 1e-6 * scale * max(1.0, np.abs(An.real).max()) or \
                np.abs(Bn.imag).max() > 1e-6 * max(1.0, np.abs(Bn.real).max()):
            raise ValueError("G: modal perturbation produced a complex realization (unpaired "
                             "complex poles?)")
        A, B = An.real, Bn.real
    B = B * g[None, :]
    D = D * g[None, :]
    P = ct.ss(A, B, C, D, dt_sys)
    Dl = _delay_ss(nu, d, kind if kind else "continuous", T, pade_order, dt_sys)
    if Dl is not None:
        P = ct.series(Dl, P)
        P = ct.ss(P.A, P.B, P.C, P.D, dt_sys)
    return P


# =====================================================================================
# robust stability over the stage's uncertainty set
# =====================================================================================
@dataclass(frozen=True, eq=False)
class RobustStabilityResult:
    """mu-based robust stability over a covering set, plus a sampled brute-force check.

    Attributes
    ----------
    mu_peak : float
        Peak over frequency of the mu *upper bound* of the covering M-Delta structure
        (refined between grid points).  ``mu_peak < 1`` (with ``nominal_stable``)
        guarantees stability for every plant of the covering set.
    mu_peak_freq_hz : float
        Its frequency [Hz].
    mu_lower_peak : float
        Peak of the mu lower bound on the grid (a plant of the covering set, possibly
        not a physical one, is destabilised by ``1 / mu_lower_peak`` times the set).
    freq_hz : ndarray, shape (F,)
    mu_upper, mu_lower : ndarray, shape (F,)
    weight_output : ndarray, shape (F,)
        Radius ``w_O(f)`` of the full output multiplicative block.
    input_gain_center, input_gain_radius : ndarray, shape (nu,)
        Input-gain disk ``c_i (1 + r_i delta_i)``; ``r_i`` is relative to ``c_i``.
    nominal_stable : bool
        The centre loop (gains ``c``, nominal modes, ``nominal_delay_samples``).
    sampled_all_stable : bool
        Every sampled parametric plant closes a stable loop.
    sampled_worst : float
        Worst spectral radius (discrete) or largest pole real part [1/s] over the samples.
    sampled_worst_parameters : dict
        The parameters of that sample.
    n_samples : int
        Vertices plus random samples checked.
    discrete : bool
    """

    mu_peak: float
    mu_peak_freq_hz: float
    mu_lower_peak: float
    freq_hz: np.ndarray
    mu_upper: np.ndarray
    mu_lower: np.ndarray
    weight_output: np.ndarray
    input_gain_center: np.ndarray
    input_gain_radius: np.ndarray
    nominal_stable: bool
    sampled_all_stable: bool
    sampled_worst: float
    sampled_worst_parameters: dict
    n_samples: int
    discrete: bool
    n_weight_samples: int = 0

    @property
    def robustly_stable(self) -> bool:
        """``nominal_stable and mu_peak < 1`` (a sufficient condition)."""
        return bool(self.nominal_stable and self.mu_peak < 1.0)


def _check_range(name, rng, *, positive=True, integer=False):
    try:
        lo, hi = rng
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a (low, high) pair, got {rng!r}") from None
    for v in (lo, hi):
        if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
            raise ValueError(f"{name}: expected finite numbers, got {rng!r}")
        if integer and not float(v).is_integer():
            raise ValueError(f"{name}: expected integers, got {rng!r}")
    if lo > hi or (positive and lo <= 0) or (integer and lo < 0):
        raise ValueError(f"{name}: expected {'0 <' if positive else ''} low <= high, got {rng!r}")
    return (int(lo), int(hi)) if integer else (float(lo), float(hi))


def robust_stability_mu(G_nominal, K, Ky, dt, freq_hz, *, input_gain_range=(0.75, 1.0),
                        freq_scale_range=(0.97, 1.03), damping_scale_range=(0.5, 2.0),
                        delay_samples_range=(0, 1), nominal_delay_samples: int = 0,
                        n_levels: int = 3, n_random: int = 24, seed: int = 0,
                        keep_dc_gain: bool = True, refine: bool = True,
                        pade_order: int = 3) -> RobustStabilityResult:
    """Robust stability of ``u = K e + Ky y`` for the stage's parametric uncertainty.

    Uncertainty set (per the issue): piezo gain per input channel in
    ``input_gain_range`` (hysteresis slope after a reversal ~0.75 of nominal), every
    modal frequency scaled within ``freq_scale_range`` (+-3 %), every modal damping
    scaled within ``damping_scale_range`` (x0.5 ... x2), computation delay of
    ``delay_samples_range`` samples (integers).

    Covering (Skogestad & Postlethwaite, 2nd ed., Sec. 7.4 / 8.2: parametric
    uncertainty covered by complex weighted blocks)::

        Gp = (I + w_O(f) Delta_O) G_c (I + R Delta_I),
        G_c = G_nominal(delay = nominal_delay_samples) diag(c),
        c_i = (lo + hi)/2,  R = diag((hi - lo)/(hi + lo)),
        w_O(f) = max over samples sigma_max((Gp_s - G0) G0^-1)

    where the samples ``Gp_s`` (:func:`perturbed_plant`) are an ``n_levels`` grid over
    frequency scale x damping scale x every delay in the range plus ``n_random``
    uniform samples, and ``G0`` is the nominal-mode plant (``E_O`` does not depend on
    the input gains).  ``Delta_I`` is diagonal complex (one scalar per input),
    ``Delta_O`` a full complex ``ny x ny`` block, and with ``Kfb = K - Ky``::

        M = [[-R T_i, -R Kfb S_o], [w_O S_o G_c, -w_O T_o]]   (loop of G_c)

    **The reported ``mu_peak`` is a conservative upper bound over the covering set**,
    which (i) replaces real gains by complex disks, (ii) lumps the modal and delay
    changes into one unstructured output block, and (iii) contains the *sampled*
    parametric plants by construction but is not proven to contain parameter
    combinations between samples.  The brute-force part therefore also closes the loop
    around every vertex of the parameter box (``2^nu`` gain corners x frequency x
    damping x delay extremes) and ``n_random`` random interior points and reports the
    worst spectral radius / pole real part.

    Parameters
    ----------
    G_nominal : control.StateSpace or TransferFunction
        Square, diagonalisable plant ``n x n`` without the computation delay.
    K, Ky : controllers ``n x n`` (``Ky`` may be None); same time base as ``G_nominal``.
    dt : float or None
        Control period [s] (from the discrete systems when None).
    freq_hz : array_like
        Strictly increasing grid [Hz] (<= Nyquist for discrete systems).
    input_gain_range, freq_scale_range, damping_scale_range : (float, float)
        Parameter boxes (factors on nominal).
    delay_samples_range : (int, int)
        Computation delays covered [samples], absolute (not relative to the nominal);
        exact factors ``exp(-j 2 pi f d dt)`` in ``w_O``, delay states (discrete) or
        Pade approximants (continuous) in the brute-force check.
    nominal_delay_samples : int
        Delay of the centre plant used to build ``M`` [samples].
    n_levels : int
        Levels per parameter of the weight grid (>= 2; ends included).
    n_random : int
        Random samples, used both for ``w_O`` and for the brute-force check.
    seed : int
    keep_dc_gain, pade_order
        See :func:`perturbed_plant`.
    refine : bool
        Refine the mu peak between grid points.

    Returns
    -------
    RobustStabilityResult
    """
    if not _is_lti(G_nominal):
        raise TypeError(f"G_nominal: expected a control.StateSpace or TransferFunction, got "
                        f"{_describe(G_nominal)}")
    if G_nominal.noutputs != G_nominal.ninputs:
        raise ValueError(f"G_nominal: the output-multiplicative covering needs a square plant, got "
                         f"{G_nominal.noutputs} outputs x {G_nominal.ninputs} inputs")
    loop = _Loop(G_nominal, K, Ky, nominal_delay_samples, dt, allow_stack=False)
    f = loop.check_freq(freq_hz, increasing=True)
    glo, ghi = _check_range("input_gain_range", input_gain_range)
    flo, fhi = _check_range("freq_scale_range", freq_scale_range)
    zlo, zhi = _check_range("damping_scale_range", damping_scale_range)
    dlo, dhi = _check_range("delay_samples_range", delay_samples_range, positive=False, integer=True)
    if isinstance(n_levels, bool) or not isinstance(n_levels, numbers.Integral) or n_levels < 2:
        raise ValueError(f"n_levels: expected an integer >= 2, got {n_levels!r}")
    if isinstance(n_random, bool) or not isinstance(n_random, numbers.Integral) or n_random < 0:
        raise ValueError(f"n_random: expected an integer >= 0, got {n_random!r}")
    if (dhi > 0 or loop.d > 0) and loop.T is None:
        raise ValueError("dt: delays need the sample period dt [s] (G_nominal is continuous)")
    n = loop.nu
    T = loop.T
    discrete = loop.kind == "discrete"
    c = (glo + ghi) / 2.0
    rad = (ghi - glo) / (ghi + glo)
    center = np.full(n, c)
    radius = np.full(n, rad)

    def pp(fs, zs, gains, dd):
        return perturbed_plant(G_nominal, fs, zs, gains, dd, dt=T, keep_dc_gain=keep_dc_gain,
                               pade_order=pade_order)

    # ---- weight samples (modes + delay; gains cancel in E_O)
    rng = np.random.default_rng(seed)
    fl = np.linspace(flo, fhi, n_levels)
    zl = np.geomspace(zlo, zhi, n_levels)
    delays = list(range(dlo, dhi + 1))
    samples = [(a, b, dd) for a in fl for b in zl for dd in delays]
    rand = [(float(rng.uniform(flo, fhi)), float(math.exp(rng.uniform(math.log(zlo), math.log(zhi)))),
             int(rng.integers(dlo, dhi + 1)), rng.uniform(glo, ghi, n)) for _ in range(n_random)]
    samples += [(a, b, dd) for a, b, dd, _ in rand]
    G0 = perturbed_plant(G_nominal, 1.0, 1.0, 1.0, 0, dt=T, keep_dc_gain=keep_dc_gain)
    modal = [(pp(a, b, 1.0, 0), dd) for a, b, dd in samples]   # delays applied as exact factors

    def weight(fr: np.ndarray) -> np.ndarray:
        G0f = _freqresp(G0, fr, loop.kind, T, "G_nominal") * _delay_factor(fr, loop.d, T)[:, None, None]
        G0T = np.swapaxes(G0f, 1, 2)
        w = np.zeros(fr.size)
        for P, dd in modal:
            Pf = _freqresp(P, fr, loop.kind, T, "perturbed plant") * _delay_factor(fr, dd, T)[:, None, None]
            E = np.swapaxes(np.linalg.solve(G0T, np.swapaxes(Pf - G0f, 1, 2)), 1, 2)   # (Pf - G0f) G0f^-1
            w = np.maximum(w, sigma_max(E))
        return w

    # ---- nominal (centre) loop and M
    Gc = ct.ss(G0.A, G0.B * c, G0.C, G0.D * c, G0.dt)
    center_loop = _Loop(Gc, K, Ky, loop.d, T, allow_stack=False)
    st_nom = _loop_stable(center_loop, pade_order)
    nominal_stable = bool(st_nom[0])
    blocks = [(1, 1)] * n + [(n, n)]

    def build(fr: np.ndarray) -> np.ndarray:
        r = center_loop.response(fr)
        w = weight(fr)[:, None, None]
        R = radius[None, :, None]
        top = np.concatenate([-R * r.T_i, -R * r.KS_fb], axis=2)
        bot = np.concatenate([w * r.SG, -w * r.T_o], axis=2)
        return np.concatenate([top, bot], axis=1), w[:, 0, 0]

    Mf, wf = build(f)
    mb = mu_upper_bound(Mf, blocks, lower=True)
    if refine:
        pk, fpk = _refine_max(lambda fr: mu_upper_bound(build(fr)[0], blocks, lower=False).upper, f, mb.upper)
    else:
        i = int(np.argmax(mb.upper))
        pk, fpk = float(mb.upper[i]), float(f[i])

    # ---- brute force on vertices and random samples
    dt_sys = T if discrete else 0
    Kfb_ss = _feedback_operator_ss(_as_ss(K, dt_sys, "K"), None if Ky is None else _as_ss(Ky, dt_sys, "Ky"),
                                   dt_sys)
    checks = []
    for corner in np.array(np.meshgrid(*[[glo, ghi]] * n, indexing="ij")).reshape(n, -1).T:
        for a in (flo, fhi):
            for b in (zlo, zhi):
                for dd in sorted({dlo, dhi}):
                    checks.append((a, b, dd, corner))
    checks += [(a, b, dd, g) for a, b, dd, g in rand]
    worst, worst_par, all_stable = -math.inf, {}, True
    for a, b, dd, g in checks:
        P = pp(a, b, g, dd)
        ok, meas = _stability(_closed_loop_A(P, Kfb_ss), discrete)
        all_stable &= ok
        if meas > worst:
            worst = meas
            worst_par = {"freq_scale": float(a), "damping_scale": float(b), "delay_samples": int(dd),
                         "input_gain": [float(v) for v in np.atleast_1d(g)]}
    out = [f.copy(), mb.upper, mb.lower, wf, center, radius]
    for a in out:
        a.setflags(write=False)
    return RobustStabilityResult(mu_peak=float(pk), mu_peak_freq_hz=float(fpk),
                                 mu_lower_peak=float(np.nanmax(mb.lower)), freq_hz=out[0],
                                 mu_upper=out[1], mu_lower=out[2], weight_output=out[3],
                                 input_gain_center=out[4], input_gain_radius=out[5],
                                 nominal_stable=nominal_stable, sampled_all_stable=bool(all_stable),
                                 sampled_worst=float(worst), sampled_worst_parameters=worst_par,
                                 n_samples=len(checks), discrete=discrete,
                                 n_weight_samples=len(samples))


# =====================================================================================
# closed-loop poles and damping
# =====================================================================================
@dataclass(frozen=True)
class LeastDampedPole:
    """The least-damped pole.

    Attributes
    ----------
    zeta : float
        Damping ratio ``-Re(s) / |s|`` (negative: unstable; 0 for a pole at ``s = 0``).
    freq_hz : float
        Natural frequency ``|s| / (2 pi)`` [Hz].
    pole : complex
        The pole as given (``z`` for discrete systems).
    pole_s : complex
        Its continuous equivalent ``s`` [rad/s] (``log(z) / dt`` for discrete poles).
    """

    zeta: float
    freq_hz: float
    pole: complex
    pole_s: complex


def closed_loop_poles(G, K, Ky=None, delay_samples: int = 0, dt=None, *, pade_order: int = 3) -> np.ndarray:
    """Poles of ``u = K e + Ky y`` around ``G`` (with the delay states, see
    :func:`loop_transfer_ss`): ``z`` for discrete loops, ``s`` [rad/s] for continuous.

    Returns
    -------
    ndarray, complex, shape (n_states,)
    """
    loop = _Loop(G, K, Ky, delay_samples, dt, allow_stack=False)
    dt_sys = loop.T if loop.kind == "discrete" else 0
    Gs = _plant_ss(G, loop.d, loop.kind, loop.T, pade_order, dt_sys, loop.nu)
    A = _closed_loop_A(Gs, _feedback_operator_ss(_as_ss(K, dt_sys, "K"),
                                                 None if Ky is None else _as_ss(Ky, dt_sys, "Ky"), dt_sys))
    return np.linalg.eigvals(A) if A.size else np.zeros(0, dtype=complex)


def least_damped_pole(system_or_poles, dt=None, *, f_band_hz=None) -> LeastDampedPole:
    """Least-damped pole of a system or a pole list, continuous or discrete.

    Parameters
    ----------
    system_or_poles : control.StateSpace, control.TransferFunction or array_like
        A system (its poles; discrete when ``dt > 0``) or poles: ``z`` when ``dt`` is
        given, else ``s`` [rad/s].
    dt : float or None
        Sample period [s] for a pole list (ignored for systems, which carry their own).
    f_band_hz : (float, float) or None
        Only poles with natural frequency in this band [Hz].

    Returns
    -------
    LeastDampedPole
        Discrete poles are mapped with ``s = log(z) / dt`` (principal branch); poles at
        ``z = 0`` (pure delays) are infinitely damped and skipped.

    Raises
    ------
    ValueError
        If no pole is left.
    """
    if _is_lti(system_or_poles):
        sysx = system_or_poles
        p = np.asarray(sysx.poles(), dtype=complex)
        T = float(sysx.dt) if ct.isdtime(sysx, strict=True) and sysx.dt is not True else None
        if ct.isdtime(sysx, strict=True) and sysx.dt is True:
            raise ValueError("system_or_poles: discrete system with dt=True; expected a numeric dt")
    else:
        p = np.atleast_1d(np.asarray(system_or_poles, dtype=complex))
        if p.ndim != 1:
            raise ValueError(f"system_or_poles: expected a 1-D pole array, got shape {p.shape}")
        if dt is not None and (isinstance(dt, bool) or not isinstance(dt, numbers.Real) or not dt > 0):
            raise ValueError(f"dt: expected a positive sample period [s] or None, got {dt!r}")
        T = None if dt is None else float(dt)
    if T is not None:
        keep = np.abs(p) > 0
        pz = p[keep]
        s = np.log(pz) / T
    else:
        pz = p
        s = p
    wn = np.abs(s)
    with np.errstate(invalid="ignore", divide="ignore"):
        zeta = np.where(wn > 0, -s.real / np.where(wn > 0, wn, 1.0), 0.0)
    fhz = wn / (2 * np.pi)
    sel = np.isfinite(s)
    if f_band_hz is not None:
        try:
            lo, hi = (float(v) for v in f_band_hz)
        except (TypeError, ValueError):
            raise ValueError(f"f_band_hz: expected a (low, high) pair in Hz, got {f_band_hz!r}") from None
        sel &= (fhz >= lo) & (fhz <= hi)
    if not np.any(sel):
        raise ValueError(f"system_or_poles: no pole left (f_band_hz={f_band_hz!r})")
    idx = np.nonzero(sel)[0]
    k = idx[int(np.argmin(zeta[idx]))]
    return LeastDampedPole(zeta=float(zeta[k]), freq_hz=float(fhz[k]), pole=complex(pz[k]),
                           pole_s=complex(s[k]))


# =====================================================================================
# JSON summary
# =====================================================================================
def _num(x):
    """JSON-safe float: non-finite values become None."""
    x = float(x)
    return x if math.isfinite(x) else None


def _dm_dict(prefix: str, m: DiskMargin) -> dict:
    return {f"{prefix}_alpha": _num(m.alpha),
            f"{prefix}_alpha_upper_bound": _num(m.alpha_upper_bound),
            f"{prefix}_gain_margin_low": _num(m.gain_margin[0]),
            f"{prefix}_gain_margin_high": _num(m.gain_margin[1]),
            f"{prefix}_gain_margin_low_db": _num(m.gain_margin_db[0]),
            f"{prefix}_gain_margin_high_db": _num(m.gain_margin_db[1]),
            f"{prefix}_phase_margin_deg": _num(m.phase_margin_deg),
            f"{prefix}_freq_hz": _num(m.freq_hz)}


def robustness_summary(G, K, freq_hz, Ky=None, *, delay_samples: int = 0, dt=None, skew: float = 0.0,
                       f_band_hz=None, robust: dict | None = None) -> dict:
    """JSON-serialisable robustness figures of one loop (units in the key names).

    Keys
    ----
    ``closed_loop_stable``; ``max_pole_real_per_s`` (continuous) or
    ``spectral_radius`` (discrete); ``least_damped_zeta``, ``least_damped_freq_hz``;
    ``peak_<map>`` and ``peak_<map>_freq_hz`` for ``So, To, Si, Ti, KS, KS_fb, SG, T_ry``
    (sigma_max peaks, refined); ``disk_margin_alpha``, ``gain_margin_db`` ([low, high]),
    ``phase_margin_deg``, ``disk_margin_freq_hz``, ``disk_margin_location``: the worst
    multiloop disk margin; ``dm_<input|output|input_output>_*`` for each multiloop
    margin and ``dm_<input|output>_loop_at_a_time_*`` lists per channel;
    ``disk_margin_skew``; with ``robust`` (keyword arguments of
    :func:`robust_stability_mu`, ``G`` as ``G_nominal``): ``mu_peak``,
    ``mu_peak_freq_hz``, ``mu_lower_peak``, ``mu_robustly_stable``,
    ``sampled_all_stable``, ``sampled_worst``, ``n_parameter_samples``.  Unbounded values
    (``gmax = inf``) are ``None``.

    Parameters
    ----------
    G, K, freq_hz, Ky, delay_samples, dt, skew
        As in :func:`disk_margins` (LTI systems or static gains).
    f_band_hz : (float, float) or None
        Band for the least-damped closed-loop pole [Hz].
    robust : dict or None
        Extra keyword arguments for :func:`robust_stability_mu` (None: skip mu).

    Returns
    -------
    dict
    """
    loop = _Loop(G, K, Ky, delay_samples, dt, allow_stack=False)
    f = loop.check_freq(freq_hz, increasing=True)
    if robust is not None and not isinstance(robust, dict):
        raise TypeError(f"robust: expected a dict of robust_stability_mu keyword arguments or None, "
                        f"got {_describe(robust)}")
    out: dict = {}
    poles = closed_loop_poles(G, K, Ky, loop.d, loop.T)
    discrete = loop.kind == "discrete"
    if not poles.size:
        stable, meas = True, (0.0 if discrete else -math.inf)
    elif discrete:
        meas = float(np.max(np.abs(poles)))
        stable = meas < 1.0
    else:
        meas = float(np.max(poles.real))
        stable = meas < 0.0
    out["closed_loop_stable"] = stable
    out["spectral_radius" if discrete else "max_pole_real_per_s"] = _num(meas)
    if poles.size:
        try:
            ld = least_damped_pole(poles, loop.T if discrete else None, f_band_hz=f_band_hz)
            out["least_damped_zeta"], out["least_damped_freq_hz"] = _num(ld.zeta), _num(ld.freq_hz)
        except ValueError:
            out["least_damped_zeta"] = out["least_damped_freq_hz"] = None
    r = loop.response(f)
    for key, attr in (("So", "S_o"), ("To", "T_o"), ("Si", "S_i"), ("Ti", "T_i"), ("KS", "KS"),
                      ("KS_fb", "KS_fb"), ("SG", "SG"), ("T_ry", "T_ry")):
        pk, fpk = _refine_max(lambda fr, a=attr: sigma_max(getattr(loop.response(fr), a)), f,
                              r.sigma_max(attr), n_peaks=6)
        out[f"peak_{key}"], out[f"peak_{key}_freq_hz"] = _num(pk), _num(fpk)
    rep = disk_margins(G, K, f, Ky, delay_samples=loop.d, dt=loop.T, skew=skew)
    w = rep.worst()
    out["disk_margin_skew"] = rep.skew
    out["disk_margin_alpha"] = _num(w.alpha)
    out["gain_margin_db"] = [_num(w.gain_margin_db[0]), _num(w.gain_margin_db[1])]
    out["phase_margin_deg"] = _num(w.phase_margin_deg)
    out["disk_margin_freq_hz"] = _num(w.freq_hz)
    out["disk_margin_location"] = w.location
    out.update(_dm_dict("dm_input", rep.input))
    out.update(_dm_dict("dm_output", rep.output))
    out.update(_dm_dict("dm_input_output", rep.input_output))
    for name, lat in (("dm_input_loop_at_a_time", rep.input_loop_at_a_time),
                      ("dm_output_loop_at_a_time", rep.output_loop_at_a_time)):
        out[f"{name}_alpha"] = [_num(m.alpha) for m in lat]
        out[f"{name}_gain_margin_db"] = [[_num(m.gain_margin_db[0]), _num(m.gain_margin_db[1])] for m in lat]
        out[f"{name}_phase_margin_deg"] = [_num(m.phase_margin_deg) for m in lat]
        out[f"{name}_freq_hz"] = [_num(m.freq_hz) for m in lat]
    if robust is not None:
        res = robust_stability_mu(G, K, Ky, loop.T, f, nominal_delay_samples=loop.d, **robust)
        out["mu_peak"] = _num(res.mu_peak)
        out["mu_peak_freq_hz"] = _num(res.mu_peak_freq_hz)
        out["mu_lower_peak"] = _num(res.mu_lower_peak)
        out["mu_robustly_stable"] = res.robustly_stable
        out["mu_nominal_stable"] = res.nominal_stable
        out["sampled_all_stable"] = res.sampled_all_stable
        out["sampled_worst"] = _num(res.sampled_worst)
        out["n_parameter_samples"] = res.n_samples
    return out
