"""H-infinity mixed-sensitivity design (paper Sec. 4.2, Appendix B; Figs. 11-13, 21-22).

* :func:`generalized_plant` -- ``P = augw(G, Wp I, Wu I, Wt I)`` with the weights of
  :mod:`nanosim.design.weights`;
* :func:`check_assumptions` -- the standard H-infinity assumptions on ``P``, in
  plain language, before slycot is called;
* :func:`design_hinf` -- S / KS / T synthesis (``control.augw`` +
  ``control.hinfsyn`` = ``control.mixsyn``) and the closed-loop analysis with the
  nominal, full and twin plants (:class:`Design`).

Units and the sign convention: see :mod:`nanosim.design.lti`.
"""
from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from nanosim.design.loops import (
    LoopAnalysis,
    analyse_loop,
    feedback_operator,
    loop_freqresp,
    loop_functions,
    stack_inputs,
)
from nanosim.design.lti import (
    AXIS_RTOL,
    BANDWIDTH_DEFINITIONS,
    SIGN_CONVENTION,
    analysis_grid_hz,
    as_ss,
    freqresp,
    sigma_max,
    single_threaded_blas,
)
from nanosim.design.weights import Weights

if TYPE_CHECKING:
    from nanosim.design.damping import DampingLoop
    from nanosim.design.discretize import Discretization
    from nanosim.design.reduction import Reduction

__all__ = ["AssumptionReport", "check_assumptions", "generalized_plant", "Design", "design_hinf"]


# =====================================================================================
# generalized plant and H-infinity assumptions
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
        """One line if all assumptions hold, else one line per failure."""
        if self.ok:
            return "all H-infinity assumptions hold"
        return "H-infinity assumptions violated:\n- " + "\n- ".join(self.failures)


def _fmt_s(p: complex) -> str:
    p = complex(p)
    if abs(p.imag) < 1e-12 * max(1.0, abs(p)):
        return f"s = {p.real:.4g} rad/s"
    return (f"s = {p.real:.3g} {'+' if p.imag >= 0 else '-'} {abs(p.imag):.4g}j rad/s "
            f"({abs(p.imag) / (2 * np.pi):.4g} Hz)")


def _feedthrough_rank(M) -> int:
    """Numerical rank of a feedthrough block: singular values above ``sqrt(eps) * max(1, sigma_max)``."""
    sv = np.linalg.svd(M, compute_uv=False) if M.size else np.zeros(0)
    return int(np.sum(sv > np.sqrt(np.finfo(float).eps) * max(1.0, sv.max(initial=0.0))))


def _on_axis(p, rtol):
    return abs(p.real) <= rtol * max(1.0, abs(p))


def _axis_zeros(A, B2, C1, D12, axis_rtol, tol, smin) -> list:
    """Imaginary-axis zeros of ``[A - sI, B2; C1, D12]`` (D12 full column rank): the
    eigenvalues ``q`` (Im q >= 0) of ``A - B2 D12^+ C1`` on the axis where
    ``[A - B2 D12^+ C1 - qI; (I - D12 D12^+) C1]`` loses column rank.
    """
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

    - (A1) ``(A, B2)`` stabilizable and ``(C2, A)`` detectable;
    - (A2) ``D12`` full column rank and ``D21`` full row rank;
    - (A3) ``[A - jwI, B2; C1, D12]`` full column rank for all ``w`` (no
      imaginary-axis zeros of the ``u -> z`` block P12);
    - (A4) ``[A - jwI, B1; C2, D21]`` full row rank for all ``w`` (no
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
    P = as_ss("P", P)
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

    Parameters
    ----------
    G : control.StateSpace
        Plant, ``ny x nu`` (controller V -> sensor V), continuous.
    weights : Weights, mapping, .json/.toml path or None
        ``None`` = the paper's weights.

    Returns
    -------
    control.StateSpace
        ``P`` with ``ny + nu`` inputs and ``ny + nu + ny + ny`` outputs (``Wt`` rows
        only if ``Wt`` is given; likewise ``Wp``, ``Wu``).
    """
    import control as ct
    G = as_ss("G", G)
    W = Weights.coerce(weights)
    W.check()
    wp, wu, wt = W.statespace(G.noutputs, G.ninputs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        warnings.simplefilter("ignore", DeprecationWarning)
        return ct.augw(G, wp, wu, wt)


# =====================================================================================
# synthesis and the Design result
# =====================================================================================
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
        Set by :func:`nanosim.pipeline.design.run_design`.
    discretization : Discretization or None
        Set by :func:`nanosim.pipeline.design.run_design`.
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
        """Closed loop with the nominal model is stable."""
        return self.nominal.stable

    @property
    def stable_full(self) -> bool | None:
        """Closed loop with the full model is stable (None without ``G_full``)."""
        return None if self.full is None else self.full.stable

    @property
    def stable_twin(self) -> bool | None:
        """Closed loop with the twin is stable (None without ``G_twin``)."""
        return None if self.twin is None else self.twin.stable

    def sigma_S_at(self, freq_hz: float, which: str = "nominal") -> float:
        """``sigma_max(S(j 2 pi f))`` for the nominal or full plant."""
        G = self.G_nominal if which == "nominal" else self.G_full
        f = np.array([float(freq_hz)])
        return float(sigma_max(loop_freqresp(freqresp(G, f), freqresp(self.K, f))[0])[0])

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


@single_threaded_blas
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
    import control as ct
    G = as_ss("G_nominal", G_nominal)
    ny, nu = G.noutputs, G.ninputs
    for nm, g in (("G_full", G_full), ("G_twin", G_twin)):
        if g is not None:
            g = as_ss(nm, g)
            if (g.noutputs, g.ninputs) != (ny, nu):
                raise ValueError(f"{nm} is {g.noutputs}x{g.ninputs} but G_nominal is {ny}x{nu}")
    G_full = None if G_full is None else as_ss("G_full", G_full)
    G_twin = None if G_twin is None else as_ss("G_twin", G_twin)
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
    nominal = analyse_loop(G, K, f, S)
    full = analyse_loop(G_full, K, f, S_full) if G_full is not None else None
    twin = analyse_loop(G_twin, K, f, S_twin) if G_twin is not None else None
    # gamma check on the grid: sigma_max of the stacked weighted closed loop
    Gf, Kf = freqresp(G, f), freqresp(K, f)
    Sf, Tf, KSf = loop_freqresp(Gf, Kf)
    blocks = [getattr(W, nm).freqresp(f)[:, None, None] * X
              for nm, X in (("Wp", Sf), ("Wu", KSf), ("Wt", Tf)) if getattr(W, nm) is not None]
    gamma_grid = float(sigma_max(np.concatenate(blocks, axis=1)).max())
    return Design(K=K, gamma=float(gamma), gamma_opt=float(gamma_opt), gamma_grid=gamma_grid,
                  controller_order=int(K.nstates), weights=W,
                  G_nominal=G, G_full=G_full, G_twin=G_twin, P=P, S=S, T=T, KS=KS, freq_hz=f,
                  nominal=nominal, full=full, twin=twin, rcond=np.asarray(rcond, dtype=float))
