"""Robustness of a controller on the stage loop as it is run: the public loop-analysis API.

Facade of :mod:`~nanosim.design.loopresponse` (loop transfer matrices ``S_o, S_i, T_o,
T_i, KS, SG`` at plant input and output, with the inner loop, in frequency and state
space), :mod:`~nanosim.design.margins` (disk margins, pole damping),
:mod:`~nanosim.design.mu` (mu bounds) and :mod:`~nanosim.design.uncertainty` (the
stage's uncertainty set, :func:`robust_stability_mu`); conventions in
:mod:`~nanosim.design.loopresponse`.  On top of them:

* :func:`robustness_summary` -- JSON figures of one loop;
* :class:`~nanosim.design.loopplant.LoopPlant` (:mod:`~nanosim.design.loopplant`, re-exported here) -- a
  sampled plant as the loop runs it (plant and delay);
* :func:`analyze_controller` -- any discrete controller (inputs ``[e; y]`` with
  ``n_error``, or ``e`` only) on a ``LoopPlant``: :class:`ControllerRobustness`.

The loop as run (:func:`nanosim.experiments.loop.run_closed_loop`) computes ``u_k``
from the reading ``y_k`` that ``Stage.step(u_{k-1})`` returned, and ``Stage.step(u_k)``
returns ``y_{k+1}``.  A model identified from the rows of a record (``u_k`` and the
reading after ``step(u_k)``, :mod:`nanosim.experiments.sysid`) therefore has a direct
feedthrough, and the loop as run is that model times ``z^-1``:
:data:`~nanosim.design.loopplant.RECORD_ROW_DELAY_SAMPLES` = 1 (pinned by ``tests/test_loop_analysis.py``).  The
linear twin ``twin.npz`` is the standard zero-order-hold model ``y_k = C x_k + D u_k``;
:meth:`~nanosim.design.loopplant.LoopPlant.twin` moves it to the same convention, ``(A, B, C A, C B + D)``.
"""
from __future__ import annotations

import collections
import contextlib
import contextvars
import dataclasses
import hashlib
import json
import math
import threading
from dataclasses import dataclass, field

import control as ct
import numpy as np

from nanosim.design.loopargs import json_num
from nanosim.design.loopplant import (
    IDENTIFIED_DELAY_SAMPLES,
    IDENTIFIED_INPUT_GAIN_OF_NOMINAL,
    RECORD_ROW_DELAY_SAMPLES,
    LoopPlant,
    controller_systems,
    electronics_ss,
)
from nanosim.design.loopresponse import (
    LoopResponse,
    LoopStateSpace,
    PreparedLoop,
    closed_loop_poles,
    frequency_response,
    loop_transfer_response,
    loop_transfer_ss,
)
from nanosim.design.loops import MODE_BAND_HZ
from nanosim.design.lti import analysis_grid_hz, refine_peak, sigma_max, single_threaded_blas
from nanosim.design.margins import (
    DiskMargin,
    DiskMarginReport,
    LeastDampedPole,
    disk_gain_phase,
    disk_margins,
    least_damped_pole,
)
from nanosim.design.mu import MuBounds, mu_lower_bound, mu_upper_bound
from nanosim.design.parametric import MixedRobustStabilityResult, robust_stability_mixed_mu
from nanosim.design.uncertainty import (
    STAGE_UNCERTAINTY,
    RobustStabilityResult,
    UncertaintySet,
    perturbed_plant,
    robust_stability_mu,
)

__all__ = [
    "RECORD_ROW_DELAY_SAMPLES", "ROBUSTNESS_MAPS", "DISK_MARGIN_TARGET", "STAGE_UNCERTAINTY", "UncertaintySet",
    "DiskMargin", "DiskMarginReport", "LeastDampedPole", "LoopResponse", "LoopStateSpace", "MuBounds",
    "RobustStabilityResult", "LoopPlant", "ControllerRobustness",
    "closed_loop_poles", "disk_gain_phase", "disk_margins", "frequency_response", "least_damped_pole",
    "loop_transfer_response", "loop_transfer_ss", "mu_lower_bound", "mu_upper_bound", "perturbed_plant",
    "robust_stability_mu", "robustness_summary", "sigma_max", "controller_systems", "analyze_controller",
    "stage_grid_hz", "pole_visibility", "VISIBLE_PEAK", "IDENTIFIED_DELAY_SAMPLES", "electronics_ss",
    "IDENTIFIED_INPUT_GAIN_OF_NOMINAL", "analysis_memo",
]

# The six loop transfer matrices of robustness.json and its figure (LoopResponse names).
ROBUSTNESS_MAPS = ("S_o", "S_i", "T_o", "T_i", "KS", "SG")
# the bench specification's acceptance: a multiloop disk margin of at least 0.4 (the scorecard's target, the
# robust bench design's constraint, the dashed line of the disk-margin figure)
DISK_MARGIN_TARGET = 0.4
# A closed-loop pole is "visible" if its modal term adds at least this much to the peak of
# [T_ry, S_o] (reference and output disturbance -> y) at its resonance.  An identified model
# assembled column by column holds a copy of each mode per column; the copies' difference is
# (nearly) unobservable and keeps its open-loop damping in any loop (peak ~0.01).
VISIBLE_PEAK = 0.05
_SUMMARY_MAPS = (("So", "S_o"), ("To", "T_o"), ("Si", "S_i"), ("Ti", "T_i"), ("KS", "KS"), ("KS_fb", "KS_fb"),
                 ("SG", "SG"), ("T_ry", "T_ry"))


# =====================================================================================
# JSON summary of one loop
# =====================================================================================
def _dm_dict(prefix: str, m: DiskMargin) -> dict:
    return {f"{prefix}_alpha": json_num(m.alpha),
            f"{prefix}_alpha_upper_bound": json_num(m.alpha_upper_bound),
            f"{prefix}_gain_margin_low": json_num(m.gain_margin[0]),
            f"{prefix}_gain_margin_high": json_num(m.gain_margin[1]),
            f"{prefix}_gain_margin_low_db": json_num(m.gain_margin_db[0]),
            f"{prefix}_gain_margin_high_db": json_num(m.gain_margin_db[1]),
            f"{prefix}_phase_margin_deg": json_num(m.phase_margin_deg),
            f"{prefix}_freq_hz": json_num(m.freq_hz)}


def _poles_dict(poles: np.ndarray, T, f_band_hz) -> dict:
    discrete = T is not None
    out: dict = {}
    if not poles.size:
        stable, meas = True, (0.0 if discrete else -math.inf)
    elif discrete:
        meas = float(np.max(np.abs(poles)))
        stable = meas < 1.0
    else:
        meas = float(np.max(poles.real))
        stable = meas < 0.0
    out["closed_loop_stable"] = stable
    out["spectral_radius" if discrete else "max_pole_real_per_s"] = json_num(meas)
    if poles.size:
        try:
            ld = least_damped_pole(poles, T, f_band_hz=f_band_hz)
            out["least_damped_zeta"], out["least_damped_freq_hz"] = json_num(ld.zeta), json_num(ld.freq_hz)
        except ValueError:
            out["least_damped_zeta"] = out["least_damped_freq_hz"] = None
    return out


def _peaks_dict(loop: PreparedLoop, f: np.ndarray, r: LoopResponse) -> dict:
    out = {}
    for key, attr in _SUMMARY_MAPS:
        pk, fpk = refine_peak(lambda fr, a=attr: sigma_max(getattr(loop.response(fr), a)), f, r.sigma_max(attr),
                              n_peaks=3, n_fine=21, rounds=4)
        out[f"peak_{key}"], out[f"peak_{key}_freq_hz"] = json_num(pk), json_num(fpk)
    return out


def _margins_dict(rep: DiskMarginReport) -> dict:
    w = rep.worst()
    out = {"disk_margin_skew": rep.skew, "disk_margin_alpha": json_num(w.alpha),
           "gain_margin_db": [json_num(w.gain_margin_db[0]), json_num(w.gain_margin_db[1])],
           "phase_margin_deg": json_num(w.phase_margin_deg), "disk_margin_freq_hz": json_num(w.freq_hz),
           "disk_margin_location": w.location}
    out.update(_dm_dict("dm_input", rep.input))
    out.update(_dm_dict("dm_output", rep.output))
    out.update(_dm_dict("dm_input_output", rep.input_output))
    for name, lat in (("dm_input_loop_at_a_time", rep.input_loop_at_a_time),
                      ("dm_output_loop_at_a_time", rep.output_loop_at_a_time)):
        out[f"{name}_alpha"] = [json_num(m.alpha) for m in lat]
        out[f"{name}_gain_margin_db"] = [[json_num(m.gain_margin_db[0]), json_num(m.gain_margin_db[1])] for m in lat]
        out[f"{name}_phase_margin_deg"] = [json_num(m.phase_margin_deg) for m in lat]
        out[f"{name}_freq_hz"] = [json_num(m.freq_hz) for m in lat]
    return out


def _mu_dict(res: RobustStabilityResult) -> dict:
    return {"mu_peak": json_num(res.mu_peak), "mu_peak_freq_hz": json_num(res.mu_peak_freq_hz),
            "mu_lower_peak": json_num(res.mu_lower_peak), "mu_robustly_stable": res.robustly_stable,
            "mu_nominal_stable": res.nominal_stable, "sampled_all_stable": res.sampled_all_stable,
            "sampled_worst": json_num(res.sampled_worst),
            "sampled_worst_parameters": res.sampled_worst_parameters, "n_parameter_samples": res.n_samples}


def _mixed_dict(res: MixedRobustStabilityResult, covering: dict) -> dict:
    """``mu_*`` keys: the mixed (real-parametric) bound; the complex covering as ``mu_covering_*``."""
    out = {"mu_peak": json_num(res.mu_peak), "mu_peak_freq_hz": json_num(res.mu_peak_freq_hz),
           "mu_robustly_stable": res.robustly_stable, "mu_centre_stable": res.centre_stable,
           "mu_method": "mixed real/complex mu upper bound (D-G scalings) of the parametric LFT: each mode's "
                        "frequency and damping and each piezo gain a real parameter; each delay of the set on its own; "
                        "null when a centre loop is unstable (mu_centre_stable)",
           "mu_n_parameters": res.n_parameters, "mu_n_real_parameters": res.n_real,
           "mu_merge_error_rel": None if res.merge_error_rel is None else json_num(res.merge_error_rel)}
    out.update({"mu_covering_peak": covering["mu_peak"], "mu_covering_peak_freq_hz": covering["mu_peak_freq_hz"],
                "mu_covering_lower_peak": covering["mu_lower_peak"],
                "mu_covering_robustly_stable": covering["mu_robustly_stable"]})
    out.update({k: covering[k] for k in ("sampled_all_stable", "sampled_worst", "sampled_worst_parameters",
                                         "n_parameter_samples")})
    return out


def robustness_summary(G, K, freq_hz, Ky=None, *, delay_samples: int = 0, dt=None, skew: float = 0.0,
                       f_band_hz=None, robust: dict | None = None) -> dict:
    """JSON-serialisable robustness figures of one loop (units in the key names).

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
        Keys:
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
        ``sampled_all_stable``, ``sampled_worst``, ``sampled_worst_parameters``,
        ``n_parameter_samples``.  Unbounded values (``gmax = inf``) are ``None``.
    """
    loop = PreparedLoop(G, K, Ky, delay_samples, dt, allow_stack=False)
    f = loop.check_freq(freq_hz, increasing=True)
    if robust is not None and not isinstance(robust, dict):
        raise TypeError(f"robust: expected a dict of robust_stability_mu keyword arguments or None, "
                        f"got {type(robust).__name__}")
    out = _poles_dict(closed_loop_poles(G, K, Ky, loop.d, loop.T), loop.T if loop.kind == "discrete" else None,
                      f_band_hz)
    out.update(_peaks_dict(loop, f, loop.response(f)))
    out.update(_margins_dict(disk_margins(G, K, f, Ky, delay_samples=loop.d, dt=loop.T, skew=skew)))
    if robust is not None:
        out.update(_mu_dict(robust_stability_mu(G, K, Ky, loop.T, f, nominal_delay_samples=loop.d, **robust)))
    return out


def pole_visibility(G, K, Ky=None, delay_samples: int = 0, dt=None) -> tuple[np.ndarray, np.ndarray]:
    """Closed-loop poles and the peak each adds to ``[T_ry, S_o]`` (r, d_o -> y) at its resonance.

    Parameters
    ----------
    G, K, Ky, delay_samples, dt
        As in :func:`loop_transfer_ss`.

    Returns
    -------
    poles : ndarray, complex
        Closed-loop poles (``z`` or ``s`` [rad/s]).
    peak : ndarray
        ``sigma_max(R_k) / (1 - |z_k|)`` (discrete) or ``sigma_max(R_k) / |Re s_k|``
        (continuous), ``R_k`` the residue of the pole in ``[T_ry, S_o]`` [sensor V / sensor V].
    """
    L = loop_transfer_ss(G, K, Ky, delay_samples, dt)
    CL = L.closed_loop
    ny = L.S_o.noutputs
    nu = CL.ninputs - 2 * ny
    A = np.asarray(CL.A, float)
    if not A.size:
        return np.zeros(0, complex), np.zeros(0)
    lam, V = np.linalg.eig(A)
    Wl = np.linalg.solve(V, np.asarray(CL.B, float)[:, list(range(ny)) + list(range(ny + nu, 2 * ny + nu))])
    Cy = np.asarray(CL.C, float)[:ny] @ V
    discrete = ct.isdtime(CL, strict=True)
    peak = np.empty(lam.size)
    for k in range(lam.size):
        r = np.linalg.norm(np.outer(Cy[:, k], Wl[k]), 2)
        dist = (1.0 - abs(lam[k])) if discrete else abs(lam[k].real)
        peak[k] = r / max(dist, 1e-15)
    return lam, peak


def _poles_as_ss(poles_s: np.ndarray) -> ct.StateSpace:
    """A continuous system with the poles ``poles_s`` [rad/s] (for grid densification)."""
    blocks = [np.array([[p.real, p.imag], [-p.imag, p.real]]) if p.imag > 0 else np.array([[p.real]])
              for p in poles_s if p.imag >= 0 and np.isfinite(p)]
    n = sum(len(b) for b in blocks)
    A = np.zeros((n, n))
    k = 0
    for b in blocks:
        A[k:k + len(b), k:k + len(b)] = b
        k += len(b)
    return ct.ss(A, np.zeros((n, 1)), np.zeros((1, n)), 0.0)


def stage_grid_hz(plant: LoopPlant, K, Ky=None, f_min_hz: float = 0.1, n: int = 600) -> np.ndarray:
    """Log grid up to the Nyquist frequency, densified near the lightly damped open- and
    closed-loop poles (:func:`nanosim.design.lti.analysis_grid_hz`) [Hz].
    """
    T = plant.dt
    pl = [np.linalg.eigvals(np.asarray(plant.G.A, float))]
    try:
        pl.append(closed_loop_poles(plant.G, K, Ky, plant.delay_samples))
    except ValueError:
        pass
    with np.errstate(divide="ignore", invalid="ignore"):
        s = [np.log(p[np.abs(p) > 0].astype(complex)) / T for p in pl]
    return analysis_grid_hz([_poles_as_ss(x) for x in s], f_min_hz, 0.5 / T, n)


# base grid of the mixed-mu analysis; a dense grid over every mode's band is added to it (24 points
# over +-3 % of frequency: 0.25 % steps, a third of the modes' half-power width), and the peak is
# the grid's (refining it between grid points costs 4x and moved it by 5 % on the seed-0 LQG)
MIXED_BASE_POINTS = 60


@dataclass(frozen=True, eq=False)
class ControllerRobustness:
    """Robustness of one controller on one :class:`LoopPlant` (from :func:`analyze_controller`).

    Attributes
    ----------
    label : str
        The plant's label.
    delay_samples : int
    response : LoopResponse
        Loop transfer matrices on ``response.freq_hz``.
    margins : DiskMarginReport
    robust : RobustStabilityResult or None
        The complex covering and the sampled check (:func:`robust_stability_mu`).
    poles : ndarray, complex
        Closed-loop poles (``z``).
    summary : dict
        :func:`robustness_summary`-style figures plus ``least_damped_in_band_*`` (poles inside
        ``least_damped_band_hz``, :data:`~nanosim.design.loops.MODE_BAND_HZ`) and
        ``least_damped_visible_*`` (poles with :func:`pole_visibility` >= :data:`VISIBLE_PEAK`).
    uncertainty : UncertaintySet or None
    mixed : MixedRobustStabilityResult or None
        Robust stability over the parametric set by the mixed mu bound (``summary["mu_peak"]``).
    """

    label: str
    delay_samples: int
    response: LoopResponse
    margins: DiskMarginReport
    robust: RobustStabilityResult | None
    poles: np.ndarray
    summary: dict = field(default_factory=dict)
    uncertainty: UncertaintySet | None = None
    mixed: MixedRobustStabilityResult | None = None
    input_gain_of_nominal: float = 1.0

    def to_dict(self) -> dict:
        """JSON-ready: the summary, the loop's delay and the uncertainty set (with its gain range on this plant)."""
        out = {"plant": self.label, "loop_delay_samples": self.delay_samples}
        out.update(self.summary)
        if self.uncertainty is not None:
            out["uncertainty_set"] = self.uncertainty.to_dict()
            out["uncertainty_set"]["plant_input_gain_of_nominal"] = self.input_gain_of_nominal
            out["uncertainty_set"]["input_gain_range_on_plant_factor"] = list(
                self.uncertainty.input_gain_range_about(self.input_gain_of_nominal))
        return out


@single_threaded_blas
def analyze_controller(controller, plant, *, n_error: int | None = None, uncertainty=STAGE_UNCERTAINTY,
                       freq_hz=None, mu: bool = True, n_levels: int = 3, n_random: int = 24,
                       seed: int = 0) -> ControllerRobustness:
    """Loop transfer matrices, disk margins, pole damping and mu of a discrete controller
    on the loop as it is run.

    Parameters
    ----------
    controller : path, ControllerConfig, DiscreteController or discrete StateSpace
        ``u = K e + Ky y`` with inputs ``[e; y]`` (``n_error`` error inputs) or ``e``
        only (:func:`controller_systems`).
    plant : LoopPlant or discrete control.StateSpace
        A StateSpace is taken as an identified model (:meth:`LoopPlant.identified`).
    n_error : int or None
        For a StateSpace controller, see :func:`controller_systems`.
    uncertainty : UncertaintySet
        Set for :func:`robust_stability_mu` (its delays are added to the loop's).
    freq_hz : array_like or None
        Analysis grid [Hz] (default :func:`stage_grid_hz`).
    mu : bool
        Compute the mu analysis (the slow part).
    n_levels, n_random, seed
        Sampling of the uncertainty set (:func:`robust_stability_mu`).

    Returns
    -------
    ControllerRobustness
    """
    if isinstance(plant, ct.StateSpace):
        plant = LoopPlant.identified(plant)
    if not isinstance(plant, LoopPlant):
        raise TypeError(f"plant: expected a LoopPlant or a discrete control.StateSpace, got {type(plant).__name__}")
    if not isinstance(uncertainty, UncertaintySet):
        raise TypeError(f"uncertainty: expected an UncertaintySet, got {type(uncertainty).__name__}")
    K, Ky = controller_systems(controller, n_error)
    if not math.isclose(float(K.dt), plant.dt, rel_tol=1e-9):
        raise ValueError(f"controller: sample time {K.dt} s differs from the plant's {plant.dt} s")
    G, d = plant.G, plant.delay_samples
    loop = PreparedLoop(G, K, Ky, d, None, allow_stack=False)
    f = loop.check_freq(stage_grid_hz(plant, K, Ky) if freq_hz is None else freq_hz, increasing=True)
    key = _analysis_key(G, K, Ky, d, f, plant.label, uncertainty, mu, n_levels, n_random, seed,
                        plant.input_gain_of_nominal)
    memo = _MEMO.get()
    with _ANALYSES_LOCK:
        hit = None if memo is None else memo.get(key)
    if hit is not None:
        return dataclasses.replace(hit, summary=dict(hit.summary))
    poles = closed_loop_poles(G, K, Ky, d)
    summary = _poles_dict(poles, plant.dt, None)
    band = _poles_dict(poles, plant.dt, MODE_BAND_HZ)
    summary["least_damped_band_hz"] = [float(f) for f in MODE_BAND_HZ]
    summary["least_damped_in_band_zeta"] = band.get("least_damped_zeta")
    summary["least_damped_in_band_freq_hz"] = band.get("least_damped_freq_hz")
    lam, peak = pole_visibility(G, K, Ky, d)
    vis = _poles_dict(lam[peak >= VISIBLE_PEAK], plant.dt, None)
    summary["least_damped_visible_zeta"] = vis.get("least_damped_zeta")
    summary["least_damped_visible_freq_hz"] = vis.get("least_damped_freq_hz")
    r = loop.response(f)
    summary.update(_peaks_dict(loop, f, r))
    rep = disk_margins(G, K, f, Ky, delay_samples=d)
    summary.update(_margins_dict(rep))
    res = mixed = None
    if mu:
        kw = uncertainty.mu_kwargs(d, plant.input_gain_of_nominal)
        res = robust_stability_mu(G, K, Ky, None, f, n_levels=n_levels, n_random=n_random, seed=seed, **kw)
        mixed = robust_stability_mixed_mu(G, K, Ky, np.geomspace(f[0], f[-1], MIXED_BASE_POINTS),
                                          input_gain_range=kw["input_gain_range"],
                                          freq_scale_range=kw["freq_scale_range"],
                                          damping_scale_range=kw["damping_scale_range"],
                                          delay_samples_range=kw["delay_samples_range"], refine=False)
        summary.update(_mixed_dict(mixed, _mu_dict(res)))
    out = ControllerRobustness(label=plant.label, delay_samples=d, response=r, margins=rep, robust=res,
                               poles=poles, summary=summary, uncertainty=uncertainty if mu else None, mixed=mixed,
                               input_gain_of_nominal=plant.input_gain_of_nominal)
    if memo is not None:
        with _ANALYSES_LOCK:
            memo[key] = dataclasses.replace(out, summary=dict(summary))
            while len(memo) > _ANALYSES_KEPT:
                memo.popitem(last=False)
    return out


# the analyses of the current command (analysis_memo), by the digest of everything they depend on: the robust LQG
# rule's mixed-mu check of its chosen member and robustness.json's analysis of the exported controller are the same
# computation (~12 s), done once within a command
_ANALYSES_KEPT = 4
_MEMO: contextvars.ContextVar = contextvars.ContextVar("nanosim_analysis_memo", default=None)
_ANALYSES_LOCK = threading.Lock()


@contextlib.contextmanager
def analysis_memo():
    """A scope (one command) in which :func:`analyze_controller` serves a repeated analysis from memory.

    Inside the ``with`` block an analysis whose inputs (plant, controller, grid, uncertainty set, sampling) hash to
    one already made returns a copy of it (the last :data:`_ANALYSES_KEPT`); outside any block every call
    computes. Nested blocks share the outer memory. ``nanosim``'s commands and
    :func:`nanosim.pipeline.design.run_design` run inside one.
    """
    if _MEMO.get() is not None:
        yield
        return
    token = _MEMO.set(collections.OrderedDict())
    try:
        yield
    finally:
        _MEMO.reset(token)


def _analysis_key(G, K, Ky, delay, f, label, uncertainty, mu, n_levels, n_random, seed, gain_of_nominal) -> str:
    h = hashlib.sha256()
    for sys_ in (G, K, Ky):
        if sys_ is None:
            h.update(b"none")
            continue
        for m in (sys_.A, sys_.B, sys_.C, sys_.D):
            a = np.ascontiguousarray(np.asarray(m, float))
            h.update(repr(a.shape).encode())
            h.update(a.tobytes())
        h.update(repr(float(sys_.dt)).encode())
    h.update(np.ascontiguousarray(np.asarray(f, float)).tobytes())
    h.update(json.dumps([int(delay), str(label), uncertainty.to_dict(), bool(mu), int(n_levels), int(n_random),
                         int(seed), float(gain_of_nominal)], sort_keys=True, default=str).encode())
    return h.hexdigest()
