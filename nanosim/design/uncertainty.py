"""The stage's uncertainty set, perturbed plants and robust stability by mu.

Uncertainty set: piezo gain per input channel 0.75 ... 1.0 of nominal, every modal
frequency +-3 %, every modal damping x0.5 ... x2, and 0 ... 1 sample of computation delay
beyond the loop as run (whose own delays are in the plant).  :data:`STAGE_UNCERTAINTY`
holds it; :func:`robust_stability_mu` covers it by complex blocks and brute-forces its
vertices; :func:`perturbed_plant` builds one member.

The gains are factors on the nominal slope, the secant of the Fig. 14 major loop's rising branch
(:mod:`nanosim.plant.piezo` normalises it to 1), the average slope of a monotone move of that size. The low
end is about the gain the identification's PRBS sees in its small minor loops,
:data:`~nanosim.design.loopplant.IDENTIFIED_INPUT_GAIN_OF_NOMINAL`: the slope after a reversal, raised by the
thermally activated operators that follow within the PRBS's periods. The athermal tangent right after a
reversal, :meth:`~nanosim.plant.piezo.PiezoConfig.small_signal_gain` (``w0``), lies below the range. A plant
holding another slope maps the gains (:meth:`UncertaintySet.input_gain_range_about`): on an identified model
the set spans ``input_gain_range / IDENTIFIED_INPUT_GAIN_OF_NOMINAL`` x its gain.
Loop conventions: :mod:`~nanosim.design.loopresponse`.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import control as ct
import numpy as np

from nanosim.design.loopargs import (
    check_delay,
    check_int,
    check_range,
    check_scale,
    describe,
    is_lti,
    timebase,
)
from nanosim.design.loopresponse import (
    PreparedLoop,
    closed_loop_matrix,
    delay_factor,
    delay_ss,
    feedback_operator_ss,
    stability,
    to_state_space,
)
from nanosim.design.lti import sigma_max
from nanosim.design.margins import refine_mu_peak
from nanosim.design.mu import mu_upper_bound

__all__ = ["UncertaintySet", "STAGE_UNCERTAINTY", "STAGE_MU_RANGES", "MODE_ZETA_MAX", "MODE_MAX_HZ",
           "RobustStabilityResult", "ModalPlant", "perturbed_plant", "robust_stability_mu"]


@dataclass(frozen=True)
class UncertaintySet:
    """A parametric uncertainty set of the stage loop (factors on nominal).

    Attributes
    ----------
    input_gain_range : (float, float)
        Gain per input channel (piezo small-signal slope), factor on the nominal (major-loop secant)
        slope. A plant whose piezo sits elsewhere (an identified model holds
        :data:`~nanosim.design.loopplant.IDENTIFIED_INPUT_GAIN_OF_NOMINAL` x nominal) maps it by
        :meth:`input_gain_range_about`.
    freq_scale_range : (float, float)
        Factor on every modal natural frequency.
    damping_scale_range : (float, float)
        Factor on every modal damping ratio.
    extra_delay_samples_range : (int, int)
        Computation delay beyond the nominal loop's [samples] (:meth:`mu_kwargs`).
    """

    input_gain_range: tuple = (0.75, 1.0)
    freq_scale_range: tuple = (0.97, 1.03)
    damping_scale_range: tuple = (0.5, 2.0)
    extra_delay_samples_range: tuple = (0, 1)

    def __post_init__(self):
        check_range("input_gain_range", self.input_gain_range)
        check_range("freq_scale_range", self.freq_scale_range)
        check_range("damping_scale_range", self.damping_scale_range)
        check_range("extra_delay_samples_range", self.extra_delay_samples_range, positive=False, integer=True)

    def input_gain_range_about(self, input_gain_of_nominal: float = 1.0) -> tuple:
        """``input_gain_range`` as factors on a plant whose piezo gain is ``input_gain_of_nominal`` x nominal."""
        g = check_scale("input_gain_of_nominal", input_gain_of_nominal)
        return tuple(float(v) / g for v in self.input_gain_range)

    def mu_kwargs(self, nominal_delay_samples: int, input_gain_of_nominal: float = 1.0) -> dict:
        """Keyword arguments of :func:`robust_stability_mu` for a loop whose nominal delay
        is ``nominal_delay_samples`` and whose piezo gain is ``input_gain_of_nominal`` x nominal.
        """
        return {"input_gain_range": self.input_gain_range_about(input_gain_of_nominal),
                "freq_scale_range": tuple(self.freq_scale_range),
                "damping_scale_range": tuple(self.damping_scale_range),
                "delay_samples_range": tuple(check_delay(nominal_delay_samples) + int(v)
                                             for v in self.extra_delay_samples_range),
                "nominal_delay_samples": check_delay(nominal_delay_samples)}

    def to_dict(self) -> dict:
        """JSON-ready description (units in the keys)."""
        out = {k if k == "extra_delay_samples_range" else f"{k}_factor": list(v) for k, v in asdict(self).items()}
        out["meaning"] = ("piezo gain per input channel as a factor on nominal, the major-loop secant (the low "
                          "end about the slope the identification's PRBS sees, IDENTIFIED_INPUT_GAIN_OF_NOMINAL; the "
                          "tangent right after a reversal, PiezoConfig.small_signal_gain, lies below; each plant's "
                          "analysis maps it onto the slope that plant holds), "
                          "every structural mode's frequency and damping ratio scaled (pairs with zeta < 0.3 up to "
                          "1 kHz, real poles), computation delay beyond the loop as run")
        return out


STAGE_UNCERTAINTY = UncertaintySet()
# STAGE_UNCERTAINTY as the keyword arguments of robust_stability_mu (and of nanosim.design.parametric's
# parametric_lft and robust_stability_mixed_mu) for a loop without nominal delay on a plant at the nominal piezo
# slope: their defaults (an identified model maps the gains, UncertaintySet.mu_kwargs)
STAGE_MU_RANGES = STAGE_UNCERTAINTY.mu_kwargs(0)
# Complex poles damped more than this, or above this frequency, are not the stage's structural modes
# (the six below 1 kHz, from the first XY pair at about 175 Hz to the twist, the paper's 740 Hz; filters, creep
# fits): the uncertainty set leaves them alone.
MODE_ZETA_MAX = 0.3
MODE_MAX_HZ = 1000.0


def perturbed_plant(G, freq_scale: float = 1.0, damping_scale: float = 1.0, input_gain=1.0,
                    delay_samples: int = 0, *, dt=None, keep_dc_gain: bool = True,
                    pade_order: int = 3) -> ct.StateSpace:
    """Plant with scaled modal frequencies and damping, input gains and a delay.

    ``G`` is diagonalised, ``A = V diag(lambda) V^-1``.  Each pole, in continuous-time
    terms ``lambda = -zeta w_n +- j w_n sqrt(1 - zeta^2)`` (discrete poles are mapped
    with ``s = log(z) / dt`` and back with ``z = exp(s dt)``), becomes
    ``w_n' = freq_scale w_n``, ``zeta' = damping_scale zeta`` for complex poles with
    ``zeta < MODE_ZETA_MAX`` and ``f_n <= MODE_MAX_HZ`` (a pair turns real if ``zeta' >= 1``;
    other pairs stay),
    and ``freq_scale lambda`` for real poles;
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
    fs = check_scale("freq_scale", freq_scale)
    zs = check_scale("damping_scale", damping_scale)
    d = check_delay(delay_samples)
    return ModalPlant(G, dt).state_space(fs, zs, input_gain, d, keep_dc_gain=keep_dc_gain, pade_order=pade_order)


class ModalPlant:
    """Modal form ``G = C V (p I - Lambda)^-1 V^-1 B + D`` of a diagonalisable plant, for
    the perturbations of :func:`perturbed_plant` (one eigendecomposition for many members).

    Parameters
    ----------
    G : control.StateSpace or TransferFunction
    dt : float or None
        Control period [s] for delays of a continuous plant.
    """

    def __init__(self, G, dt=None):
        if not is_lti(G):
            raise TypeError(f"G: expected a control.StateSpace or TransferFunction, got {describe(G)}")
        self.kind, self.T = timebase({"G": G}, dt)
        self.discrete = self.kind == "discrete"
        self.dt_sys = self.T if self.discrete else 0
        Gs = ct.ss(G)
        self.A, self.B, self.C, self.D = (np.asarray(m, dtype=float) for m in (Gs.A, Gs.B, Gs.C, Gs.D))
        self.nu = self.B.shape[1]
        n = self.A.shape[0]
        self.lam = np.zeros(0, complex)
        if n:
            lam, V = np.linalg.eig(self.A)
            if np.linalg.cond(V) > 1e10:
                raise ValueError("G: the state matrix is not (numerically) diagonalisable; "
                                 "expected a plant with distinct modes")
            self.lam, self.V = lam, V
            self.VinvB = np.linalg.solve(V, self.B.astype(complex))
            self.CV = self.C @ V
            if self.discrete:
                with np.errstate(divide="ignore"):
                    self.s = np.log(lam.astype(complex)) / self.T
            else:
                self.s = lam.astype(complex)

    def mode_kind(self) -> np.ndarray:
        """Per eigenvalue: 1 for a structural pair member (complex, ``zeta < MODE_ZETA_MAX``,
        ``f_n <= MODE_MAX_HZ``), 2 for a real pole that the frequency scale moves, 0 for a
        pole the uncertainty set leaves alone (``s = 0``, a discrete pole on the negative
        real axis, a filter pair).
        """
        kind = np.zeros(self.lam.size, int)
        for k, sk in enumerate(self.s):
            if not np.isfinite(sk) or sk == 0:
                continue
            if self.discrete and self.lam[k].real < 0 and abs(self.lam[k].imag) <= 1e-12 * abs(self.lam[k]):
                continue
            if abs(sk.imag) > 1e-12 * abs(sk):
                if -sk.real / abs(sk) < MODE_ZETA_MAX and abs(sk) <= 2 * math.pi * MODE_MAX_HZ:
                    kind[k] = 1
            else:
                kind[k] = 2
        return kind

    def poles(self, fs: float, zs: float, keep_dc_gain: bool = True):
        """Perturbed poles (``z`` or ``s``) and the residue factors that keep each mode's DC gain.

        Modes are the complex pairs with damping below :data:`MODE_ZETA_MAX` and natural
        frequency up to :data:`MODE_MAX_HZ` (the structure's resonances), and the real poles;
        other pairs (signal-chain filters: the gauge's 5 kHz Butterworth discretized at 4 kHz
        shows as zeta 0.12 at 1.8 kHz) and discrete poles on the negative real axis (no
        conjugate partner) stay where they are.
        """
        s_new = self.s.copy()
        kind = self.mode_kind()
        for k, sk in enumerate(self.s):
            if kind[k] == 0:
                continue
            wn = abs(sk)
            if kind[k] == 1:
                zeta = -sk.real / wn
                zn, wn2 = zeta * zs, wn * fs
                if zn < 1:
                    s_new[k] = wn2 * (-zn + 1j * math.copysign(math.sqrt(1 - zn * zn), sk.imag))
                else:
                    r = math.sqrt(zn * zn - 1)
                    s_new[k] = wn2 * (-zn + (r if sk.imag > 0 else -r))
            else:
                s_new[k] = sk * fs
        lam_new = np.exp(s_new * self.T) if self.discrete else s_new
        lam_new = np.where(np.isfinite(self.s), lam_new, self.lam)
        fac = np.ones(lam_new.size, complex)
        if keep_dc_gain:
            p0 = 1.0 if self.discrete else 0.0
            with np.errstate(divide="ignore", invalid="ignore"):
                fac = (p0 - lam_new) / (p0 - self.lam)
            fac = np.where(np.isfinite(fac) & (np.abs(p0 - self.lam) > 1e-12), fac, 1.0)
        return lam_new, fac

    def _gains(self, input_gain) -> np.ndarray:
        g = np.asarray(input_gain, dtype=float)
        if g.ndim == 0:
            g = np.full(self.nu, float(g))
        if g.shape != (self.nu,) or not np.all(np.isfinite(g)):
            raise ValueError(f"input_gain: expected a scalar or {self.nu} finite factors (one per input), "
                             f"got {np.shape(input_gain)}")
        return g

    def state_space(self, fs: float, zs: float, input_gain=1.0, delay_samples: int = 0, *,
                    keep_dc_gain: bool = True, pade_order: int = 3) -> ct.StateSpace:
        """The member of :func:`perturbed_plant` (states ``[delay; modal]``)."""
        g = self._gains(input_gain)
        d = check_delay(delay_samples)
        if d and self.T is None:
            raise ValueError(f"dt: delay_samples={d} on a continuous plant needs the sample period dt [s]")
        A, B = self.A, self.B
        if self.lam.size:
            lam_new, fac = self.poles(fs, zs, keep_dc_gain)
            An = self.V @ np.diag(lam_new) @ np.linalg.inv(self.V)
            Bn = self.V @ (fac[:, None] * self.VinvB)
            scale = max(1.0, np.abs(A).max(), np.abs(B).max())
            if np.abs(An.imag).max() > 1e-6 * scale * max(1.0, np.abs(An.real).max()) or \
                    np.abs(Bn.imag).max() > 1e-6 * max(1.0, np.abs(Bn.real).max()):
                raise ValueError("G: modal perturbation produced a complex realization (unpaired "
                                 "complex poles?)")
            A, B = An.real, Bn.real
        P = ct.ss(A, B * g[None, :], self.C, self.D * g[None, :], self.dt_sys)
        Dl = delay_ss(self.nu, d, self.kind if self.kind else "continuous", self.T, pade_order, self.dt_sys)
        if Dl is not None:
            P = ct.series(Dl, P)
            P = ct.ss(P.A, P.B, P.C, P.D, self.dt_sys)
        return P

    def response(self, f: np.ndarray, fs: float = 1.0, zs: float = 1.0, *, keep_dc_gain: bool = True) -> np.ndarray:
        """Frequency response (F, ny, nu) of the member with unit gains and no delay, on ``f`` [Hz]."""
        p = np.exp(2j * np.pi * f * self.T) if self.discrete else 2j * np.pi * f
        if not self.lam.size:
            return np.broadcast_to(self.D.astype(complex), (f.size,) + self.D.shape).copy()
        lam_new, fac = self.poles(fs, zs, keep_dc_gain)
        with np.errstate(divide="ignore", invalid="ignore"):
            R = fac[None, :] / (p[:, None] - lam_new[None, :])                  # (F, n)
        return np.einsum("in,fn,nj->fij", self.CV, R, self.VinvB) + self.D[None]


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


def robust_stability_mu(G_nominal, K, Ky, dt, freq_hz, *,
                        input_gain_range=STAGE_MU_RANGES["input_gain_range"],
                        freq_scale_range=STAGE_MU_RANGES["freq_scale_range"],
                        damping_scale_range=STAGE_MU_RANGES["damping_scale_range"],
                        delay_samples_range=STAGE_MU_RANGES["delay_samples_range"], nominal_delay_samples: int = 0,
                        n_levels: int = 3, n_random: int = 24, seed: int = 0,
                        keep_dc_gain: bool = True, refine: bool = True,
                        pade_order: int = 3) -> RobustStabilityResult:
    """Robust stability of ``u = K e + Ky y`` for the stage's parametric uncertainty.

    Uncertainty set: piezo gain per input channel in
    ``input_gain_range`` (factors on the nominal, major-loop secant slope; see the module docstring), every
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
    if not is_lti(G_nominal):
        raise TypeError(f"G_nominal: expected a control.StateSpace or TransferFunction, got "
                        f"{describe(G_nominal)}")
    if G_nominal.noutputs != G_nominal.ninputs:
        raise ValueError(f"G_nominal: the output-multiplicative covering needs a square plant, got "
                         f"{G_nominal.noutputs} outputs x {G_nominal.ninputs} inputs")
    loop = PreparedLoop(G_nominal, K, Ky, nominal_delay_samples, dt, allow_stack=False)
    f = loop.check_freq(freq_hz, increasing=True)
    glo, ghi = check_range("input_gain_range", input_gain_range)
    flo, fhi = check_range("freq_scale_range", freq_scale_range)
    zlo, zhi = check_range("damping_scale_range", damping_scale_range)
    dlo, dhi = check_range("delay_samples_range", delay_samples_range, positive=False, integer=True)
    check_int("n_levels", n_levels, 2)
    check_int("n_random", n_random, 0)
    if (dhi > 0 or loop.d > 0) and loop.T is None:
        raise ValueError("dt: delays need the sample period dt [s] (G_nominal is continuous)")
    n = loop.nu
    T = loop.T
    discrete = loop.kind == "discrete"
    c = (glo + ghi) / 2.0
    rad = (ghi - glo) / (ghi + glo)
    center = np.full(n, c)
    radius = np.full(n, rad)

    mp = ModalPlant(G_nominal, T)

    def pp(fs, zs, gains, dd):
        return mp.state_space(fs, zs, gains, dd, keep_dc_gain=keep_dc_gain, pade_order=pade_order)

    # ---- weight samples (modes + delay; gains cancel in E_O)
    rng = np.random.default_rng(seed)
    fl = np.linspace(flo, fhi, n_levels)
    zl = np.geomspace(zlo, zhi, n_levels)
    delays = list(range(dlo, dhi + 1))
    samples = [(a, b, dd) for a in fl for b in zl for dd in delays]
    rand = [(float(rng.uniform(flo, fhi)), float(math.exp(rng.uniform(math.log(zlo), math.log(zhi)))),
             int(rng.integers(dlo, dhi + 1)), rng.uniform(glo, ghi, n)) for _ in range(n_random)]
    samples += [(a, b, dd) for a, b, dd, _ in rand]
    G0 = pp(1.0, 1.0, 1.0, 0)

    def weight(fr: np.ndarray) -> np.ndarray:
        G0f = mp.response(fr, keep_dc_gain=keep_dc_gain) * delay_factor(fr, loop.d, T)[:, None, None]
        G0T = np.swapaxes(G0f, 1, 2)
        w = np.zeros(fr.size)
        for a, b, dd in samples:      # modes and delay (exact factors); the gains cancel in E_O
            Pf = mp.response(fr, a, b, keep_dc_gain=keep_dc_gain) * delay_factor(fr, dd, T)[:, None, None]
            E = np.swapaxes(np.linalg.solve(G0T, np.swapaxes(Pf - G0f, 1, 2)), 1, 2)   # (Pf - G0f) G0f^-1
            w = np.maximum(w, sigma_max(E))
        return w

    # ---- nominal (centre) loop and M
    Gc = ct.ss(G0.A, G0.B * c, G0.C, G0.D * c, G0.dt)
    center_loop = PreparedLoop(Gc, K, Ky, loop.d, T, allow_stack=False)
    st_nom = center_loop.stability(pade_order)
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
    mb = mu_upper_bound(Mf, blocks, lower=True, peak_only=True)
    if refine:
        top = float(np.max(mb.upper))
        pk, fpk = refine_mu_peak(lambda fr: mu_upper_bound(build(fr)[0], blocks, lower=False, peak_only=True,
                                                           floor=top).upper, f, mb.upper)
    else:
        i = int(np.argmax(mb.upper))
        pk, fpk = float(mb.upper[i]), float(f[i])

    # ---- brute force on vertices and random samples
    dt_sys = T if discrete else 0
    Kys = None if Ky is None else to_state_space(Ky, dt_sys, "Ky")
    Kfb_ss = feedback_operator_ss(to_state_space(K, dt_sys, "K"), Kys, dt_sys)
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
        ok, meas = stability(closed_loop_matrix(P, Kfb_ss), discrete)
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


