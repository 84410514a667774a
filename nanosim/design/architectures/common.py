"""Shared pieces of the controller bench: the design result, filters, decoupling and loop checks.

Every bench architecture (:mod:`nanosim.design.architectures`) is a pure function of the
identified plant ``G`` (controller V -> sensor V, the model ``nanosim identify`` writes)
that returns a :class:`BenchDesign`: a discrete state-space controller with the same
layout as ``controller.npz`` (``Akd, Bkd, Ckd, Dkd, dt, n_error``), so it runs
everywhere a :class:`~nanosim.design.controller.DiscreteController` runs.

The loop as run
---------------
``nanosim identify`` pairs each command with the reading the controller had when it
computed it, so its discrete model already is the loop as run: the designs and every
check here close the loop around the identified model as it is (every design's default
``delay_samples`` is :data:`~nanosim.design.robustness.IDENTIFIED_DELAY_SAMPLES` = 0, pinned by
``tests/test_bench_controllers.py``). ``delay_samples = d`` adds ``z^-d`` for a model identified
from record rows (the reading of the period in which the command was applied), which lacks the
loop's sample of delay (:data:`~nanosim.design.robustness.RECORD_ROW_DELAY_SAMPLES` = 1). A model of
``nanosim identify`` must not get that sample again: it would design and check for one sample more
delay than the stage has.

Filters are continuous prototypes mapped to 4 kHz with Tustin, prewarped at their own
characteristic frequency, so a notch sits exactly on its mode.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from nanosim import constants
from nanosim.design.controller import ControllerConfig, DiscreteController
from nanosim.design.robustness import IDENTIFIED_DELAY_SAMPLES, loop_transfer_response, mu_upper_bound

__all__ = ["DT_S", "IDENTIFIED_DELAY_SAMPLES", "BenchDesign", "stack_2dof", "split_2dof", "as_discrete",
           "as_continuous",
           "dc_gain_z", "lightly_damped_modes", "distinct_modes_hz", "mode_groups", "tf_to_ss", "notch", "lowpass2",
           "pi_leaky", "series_siso", "diag_ss", "static_ss", "freqresp_z", "analysis_grid_hz", "loop_response",
           "disk_margin_summary", "loop_at_a_time_alpha", "sensitivity_bandwidth_hz",
           "reference_error_bandwidth_hz", "max_gain",
           "closed_loop_spectral_radius", "uncertainty_vertex_check"]

DT_S = constants.CONTROL_PERIOD_S
# integrators leak at this corner so that (I - Akd) is invertible (DiscreteController.reset_at needs it)
LEAK_HZ = 0.01


@dataclass(frozen=True, eq=False)
class BenchDesign:
    """One bench controller: the discrete state space and how it was tuned.

    Attributes
    ----------
    name : str
        Bench name (``paper``, ``pi-notch``, ...).
    K : control.StateSpace
        Discrete controller, sample time ``dt``: inputs ``[e]`` (``n_error`` columns) or
        ``[e; y]`` (errors then measurements, sensor V), outputs the commands [controller V].
    n_error : int
        Number of error inputs (3).
    tuning_rule : str
        The rule the design follows, in one sentence.
    parameters : dict
        JSON-ready tuning results (gains, filter corners, predicted margins).
    """

    name: str
    K: Any
    n_error: int
    tuning_rule: str
    parameters: dict = field(default_factory=dict)

    def __post_init__(self):
        if not (self.K.dt and self.K.dt > 0):
            raise ValueError(f"K: expected a discrete system with a sample time, got dt={self.K.dt!r}")
        ControllerConfig(*self.matrices, n_error=self.n_error)     # validates shapes

    @property
    def matrices(self) -> tuple:
        """``(Akd, Bkd, Ckd, Dkd, dt)``."""
        K = self.K
        return (np.asarray(K.A, float), np.asarray(K.B, float), np.asarray(K.C, float), np.asarray(K.D, float),
                float(K.dt))

    Akd = property(lambda self: self.matrices[0])
    Bkd = property(lambda self: self.matrices[1])
    Ckd = property(lambda self: self.matrices[2])
    Dkd = property(lambda self: self.matrices[3])
    dt = property(lambda self: self.matrices[4])

    @property
    def config(self) -> ControllerConfig:
        """The immutable matrices as a :class:`ControllerConfig`."""
        return ControllerConfig(*self.matrices, n_error=self.n_error)

    def controller(self) -> DiscreteController:
        """A fresh :class:`DiscreteController` (zero state)."""
        return DiscreteController(self.config)

    @property
    def two_dof(self) -> bool:
        """True if the controller also reads the measurement ``y``."""
        return self.K.ninputs > self.n_error

    def split(self):
        """``(Ke, Ky)``: the error and measurement parts (``Ky`` None for one degree of freedom)."""
        return split_2dof(self.K, self.n_error)


def stack_2dof(Ke, Ky):
    """``[Ke, Ky]``: one discrete controller with inputs ``[e; y]`` (``u = Ke e + Ky y``)."""
    from nanosim.design.loops import stack_inputs
    return stack_inputs(Ke, Ky)


def split_2dof(K, n_error: int):
    """``(Ke, Ky)`` of ``u = Ke e + Ky y`` from a stacked discrete ``[Ke, Ky]`` (shared states)."""
    import control as ct
    A, B, C, D = (np.asarray(m, float) for m in (K.A, K.B, K.C, K.D))
    Ke = ct.ss(A, B[:, :n_error], C, D[:, :n_error], K.dt)
    if K.ninputs == n_error:
        return Ke, None
    return Ke, ct.ss(A, B[:, n_error:], C, D[:, n_error:], K.dt)


# =====================================================================================
# models
# =====================================================================================
def as_discrete(G, dt: float = DT_S):
    """``G`` at the sample time ``dt``: a discrete model as it is, a continuous one by Tustin.

    The identified continuous model is the inverse Tustin transform of the identified
    discrete one, so Tustin gives the identified discrete model back exactly.
    """
    import control as ct
    _check_lti("G", G)
    if G.dt is None or G.dt == 0 or G.dt is True:
        return ct.ss(ct.c2d(ct.ss(G), dt, "tustin"))
    if abs(G.dt - dt) > 1e-12 * dt:
        raise ValueError(f"G: expected the control period dt = {dt:g} s, got a model sampled at {G.dt:g} s")
    return ct.ss(G)


def as_continuous(G):
    """``G`` in continuous time: a continuous model as it is, a discrete one by inverse Tustin."""
    import control as ct

    from identification.d2c import d2c_tustin
    _check_lti("G", G)
    if not G.dt:
        return ct.ss(G)
    m = d2c_tustin(G.A, G.B, G.C, G.D, float(G.dt))
    return ct.ss(m.A, m.B, m.C, m.D)


def _check_lti(name, G):
    import control as ct
    if not isinstance(G, (ct.StateSpace, ct.TransferFunction)):
        raise ValueError(f"{name}: expected a control.StateSpace (the identified plant), got {type(G).__name__}")
    if G.noutputs != G.ninputs:
        raise ValueError(f"{name}: expected a square plant (3 x 3), got {G.noutputs} x {G.ninputs}")


def dc_gain_z(G) -> np.ndarray:
    """Static gain ``G(z = 1)`` (discrete) or ``G(0)`` (continuous) [sensor V / controller V]."""
    A, B, C, D = (np.asarray(m, float) for m in (G.A, G.B, G.C, G.D))
    M = np.eye(A.shape[0]) - A if G.dt else -A
    return D + C @ np.linalg.solve(M, B)


def lightly_damped_modes(G, zeta_max: float = 0.05, f_min_hz: float = 20.0) -> list[tuple[float, float]]:
    """``(freq_hz, zeta)`` of the lightly damped poles of ``G`` above ``f_min_hz``, ascending.

    Discrete poles are mapped to continuous ones with ``s = ln(z) / dt``.
    """
    p = np.linalg.eigvals(np.asarray(G.A, float))
    if G.dt:
        p = np.log(p.astype(complex)) / float(G.dt)
    w = np.abs(p)
    keep = (p.imag > 0) & (w > 2 * np.pi * f_min_hz) & (-p.real < zeta_max * w)
    out = sorted((float(w[i] / (2 * np.pi)), float(-p[i].real / w[i])) for i in np.flatnonzero(keep))
    return out


def distinct_modes_hz(G, rel_tol: float = 1e-3, **kwargs) -> list[float]:
    """Frequencies [Hz] of :func:`lightly_damped_modes`, repeated ones (within ``rel_tol``,
    the same mode identified in several columns) merged.
    """
    out: list[float] = []
    for f, _ in lightly_damped_modes(G, **kwargs):
        if not out or f > out[-1] * (1 + rel_tol):
            out.append(f)
    return out


def mode_groups(modes, rel_gap: float = 0.05) -> list[tuple[float, float]]:
    """Merge modes closer than ``rel_gap`` (relative) into ``(f_low_hz, f_high_hz)`` groups."""
    groups: list[list[float]] = []
    for f, _ in sorted(modes):
        if groups and f <= groups[-1][1] * (1 + rel_gap):
            groups[-1][1] = f
        else:
            groups.append([f, f])
    return [(lo, hi) for lo, hi in groups]


# =====================================================================================
# filters (SISO, discrete by prewarped Tustin)
# =====================================================================================
def tf_to_ss(num, den, dt: float = DT_S, prewarp_hz: float | None = None):
    """Continuous ``num(s)/den(s)`` -> discrete state space at ``dt`` (Tustin, optional prewarp)."""
    import control as ct
    sys = ct.tf(num, den)
    kw = {} if prewarp_hz is None else {"prewarp_frequency": 2 * np.pi * prewarp_hz}
    return ct.ss(ct.c2d(sys, dt, "tustin", **kw))


def notch(f_hz: float, zeta_pole: float, zeta_zero: float = 0.0, dt: float = DT_S):
    """Notch ``(s^2 + 2 zz w s + w^2)/(s^2 + 2 zp w s + w^2)`` at ``f_hz`` (unit gain far from it)."""
    w = 2 * np.pi * f_hz
    return tf_to_ss([1, 2 * zeta_zero * w, w * w], [1, 2 * zeta_pole * w, w * w], dt, prewarp_hz=f_hz)


def lowpass2(f_hz: float, zeta: float = 0.7, dt: float = DT_S):
    """Second-order low-pass ``w^2/(s^2 + 2 zeta w s + w^2)`` at ``f_hz``."""
    w = 2 * np.pi * f_hz
    return tf_to_ss([w * w], [1, 2 * zeta * w, w * w], dt, prewarp_hz=f_hz)


def pi_leaky(gain: float, zero_hz: float, dt: float = DT_S, leak_hz: float = LEAK_HZ):
    """PI ``gain (s + wz)/(s + wl)``: proportional ``gain`` above ``zero_hz``, integral below
    (the integrator leaks below ``leak_hz`` so the state-space has no pole at ``z = 1``).
    """
    wz, wl = 2 * np.pi * zero_hz, 2 * np.pi * leak_hz
    return tf_to_ss([gain, gain * wz], [1, wl], dt)


def series_siso(*systems):
    """Product of SISO systems (in order of application)."""
    import control as ct
    out = systems[0]
    for s in systems[1:]:
        out = ct.series(out, s)
    return ct.ss(out)


def diag_ss(systems):
    """Block-diagonal MIMO system from a list of SISO (or MIMO) discrete systems."""
    import control as ct
    from scipy.linalg import block_diag
    dt = systems[0].dt
    A = block_diag(*[np.asarray(s.A, float) for s in systems])
    B = block_diag(*[np.asarray(s.B, float) for s in systems])
    C = block_diag(*[np.asarray(s.C, float) for s in systems])
    D = block_diag(*[np.asarray(s.D, float) for s in systems])
    return ct.ss(A, B, C, D, dt)


def static_ss(M, dt: float = DT_S):
    """A static gain matrix as a state-less discrete system."""
    import control as ct
    M = np.atleast_2d(np.asarray(M, float))
    return ct.ss(np.zeros((0, 0)), np.zeros((0, M.shape[1])), np.zeros((M.shape[0], 0)), M, dt)


# =====================================================================================
# fast loop checks (frequency responses, disk margins through nanosim's loop analysis)
# =====================================================================================
def freqresp_z(sys_, freq_hz) -> np.ndarray:
    """Frequency response of a discrete system, shape ``(F, ny, nu)`` (:func:`~nanosim.design.lti.ss_response`
    at ``z = exp(j 2 pi f dt)``).
    """
    from nanosim.design.lti import ss_response
    z = np.exp(2j * np.pi * np.asarray(freq_hz, float) * float(sys_.dt))
    return ss_response(sys_.A, sys_.B, sys_.C, sys_.D, z)


def analysis_grid_hz(dt: float = DT_S, n: int = 700, modes=()) -> np.ndarray:
    """Log grid from 0.1 Hz to just below Nyquist, densified around ``modes`` (Hz)."""
    nyq = 0.5 / dt
    f = np.logspace(-1, np.log10(0.999 * nyq), n)
    extra = [f0 * np.linspace(0.9, 1.1, 81) for f0 in modes if f0 < 0.95 * nyq]
    return np.unique(np.concatenate([f, *extra])) if extra else f


def loop_response(Gf, freq_hz, Ke, Ky=None, delay_samples: int = IDENTIFIED_DELAY_SAMPLES, dt: float = DT_S):
    """:class:`~nanosim.design.robustness.LoopResponse` of ``u = Ke e + Ky y`` around the plant
    response ``Gf`` (F, ny, nu) on ``freq_hz``, with ``delay_samples`` of input delay.
    """
    Kf = freqresp_z(Ke, freq_hz)
    Kyf = None if Ky is None else freqresp_z(Ky, freq_hz)
    return loop_transfer_response(Gf, Kf, freq_hz, Ky=Kyf, delay_samples=delay_samples, dt=dt)


def loop_at_a_time_alpha(Gf, Kf, delay_samples: int = IDENTIFIED_DELAY_SAMPLES, dt: float = DT_S,
                         freq_hz=None) -> float:
    """Smallest loop-at-a-time symmetric disk margin at plant input and output, from the
    responses ``Gf`` (F, ny, nu) and ``Kf`` (F, nu, ny) of plant and feedback operator
    (fast: no validation, for tuning loops; ``freq_hz`` needed with a delay).
    """
    if delay_samples:
        Gf = Gf * np.exp(-2j * np.pi * np.asarray(freq_hz) * delay_samples * dt)[:, None, None]
    from nanosim.design.loops import sensitivities
    So, Si = sensitivities(Gf, Kf)[2:]
    peak = max(np.abs(np.diagonal(So, axis1=1, axis2=2) - 0.5).max(),
               np.abs(np.diagonal(Si, axis1=1, axis2=2) - 0.5).max())
    return float(1.0 / peak)


def _symmetric_alpha_siso(S) -> float:
    return float(1.0 / np.max(np.abs(S - 0.5)))


def disk_margin_summary(r, multiloop: bool = True) -> dict:
    """Symmetric disk margins of a :class:`LoopResponse` on its grid (no refinement).

    ``loop_at_a_time``: the smallest single-loop ``alpha`` at plant input and output;
    ``multiloop``: the smaller of the simultaneous input and output margins
    (``1 / sup mu(S - I/2)`` with diagonal complex perturbations, upper bound; skipped,
    the slow part, with ``multiloop=False``).
    """
    n_o, n_i = r.S_o.shape[1], r.S_i.shape[1]
    lat_o = [_symmetric_alpha_siso(r.S_o[:, k, k]) for k in range(n_o)]
    lat_i = [_symmetric_alpha_siso(r.S_i[:, k, k]) for k in range(n_i)]
    if not multiloop:
        return {"loop_at_a_time": min(lat_o + lat_i), "loop_at_a_time_output": lat_o,
                "loop_at_a_time_input": lat_i}
    mo = mu_upper_bound(r.S_o - 0.5 * np.eye(n_o), [(1, 1)] * n_o, lower=False, peak_only=True).upper
    mi = mu_upper_bound(r.S_i - 0.5 * np.eye(n_i), [(1, 1)] * n_i, lower=False, peak_only=True).upper
    return {"loop_at_a_time": min(lat_o + lat_i), "loop_at_a_time_output": lat_o, "loop_at_a_time_input": lat_i,
            "multiloop": float(1.0 / max(mo.max(), mi.max())), "multiloop_output": float(1.0 / mo.max()),
            "multiloop_input": float(1.0 / mi.max())}


def sensitivity_bandwidth_hz(r, level: float = 1 / math.sqrt(2)) -> float:
    """First frequency where ``sigma_max(S_o)`` rises through ``level`` (-3 dB) [Hz]."""
    return _first_rise_hz(np.linalg.norm(r.S_o, ord=2, axis=(1, 2)), r.freq_hz, level)


def reference_error_bandwidth_hz(r, level: float = 1 / math.sqrt(2)) -> float:
    """First frequency where ``sigma_max(I - T_ry)``, reference to error through the whole two-degree-of-freedom
    controller (prefilter included), rises through ``level`` (-3 dB) [Hz]: what the bandwidth experiment's
    reference-to-error PRBS measures. Equal to :func:`sensitivity_bandwidth_hz` for a one-degree-of-freedom loop.
    """
    E = np.eye(r.T_ry.shape[1])[None] - r.T_ry
    return _first_rise_hz(np.linalg.norm(E, ord=2, axis=(1, 2)), r.freq_hz, level)


def _first_rise_hz(s: np.ndarray, f: np.ndarray, level: float) -> float:
    """First frequency of ``f`` where ``s`` rises through ``level``, log-linear between grid points [Hz]."""
    above = np.flatnonzero(s >= level)
    if not above.size:
        return float("inf")
    i = int(above[0])
    if i == 0:
        return float(f[0])
    x0, x1 = np.log(f[i - 1]), np.log(f[i])
    t = (level - s[i - 1]) / (s[i] - s[i - 1])
    return float(np.exp(x0 + t * (x1 - x0)))


def closed_loop_spectral_radius(Gd, Ke, Ky=None, delay_samples: int = IDENTIFIED_DELAY_SAMPLES) -> float:
    """Spectral radius of the discrete loop ``u = Ke (r - y) + Ky y`` around ``z^-d Gd``."""
    A, B, C, D = (np.asarray(m, float) for m in (Gd.A, Gd.B, Gd.C, Gd.D))
    ny, nu = C.shape[0], B.shape[1]
    d = int(delay_samples)
    # plant with d unit delays at its input: states [x; q1..qd], q_d feeds the plant
    n, nq = A.shape[0], d * nu
    Ap = np.zeros((n + nq, n + nq))
    Ap[:n, :n] = A
    Bp = np.zeros((n + nq, nu))
    Cp = np.zeros((ny, n + nq))
    Cp[:, :n] = C
    Dp = np.zeros((ny, nu))
    if d == 0:
        Bp[:n], Dp = B, D
    else:
        Ap[:n, n + nq - nu:] = B
        Cp[:, n + nq - nu:] = D
        for j in range(1, d):
            Ap[n + j * nu:n + (j + 1) * nu, n + (j - 1) * nu:n + j * nu] = np.eye(nu)
        Bp[n:n + nu] = np.eye(nu)
    Ak, Bk, Ck, Dk = (np.asarray(m, float) for m in (Ke.A, Ke.B, Ke.C, Ke.D))
    if Ky is not None:   # feedback operator Kfb = Ke - Ky (shared states)
        Bk = Bk - np.asarray(Ky.B, float)
        Dk = Dk - np.asarray(Ky.D, float)
    # u = -Kfb y (r = 0): y = Cp xp + Dp u; xk+ = Ak xk - Bk y; u = Ck xk - Dk y
    M = np.linalg.inv(np.eye(nu) + Dk @ Dp)
    # u = M (Ck xk - Dk Cp xp)
    Au_p, Au_k = -M @ Dk @ Cp, M @ Ck
    y_p, y_k = Cp + Dp @ Au_p, Dp @ Au_k
    top = np.hstack([Ap + Bp @ Au_p, Bp @ Au_k])
    bot = np.hstack([-Bk @ y_p, Ak - Bk @ y_k])
    Acl = np.vstack([top, bot])
    return float(np.max(np.abs(np.linalg.eigvals(Acl)))) if Acl.size else 0.0


def uncertainty_vertex_check(Gd, Ke, Ky=None, uncertainty=None, *, n_random: int = 32, seed: int = 0,
                             input_gain_of_nominal: float = 1.0) -> dict:
    """Brute-force robust stability of ``u = Ke (r - y) + Ky y`` over a parametric uncertainty set.

    Every vertex of ``uncertainty`` (default :data:`~nanosim.design.uncertainty.STAGE_UNCERTAINTY`:
    both ends of the modal frequency and damping factors and of the extra delay, and each input's
    gain at either end, ``2^(3 + nu)`` plants) plus ``n_random`` uniform samples (log-uniform
    damping factor, integer delay), each built by :class:`~nanosim.design.uncertainty.ModalPlant`
    from the discrete ``Gd`` (the loop as run) and closed with
    :func:`closed_loop_spectral_radius`. A sampled check, not a certificate: fast enough for a
    tuning rule (about 0.2 s for 96 plants of a 37-state model). ``input_gain_of_nominal``: the piezo
    gain ``Gd`` holds as a factor on the set's nominal (an identified model:
    :data:`~nanosim.design.robustness.IDENTIFIED_INPUT_GAIN_OF_NOMINAL`); the set's gains are mapped by it.

    Returns
    -------
    dict
        ``n_checked``, ``n_unstable``, ``all_stable``, ``worst_spectral_radius`` and
        ``worst`` (``freq_scale``, ``damping_scale``, ``input_gain`` list, ``extra_delay_samples``).
    """
    import itertools

    from nanosim.design.uncertainty import STAGE_UNCERTAINTY, ModalPlant
    u = STAGE_UNCERTAINTY if uncertainty is None else uncertainty
    if not (isinstance(n_random, int) and n_random >= 0):
        raise ValueError(f"n_random: expected an integer >= 0, got {n_random!r}")
    mp = ModalPlant(Gd, float(Gd.dt))
    nu = int(np.asarray(Gd.B).shape[1])
    g0, g1 = u.input_gain_range_about(input_gain_of_nominal)
    pts = [(fs, zs, tuple(g), d) for fs, zs, d in itertools.product(u.freq_scale_range, u.damping_scale_range,
                                                                     u.extra_delay_samples_range)
           for g in itertools.product((g0, g1), repeat=nu)]
    rng = np.random.default_rng(seed)
    lz = np.log(np.asarray(u.damping_scale_range, float))
    d0, d1 = (int(v) for v in u.extra_delay_samples_range)
    for _ in range(n_random):
        pts.append((float(rng.uniform(*u.freq_scale_range)), float(np.exp(rng.uniform(*lz))),
                    tuple(float(x) for x in rng.uniform(g0, g1, nu)), int(rng.integers(d0, d1 + 1))))
    worst, arg, bad = -1.0, None, 0
    for fs, zs, g, d in pts:
        rho = closed_loop_spectral_radius(mp.state_space(fs, zs, np.array(g), int(d)), Ke, Ky, 0)
        bad += rho >= 1.0
        if rho > worst:
            worst, arg = rho, (fs, zs, g, d)
    return {"n_checked": len(pts), "n_unstable": int(bad), "all_stable": bool(bad == 0),
            "worst_spectral_radius": float(worst),
            "worst": {"freq_scale": float(arg[0]), "damping_scale": float(arg[1]),
                      "input_gain": [float(x) for x in arg[2]], "extra_delay_samples": int(arg[3])}}


def max_gain(ok: Callable[[float], bool], lo: float, hi: float, rel_tol: float = 0.01, max_iter: int = 40) -> float:
    """Largest ``k`` in ``[lo, hi]`` with ``ok(k)`` by geometric bisection (``ok(lo)`` must hold).

    Raises
    ------
    ValueError
        ``ok(lo)`` is false: no gain in the range meets the rule.
    """
    if not ok(lo):
        raise ValueError(f"no gain in [{lo:g}, {hi:g}] meets the tuning rule (it fails at the lowest gain {lo:g})")
    if ok(hi):
        return hi
    for _ in range(max_iter):
        if hi / lo < 1 + rel_tol:
            break
        mid = math.sqrt(lo * hi)
        if ok(mid):
            lo = mid
        else:
            hi = mid
    return lo
