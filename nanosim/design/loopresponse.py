"""Loop transfer matrices of a MIMO feedback loop, in frequency and in state space.

Conventions
-----------
Shared by :mod:`~nanosim.design.margins`, :mod:`~nanosim.design.mu`,
:mod:`~nanosim.design.uncertainty` and :mod:`~nanosim.design.robustness`.

Plant and controller
    ``G`` is ``ny x nu`` (controller volts in, sensor volts out).  Negative feedback,
    ``e = r - y``.  The controller may be two-degree-of-freedom::

        u = K e + Ky y          K, Ky: nu x ny  (Ky may be None, i.e. zero)

    The *feedback operator* is ``Kfb = K - Ky``, so ``u = K r - Kfb y``.  Only ``Kfb``
    decides stability and margins; ``K`` alone enters the reference paths.  (The
    stage's default controller is such an H-infinity ``K`` around an inner damping
    loop ``Ky``, :mod:`nanosim.design.damping`.)
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
    first.  Frequencies are in Hz (``freq_hz``); ``s = j 2 pi f``,
    ``z = exp(j 2 pi f dt)``.  Angles are in degrees, gains are factors unless a name
    ends in ``_db``.
Time base
    Systems may be continuous or discrete (``dt`` = control period, 250e-6 s on the
    stage); all LTI arguments of one call share it (:mod:`~nanosim.design.loopargs`).
    Discrete frequency grids must not exceed the Nyquist frequency ``1 / (2 dt)``.
Delay
    ``delay_samples = d`` (0, 1, ...) is a computation delay at the plant input, the
    same in every input channel: ``Gd = G z^-d`` (discrete) or ``Gd = G exp(-s d dt)``
    (continuous).  In *frequency responses* it is the exact factor
    ``exp(-j 2 pi f d dt)``.  In *state space* a discrete plant gets ``d`` exact
    unit-delay states per input; a continuous plant a Pade approximant of order
    ``pade_order`` per input (an approximation).
"""
from __future__ import annotations

import math
import numbers
import warnings
from dataclasses import dataclass

import control as ct
import numpy as np
import scipy.linalg

from nanosim.design.loopargs import (
    check_delay,
    check_freq,
    check_system,
    io_shape,
    is_lti,
    timebase,
)
from nanosim.design.loops import feedback_operator, sensitivities, stack_inputs
from nanosim.design.lti import freqresp, sigma_max

__all__ = ["LOOP_MAPS", "LoopResponse", "LoopStateSpace", "PreparedLoop", "frequency_response", "response_stack",
           "delay_factor", "loop_transfer_response", "loop_transfer_ss", "closed_loop_poles", "to_state_space",
           "delay_ss", "delayed_plant_ss", "feedback_operator_ss", "closed_loop_matrix", "stability"]

LOOP_MAPS = ("S_o", "T_o", "S_i", "T_i", "KS", "KS_fb", "SG", "T_ry", "Lo", "Li")


# =====================================================================================
# frequency responses
# =====================================================================================
def response_stack(x, f: np.ndarray, name: str) -> np.ndarray:
    """``x`` (LTI, static gain or response stack) on the grid ``f`` [Hz] as a complex
    ``(F, rows, cols)`` stack; raises if it is not finite (a pole on the grid).
    """
    F = f.size
    if is_lti(x):
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            H = np.asarray(freqresp(x, f), dtype=complex)
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
    """Checked frequency response of an LTI system or static gain, frequency first.

    Parameters
    ----------
    sys : control.StateSpace, control.TransferFunction, array_like or float
        Continuous systems are evaluated at ``s = j 2 pi f``, discrete ones at
        ``z = exp(j 2 pi f dt)`` (:func:`nanosim.design.lti.freqresp`).  A 2-D array
        is a static gain.
    freq_hz : array_like, shape (F,)
        Frequencies [Hz], >= 0 (and <= Nyquist for discrete systems).

    Returns
    -------
    ndarray, complex, shape (F, noutputs, ninputs)
    """
    check_system("sys", sys, allow_stack=False)
    kind, T = timebase({"sys": sys}, None)
    return response_stack(sys, check_freq(freq_hz, kind, T), "sys")


def delay_factor(f: np.ndarray, d: int, T) -> np.ndarray:
    """``exp(-j 2 pi f d T)`` on the grid ``f`` [Hz] (ones for ``d = 0``)."""
    if d == 0:
        return np.ones(f.size, dtype=complex)
    return np.exp(-2j * np.pi * f * d * T)


@dataclass(frozen=True, eq=False)
class LoopResponse:
    """Closed-loop frequency responses (definitions in the module docstring).

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
        ``Kfb S_o``: sensor noise / output disturbance to ``-u`` [V/V].
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
        for name in ("freq_hz",) + LOOP_MAPS:
            getattr(self, name).setflags(write=False)

    def sigma_max(self, name: str) -> np.ndarray:
        """``sigma_max`` of the map ``name`` (one of :data:`LOOP_MAPS`) per grid frequency, (F,)."""
        if name not in LOOP_MAPS:
            raise ValueError(f"name: expected one of {LOOP_MAPS}, got {name!r}")
        return sigma_max(getattr(self, name))

    def peak(self, name: str) -> tuple[float, float]:
        """``(max_f sigma_max, frequency [Hz])`` of the map ``name`` on the grid (not refined)."""
        s = self.sigma_max(name)
        i = int(np.argmax(s))
        return float(s[i]), float(self.freq_hz[i])


def _loop_from_stacks(f, Gf, Kf, Kyf, d, T) -> LoopResponse:
    ny, nu = Gf.shape[1:]
    Gd = Gf * delay_factor(f, d, T)[:, None, None] if d else Gf
    Kfb = Kf if Kyf is None else Kf - Kyf
    Iy, Iu = np.eye(ny), np.eye(nu)
    Lo, Li, S_o, S_i = sensitivities(Gd, Kfb)
    SG = S_o @ Gd
    return LoopResponse(freq_hz=f.copy(), S_o=S_o, T_o=Iy - S_o, S_i=S_i, T_i=Iu - S_i,
                        KS=S_i @ Kf, KS_fb=Kfb @ S_o, SG=SG, T_ry=SG @ Kf, Lo=Lo, Li=Li, delay_samples=d)


class PreparedLoop:
    """Validated loop arguments; evaluates :class:`LoopResponse` on any grid.

    Parameters
    ----------
    G, K, Ky, delay_samples, dt
        As in :func:`loop_transfer_response`.
    allow_stack : bool
        Accept ``(F, rows, cols)`` response stacks (frequency-only analyses).

    Attributes
    ----------
    ny, nu, d : int
        Outputs, inputs, delay [samples].
    kind : {'discrete', 'continuous', None}
    T : float or None
        Sample period [s].
    has_stack, all_lti : bool
    """

    def __init__(self, G, K, Ky, delay_samples, dt, *, allow_stack=True):
        check_system("G", G, allow_stack=allow_stack)
        check_system("K", K, allow_stack=allow_stack)
        check_system("Ky", Ky, allow_none=True, allow_stack=allow_stack)
        ny, nu = io_shape(G)
        for name, x in (("K", K), ("Ky", Ky)):
            if x is not None and io_shape(x) != (nu, ny):
                r, c = io_shape(x)
                raise ValueError(f"{name}: expected {nu} outputs x {ny} inputs (nu x ny for a plant G "
                                 f"with {ny} outputs and {nu} inputs), got {r} x {c}")
        self.ny, self.nu = ny, nu
        self.d = check_delay(delay_samples)
        self.kind, self.T = timebase({"G": G, "K": K, "Ky": Ky}, dt)
        if self.d and self.T is None:
            raise ValueError(f"dt: delay_samples={self.d} needs the sample period dt [s] "
                             f"(none of G, K, Ky is discrete)")
        self.G, self.K, self.Ky = G, K, Ky
        self.has_stack = any(isinstance(x, (np.ndarray, list, tuple)) and np.ndim(x) == 3
                             for x in (G, K, Ky) if x is not None)
        self.all_lti = all(is_lti(x) or np.ndim(x) in (0, 2) for x in (G, K, Ky) if x is not None)

    def check_freq(self, freq_hz, increasing=False) -> np.ndarray:
        """The checked grid [Hz] (response stacks must match its length)."""
        f = check_freq(freq_hz, self.kind, self.T, increasing=increasing)
        for name, x in (("G", self.G), ("K", self.K), ("Ky", self.Ky)):
            if x is not None and not is_lti(x) and np.ndim(x) == 3 and np.shape(x)[0] != f.size:
                raise ValueError(f"{name}: frequency-response stack has {np.shape(x)[0]} frequencies, "
                                 f"expected {f.size} (one per freq_hz entry)")
        return f

    def response(self, f) -> LoopResponse:
        """:class:`LoopResponse` on the (checked) grid ``f`` [Hz]."""
        Gf = response_stack(self.G, f, "G")
        Kf = response_stack(self.K, f, "K")
        Kyf = None if self.Ky is None else response_stack(self.Ky, f, "Ky")
        try:
            return _loop_from_stacks(f, Gf, Kf, Kyf, self.d, self.T)
        except np.linalg.LinAlgError as exc:
            raise ValueError("the loop is singular (I + G Kfb not invertible) at some grid "
                             "frequency; move the grid off that point") from exc

    @property
    def dt_sys(self):
        """Time base of state-space realizations: ``T`` (discrete) or 0."""
        return self.T if self.kind == "discrete" else 0

    def closed_loop_A(self, pade_order: int = 3) -> np.ndarray:
        """State matrix of the closed loop (plant, delay, ``K``, ``Ky`` states)."""
        Gs = delayed_plant_ss(self.G, self.d, self.kind, self.T, pade_order, self.dt_sys, self.nu)
        Kys = None if self.Ky is None else to_state_space(self.Ky, self.dt_sys, "Ky")
        return closed_loop_matrix(Gs, feedback_operator_ss(to_state_space(self.K, self.dt_sys, "K"), Kys,
                                                           self.dt_sys))

    def stability(self, pade_order: int = 3):
        """``(stable, measure)`` of the nominal loop, or None with response stacks."""
        if self.has_stack or not self.all_lti:
            return None
        return stability(self.closed_loop_A(pade_order), self.kind == "discrete")


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
        Computation delay at the plant input [samples]: the factor
        ``exp(-j 2 pi f d dt)`` multiplies ``G``.
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
    loop = PreparedLoop(G, K, Ky, delay_samples, dt)
    return loop.response(loop.check_freq(freq_hz))


# =====================================================================================
# state-space loop functions
# =====================================================================================
def to_state_space(x, dt_sys, name: str) -> ct.StateSpace:
    """State-space form of an LTI system or static gain with time base ``dt_sys``."""
    if is_lti(x):
        s = ct.ss(x)
        A, B, C, D = (np.asarray(m, dtype=float) for m in (s.A, s.B, s.C, s.D))
        return ct.ss(A, B, C, D, dt_sys)
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        a = a.reshape(1, 1)
    if a.ndim != 2:
        raise ValueError(f"{name}: a state-space loop needs LTI systems or 2-D gains, got shape {a.shape}")
    return ct.ss(np.zeros((0, 0)), np.zeros((0, a.shape[1])), np.zeros((a.shape[0], 0)), a, dt_sys)


def delay_ss(n: int, d: int, kind, T, pade_order: int, dt_sys) -> ct.StateSpace | None:
    """``d`` samples of delay in each of ``n`` channels: exact unit delays (discrete) or a
    Pade approximant of ``exp(-s d T)`` (continuous); None for ``d = 0``.
    """
    if d == 0:
        return None
    if kind == "discrete":
        one = ct.ss(ct.tf([1.0], [1.0] + [0.0] * d, T))
    else:
        num, den = ct.pade(d * T, pade_order)
        one = ct.ss(ct.tf(num, den))
    mats = [scipy.linalg.block_diag(*[getattr(one, m)] * n) for m in "ABCD"]
    return ct.ss(*mats, dt_sys)


def delayed_plant_ss(G, d, kind, T, pade_order, dt_sys, nu) -> ct.StateSpace:
    """``G`` with the input delay of :func:`delay_ss` in series (states ``[delay; G]``)."""
    Gs = to_state_space(G, dt_sys, "G")
    Dl = delay_ss(nu, d, kind if kind else "continuous", T, pade_order, dt_sys)
    if Dl is not None:
        Gs = ct.series(Dl, Gs)
        Gs = ct.ss(Gs.A, Gs.B, Gs.C, Gs.D, dt_sys)
    return Gs


def _stacked(Ks: ct.StateSpace, Kys: ct.StateSpace | None, dt_sys) -> ct.StateSpace:
    """``[K, Ky]`` with inputs ``[e; y]`` (:func:`nanosim.design.loops.stack_inputs`)."""
    nu, ny = Ks.noutputs, Ks.ninputs
    if Kys is None:
        Kys = ct.ss(np.zeros((0, 0)), np.zeros((0, ny)), np.zeros((nu, 0)), np.zeros((nu, ny)), dt_sys)
    K2 = stack_inputs(Ks, Kys)
    return ct.ss(K2.A, K2.B, K2.C, K2.D, dt_sys)


def feedback_operator_ss(Ks: ct.StateSpace, Kys: ct.StateSpace | None, dt_sys) -> ct.StateSpace:
    """``Kfb = K - Ky`` as one realization (the loop is ``u = -Kfb y``)."""
    Kfb = feedback_operator(_stacked(Ks, Kys, dt_sys), Ks.ninputs)
    return ct.ss(Kfb.A, Kfb.B, Kfb.C, Kfb.D, dt_sys)


def closed_loop_matrix(Gs: ct.StateSpace, Kfb: ct.StateSpace) -> np.ndarray:
    """State matrix of ``u = -Kfb y`` around ``Gs`` (states ``[x_G; x_K]``)."""
    A, B, C, D = Gs.A, Gs.B, Gs.C, Gs.D
    Ak, Bk, Ck, Dk = Kfb.A, Kfb.B, Kfb.C, Kfb.D
    W = np.eye(B.shape[1]) + Dk @ D
    if np.linalg.cond(W) > 1e12:
        raise ValueError("the loop is not well posed: I + Kfb(inf) G(inf) is singular")
    E = np.linalg.inv(W)
    Cy = C - D @ E @ Dk @ C
    return np.block([[A - B @ E @ Dk @ C, B @ E @ Ck],
                     [-Bk @ Cy, Ak - Bk @ D @ E @ Ck]])


def stability(A: np.ndarray, discrete: bool) -> tuple[bool, float]:
    """``(stable, measure)``: spectral radius (discrete) or largest real part [1/s]."""
    if A.size == 0:
        return True, (0.0 if discrete else -math.inf)
    p = np.linalg.eigvals(A)
    if discrete:
        m = float(np.max(np.abs(p)))
        return bool(m < 1.0), m
    m = float(np.max(p.real))
    return bool(m < 0.0), m


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
        Computation delay at the plant input (see the module docstring).
    dt : float or None
        Control period [s] (taken from the discrete systems when None).
    pade_order : int
        Order of the Pade approximant for continuous delays.

    Returns
    -------
    LoopStateSpace
    """
    loop = PreparedLoop(G, K, Ky, delay_samples, dt, allow_stack=False)
    if isinstance(pade_order, bool) or not isinstance(pade_order, numbers.Integral) or pade_order < 1:
        raise ValueError(f"pade_order: expected a positive integer, got {pade_order!r}")
    ny, nu, d, dt_sys = loop.ny, loop.nu, loop.d, loop.dt_sys
    Gs = delayed_plant_ss(G, d, loop.kind, loop.T, pade_order, dt_sys, nu)
    Ks = to_state_space(K, dt_sys, "K")
    Kys = None if Ky is None else to_state_space(Ky, dt_sys, "Ky")
    K2 = _stacked(Ks, Kys, dt_sys)                        # inputs [e; y]
    Be, By, De, Dy = K2.B[:, :ny], K2.B[:, ny:], K2.D[:, :ny], K2.D[:, ny:]
    C2 = ct.ss(K2.A, np.hstack([Be, By - Be]), K2.C, np.hstack([De, Dy - De]), dt_sys)   # inputs [r; y]
    W = np.eye(ny) + Gs.D @ (De - Dy)
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
    CL = ct.ss(Ag, B_gen, C_gen, D_gen, dt_sys).lft(C2, nu=nu, ny=2 * ny)
    CL = ct.ss(CL.A, CL.B, CL.C, CL.D, dt_sys)
    r, di, do = slice(0, ny), slice(ny, ny + nu), slice(ny + nu, 2 * ny + nu)
    y, u, up, yp = slice(0, ny), slice(ny, ny + nu), slice(ny + nu, ny + 2 * nu), \
        slice(ny + 2 * nu, 2 * ny + 2 * nu)

    def sub(o, i, sign=1.0):
        return ct.ss(CL.A, CL.B[:, i], sign * CL.C[o, :], sign * CL.D[o, i], dt_sys)

    stable, meas = stability(CL.A, loop.kind == "discrete")
    return LoopStateSpace(S_o=sub(y, do), T_o=sub(yp, do, -1.0), S_i=sub(up, di), T_i=sub(u, di, -1.0),
                          KS=sub(u, r), KS_fb=sub(u, do, -1.0), SG=sub(y, di), T_ry=sub(y, r),
                          closed_loop=CL, stable=stable, stability_measure=meas, delay_samples=d)


def closed_loop_poles(G, K, Ky=None, delay_samples: int = 0, dt=None, *, pade_order: int = 3) -> np.ndarray:
    """Poles of ``u = K e + Ky y`` around ``G`` (with the delay states, see
    :func:`loop_transfer_ss`): ``z`` for discrete loops, ``s`` [rad/s] for continuous.

    Returns
    -------
    ndarray, complex, shape (n_states,)
    """
    A = PreparedLoop(G, K, Ky, delay_samples, dt, allow_stack=False).closed_loop_A(pade_order)
    return np.linalg.eigvals(A) if A.size else np.zeros(0, dtype=complex)
