"""(g) lqg: H2-optimal (LQG) output feedback with integral action, from the stage's known noise levels.

:func:`design_lqg` designs the members of a tuning rule (:class:`~nanosim.design.architectures.lqg_rules.LqgRule`,
a value) with :func:`~nanosim.design.architectures.lqg_synthesis.lqg_controller` -- a steady-state Kalman
filter from the stage's DAC and gauge noise levels with an input-disturbance observer, and LQR on the
reading and its leaky integral (the controller is described in
:mod:`~nanosim.design.architectures.lqg_synthesis`) -- and returns the first member the rule's checks
accept. The names of the rules' and the controller's constants are re-exported here.

Tuning rules
------------
Robust rule (the default rule, :meth:`LqgRule.robust`; bench member ``lqg``). The identified model holds the
piezo's gain in the identification's small minor loops, about the low end of the uncertainty set's gain range
(:data:`~nanosim.design.robustness.IDENTIFIED_INPUT_GAIN_OF_NOMINAL`); a monotone move (a step, a ramp) runs
at up to the nominal slope, the top of the range, which the linear twin holds. So the design model's piezo
gain is placed inside the range (:func:`design_input_gains`, fractions :data:`ROBUST_GAIN_FRACTIONS` of the
log range from its centre to its top). Its structural modes above :data:`SHIFT_ABOVE_HZ` are moved up by
the factors :data:`ROBUST_FREQ_SCALES` (:func:`shifted_modes`): an LQG designed at the identified frequencies
loses its phase quickly just above those modes, and the set allows them a few per cent higher together
with one more sample of delay; designed for modes above the set's top, the controller's phase holds over
the set. Each member of :data:`ROBUST_GAIN_FRACTIONS` x :data:`ROBUST_LADDER` (frequency scale, inflation,
``R_U``) is designed; in the order of their predicted DAC- and gauge-noise sigma
(:func:`predicted_noise_sigma_nm`), the first is taken that

1. has a multiloop disk margin of at least :data:`ROBUST_MIN_DISK_MARGIN` on the identified model
   [1]_,
2. is stable at every vertex and sample of :data:`~nanosim.design.uncertainty.STAGE_UNCERTAINTY`
   (:func:`~nanosim.design.architectures.common.uncertainty_vertex_check`), and
3. has a mixed real/complex mu upper bound below :data:`ROBUST_MU_MAX` over it
   (:func:`~nanosim.design.parametric.robust_stability_mixed_mu`, [2]_), as
   ``robustness.json`` reports it.

At most :data:`ROBUST_MAX_MU_CHECKS` mu analyses are run; if none passes, the checked member with the least
mu is returned with ``parameters["robust_rule_met"]`` False. ``parameters["tried"]`` records why each cheaper
member was passed over.

Nominal rule (:meth:`LqgRule.nominal`, ``lqg-nominal``): the identified frequencies and gain, the inflations
:data:`MEASUREMENT_INFLATION` tried in order until the multiloop disk margin reaches :data:`MIN_DISK_MARGIN`.
It is not checked over the uncertainty set.

Gain-range rule (:meth:`LqgRule.gain_range`, the bench's ``lqg-gain-range``): the robust rule asks its disk
margin on the identified model, the low end of the gain range; this rule designs at
:data:`GAIN_RANGE_FRACTIONS` of the top of the range and asks the margin at both ends. It buys margin on the
twin (a monotone move's slope) with bandwidth and settling: the disturbance observer's closed-loop pole is
cancelled by the reference path only at the design gain, and a loop designed at the top runs its steps below
it.

Bandwidth rule (:meth:`LqgRule.bandwidth`, ``lqg-bandwidth``): the robust rule fixes the loop's speed by its
weight ``R_U``, so a flexure sweep redesigned by it says little about what the mechanics allow. This rule runs
the robust rule at each weight of :data:`BANDWIDTH_CONTROL_WEIGHTS`, smallest first, and takes the first pick
that meets every check, without the reference prefilter. Robustness is not monotone in bandwidth across the
ladder's scales and inflations, so the weights are scanned rather than bisected. Its checks are made on the
identified model; they do not carry to the top of the gain range (the gain-range rule asks there). It measures
what the mechanics allow; it is not a default.

Reference prefilter (``LqgRule.reference_prefilter``, :mod:`~nanosim.design.architectures.prefilter`): a step
excites a lightly damped closed-loop pair of the reference-to-output map; a notch on the reference at that
pair, the same on every axis, removes the ring without touching the feedback operator (so every margin, mu
and noise figure is unchanged), at the price of a fraction of a millisecond of reference delay.

``parameters["spectral_radius_small_signal_gain"]`` reports, not as a criterion, the loop at
:data:`SMALL_SIGNAL_GAIN` x the identified input gain, the piezo's tangent slope at the end of a long monotone
move, above the set's top.

Delay and inputs
----------------
``nanosim identify`` pairs each command with the reading the controller had when it computed it, so the
identified model is the loop as run (``delay_samples = 0``,
:data:`nanosim.design.robustness.IDENTIFIED_DELAY_SAMPLES`, as ``nanosim design`` and the robustness analysis
use it); ``delay_samples = d`` adds ``z^-d`` registers for a model identified from record rows.

Inputs ``[e; y]`` like every two-degree-of-freedom bench controller: the estimator reads ``y``, the
integrator ``e``; the reference enters through the integrator only (no kick on steps), after the reference
prefilter. What these rules give on the stage is on the documentation's explanation page of the default
controller and in the generated validation page.

References
----------
.. [1] P. Seiler, A. Packard and P. Gahinet, "An introduction to disk margins", IEEE Control Systems
   Magazine 40(5), 2020.
.. [2] P. M. Young, M. P. Newlin and J. C. Doyle, "Computing bounds for the mixed mu problem", Int. J.
   Robust Nonlinear Control 5(6), 1995.
"""
from __future__ import annotations

import math
import warnings
from typing import NamedTuple

from nanosim import constants
from nanosim.design.robustness import IDENTIFIED_DELAY_SAMPLES, IDENTIFIED_INPUT_GAIN_OF_NOMINAL
from nanosim.design.architectures.common import (
    DT_S,
    BenchDesign,
    analysis_grid_hz,
    as_discrete,
    closed_loop_spectral_radius,
    disk_margin_summary,
    freqresp_z,
    loop_response,
    reference_error_bandwidth_hz,
    sensitivity_bandwidth_hz,
    uncertainty_vertex_check,
)
from nanosim.design.architectures.lqg_rules import (
    BANDWIDTH_CONTROL_WEIGHTS,
    BANDWIDTH_TUNING_RULE,
    DEFAULT_LADDER,
    GAIN_RANGE_FRACTIONS,
    GAIN_RANGE_TUNING_RULE,
    MIN_DISK_MARGIN,
    PREFILTER_RULE,
    ROBUST_FREQ_SCALES,
    ROBUST_INFLATIONS,
    ROBUST_LADDER,
    ROBUST_MAX_MU_CHECKS,
    ROBUST_MIN_DISK_MARGIN,
    ROBUST_MU_MAX,
    ROBUST_TUNING_RULE,
    TUNING_RULE,
    LqgRule,
)
from nanosim.design.architectures.lqg_synthesis import (
    CONTROL_WEIGHT,
    DESIGN_FREQ_SCALE,
    DISTURBANCE_CORNER_HZ,
    DISTURBANCE_NOISE_V,
    INTEGRAL_WEIGHT,
    MEASUREMENT_INFLATION,
    ROBUST_GAIN_FRACTIONS,
    SHIFT_ABOVE_HZ,
    SMALL_SIGNAL_GAIN,
    delay_augmented,
    design_input_gains,
    disturbance_noise_V,
    gauge_noise_per_sample_V,
    input_scaled,
    lqg_controller,
    predicted_noise_sigma_nm,
    shifted_modes,
    with_delay,
)

__all__ = ["design_lqg", "LqgRule", "lqg_controller", "delay_augmented", "TUNING_RULE", "CONTROL_WEIGHT",
           "INTEGRAL_WEIGHT", "MEASUREMENT_INFLATION", "DEFAULT_LADDER", "ROBUST_TUNING_RULE",
           "MIN_DISK_MARGIN", "DISTURBANCE_NOISE_V", "ROBUST_LADDER", "ROBUST_FREQ_SCALES",
           "ROBUST_INFLATIONS", "ROBUST_MIN_DISK_MARGIN", "ROBUST_MU_MAX", "ROBUST_MAX_MU_CHECKS",
           "DISTURBANCE_CORNER_HZ", "DESIGN_FREQ_SCALE", "SHIFT_ABOVE_HZ", "SMALL_SIGNAL_GAIN",
           "GAIN_RANGE_FRACTIONS", "GAIN_RANGE_TUNING_RULE", "BANDWIDTH_CONTROL_WEIGHTS", "BANDWIDTH_TUNING_RULE",
           "PREFILTER_RULE", "gauge_noise_per_sample_V", "shifted_modes", "design_input_gains",
           "ROBUST_GAIN_FRACTIONS", "predicted_noise_sigma_nm", "disturbance_noise_V"]


def design_lqg(G, rule: LqgRule | None = None, *, dt: float = DT_S,
               delay_samples: int = IDENTIFIED_DELAY_SAMPLES) -> BenchDesign:
    """LQG with integral action by a tuning rule (module docstring).

    Parameters
    ----------
    G : control.StateSpace
        Identified plant (discrete at ``dt``, or continuous: Tustin), 3 x 3.
    rule : LqgRule or None
        The tuning rule, a value: :meth:`LqgRule.robust` (None, the default),
        :meth:`LqgRule.nominal`, :meth:`LqgRule.gain_range`, :meth:`LqgRule.bandwidth` or a variant
        (``dataclasses.replace``).
    dt : float
        Control period [s].
    delay_samples : int
        Loop delay [samples] in the design model and every check.

    Returns
    -------
    BenchDesign
        Two-degree-of-freedom controller, inputs ``[e; y]``, named ``lqg``. ``parameters["uncertainty_vertices"]``
        holds the brute-force check (:func:`~nanosim.design.architectures.common.uncertainty_vertex_check`)
        of the chosen loop, ``parameters["mu_peak"]`` its mixed-mu bound (``over_uncertainty`` rules),
        ``parameters["tried"]`` every member and the check that rejected it, ``parameters["bandwidth_search"]``
        each weight a bandwidth scan tried. If no member of an ``over_uncertainty`` rule meets every check, the
        checked member with the least mu (or, without a vertex-stable member, the least worst vertex radius;
        with ``margin_at_gain_top`` and no member holding the margin at the top, the largest margin there) is
        returned with ``parameters["robust_rule_met"]`` False and a warning.

    Raises
    ------
    ValueError
        ``rule`` is not an :class:`LqgRule`; no member's nominal loop is stable with the disk margin (and, for
        an ``over_uncertainty`` rule, at every vertex).
    """
    from nanosim.design.architectures.common import split_2dof
    from nanosim.design.uncertainty import ModalPlant
    rule = LqgRule.robust() if rule is None else rule
    if not isinstance(rule, LqgRule):
        raise ValueError(f"rule: expected an LqgRule (LqgRule.robust(), .nominal(), ...), got {rule!r}")
    if rule.control_weights is not None:
        return _seek_bandwidth(G, rule, dt=dt, delay_samples=delay_samples)
    robust = rule.over_uncertainty
    Gd = as_discrete(G, dt)
    Gloop = with_delay(Gd, delay_samples) if delay_samples else Gd
    f = analysis_grid_hz(dt, n=400)
    Gf = freqresp_z(Gd, f)
    ladder = tuple((sc, i, rule.control_weight) for sc in rule.freq_scales for i in rule.inflations)
    if rule.design_input_gain is not None:
        gains = (rule.design_input_gain,)
    elif rule.gain_fractions is not None:
        gains = design_input_gains(rule.gain_fractions)
    else:
        gains = (1.0,)
    members = []
    for g in gains:
        Gdes = input_scaled(Gd, g)
        design_models = {s: shifted_modes(Gdes, s) if s != 1.0 else Gdes for s in dict.fromkeys(m[0] for m in ladder)}
        for scale, infl, ru in ladder:
            dn = disturbance_noise_V(infl) if robust else DISTURBANCE_NOISE_V
            K = lqg_controller(design_models[scale], delay_samples=delay_samples, measurement_inflation=infl,
                               control_weight=ru, disturbance_noise_V=dn)
            Ke, Ky = split_2dof(K, Gd.noutputs)
            rho = closed_loop_spectral_radius(Gd, Ke, Ky, delay_samples)
            sig = float(predicted_noise_sigma_nm(Gloop, K)[:2].max()) if rho < 1.0 else float("inf")
            members.append(_Member(sig, scale, infl, ru, dn, K, rho, g))
    if robust:
        members.sort(key=lambda m: m.sigma_nm)
    min_dm = rule.min_disk_margin
    gain_top = design_input_gains((1.0,))[0]          # the set's top on the identified model (the linear twin's gain)
    tried, best, fallback, short_top, n_mu = [], None, None, None, 0
    check_top = robust and rule.margin_at_gain_top
    for m in members:
        row = {"design_input_gain": m.gain, "design_freq_scale": m.scale, "measurement_inflation": m.inflation,
               "control_weight": m.ru,
               "predicted_sigma_nm": m.sigma_nm, "spectral_radius": m.rho}
        tried.append(row)
        if m.rho >= 1.0:
            continue
        Ke, Ky = split_2dof(m.K, Gd.noutputs)
        r = loop_response(Gf, f, Ke, Ky, delay_samples=delay_samples, dt=dt)
        dm = disk_margin_summary(r)
        row["multiloop_disk_margin"] = dm["multiloop"]
        if dm["multiloop"] < min_dm:
            continue
        dm_top = disk_margin_summary(loop_response(Gf * gain_top, f, Ke, Ky, delay_samples=delay_samples, dt=dt))
        row["multiloop_disk_margin_top"] = dm_top["multiloop"]
        if check_top and dm_top["multiloop"] < min_dm:
            if short_top is None or dm_top["multiloop"] > short_top.disk_margin_top["multiloop"]:
                short_top = m._replace(response=r, disk_margin=dm, disk_margin_top=dm_top)
            continue
        v = uncertainty_vertex_check(Gloop, Ke, Ky, input_gain_of_nominal=IDENTIFIED_INPUT_GAIN_OF_NOMINAL)
        row["worst_spectral_radius"] = v["worst_spectral_radius"]
        cand = m._replace(response=r, disk_margin=dm, vertices=v, disk_margin_top=dm_top)
        if not robust:
            best = cand
            break
        if fallback is None or v["worst_spectral_radius"] < fallback.vertices["worst_spectral_radius"]:
            fallback = cand
        if not v["all_stable"] or n_mu >= rule.max_mu_checks:
            continue
        mu = _mixed_mu_peak(Gloop, m.K, Gd.noutputs)
        n_mu += 1
        row["mu_peak"] = mu
        cand = cand._replace(mu=mu)
        if best is None or mu < best.mu:
            best = cand
        if mu < rule.mu_max:
            break
    if best is None:
        best = fallback
    took_short_top = best is None and short_top is not None
    if took_short_top:
        Ke, Ky = split_2dof(short_top.K, Gd.noutputs)
        best = short_top._replace(vertices=uncertainty_vertex_check(
            Gloop, Ke, Ky, input_gain_of_nominal=IDENTIFIED_INPUT_GAIN_OF_NOMINAL))
    if best is None:
        raise ValueError(f"G: no LQG loop of the rule is stable with a multiloop disk margin >= {min_dm}"
                         f"{' at the identified gain' if check_top else ''}: {tried}")
    sig, scale, infl, ru, dn, K, rho, design_input_gain, r, dm, v, mu, dm_top = best
    met = (mu is not None and mu < rule.mu_max and not took_short_top) if robust else True
    if took_short_top:
        warnings.warn(f"G: no member of the robust LQG rule has a multiloop disk margin >= {min_dm:g} at the top of "
                      f"the uncertainty set's gain range (x{gain_top:.3g} the identified gain; taken: the largest, "
                      f"{dm_top['multiloop']:.3g}); parameters['robust_rule_met'] is False", stacklevel=2)
    elif not met:
        warnings.warn(f"G: no member of the robust LQG rule has mixed mu < {rule.mu_max:g} over the uncertainty set "
                      f"(taken: {'mu %.3g' % mu if mu is not None else 'the least worst vertex radius'}); "
                      "parameters['robust_rule_met'] is False", stacklevel=2)
    prefilter = None
    if rule.reference_prefilter:
        from nanosim.design.architectures.prefilter import design_reference_prefilter
        K_fb = K
        K, prefilter = design_reference_prefilter(Gd, K, Gd.noutputs, delay_samples=delay_samples, dt=dt)
        if K is not K_fb:           # the reference path changed: its response to the reference too
            r = loop_response(Gf, f, *split_2dof(K, Gd.noutputs), delay_samples=delay_samples, dt=dt)
    Ke, Ky = split_2dof(K, Gd.noutputs)
    Pup = ModalPlant(Gd, dt).state_space(1.0, 1.0, SMALL_SIGNAL_GAIN, delay_samples)
    params = {"rule": "robust" if robust else "nominal", "robust_rule_met": met, "uncertainty_vertices": v,
              "design_input_gain": float(design_input_gain),
              "mu_peak": mu,
              "design_freq_scale": scale, "shift_above_hz": SHIFT_ABOVE_HZ,
              "disturbance_noise_V": dn, "disturbance_corner_hz": DISTURBANCE_CORNER_HZ,
              "tried": tried, "control_weight": ru, "integral_weight": INTEGRAL_WEIGHT,
              "measurement_inflation": infl, "input_noise_V": constants.DAC_WHITE_NOISE_V,
              "measurement_noise_V": gauge_noise_per_sample_V(dt), "controller_order": int(K.nstates),
              "predicted_bandwidth_S_hz": sensitivity_bandwidth_hz(r),
              "predicted_bandwidth_ref_to_error_hz": reference_error_bandwidth_hz(r),
              "predicted_bandwidth_ref_to_error_top_hz": reference_error_bandwidth_hz(
                  loop_response(Gf * gain_top, f, Ke, Ky, delay_samples=delay_samples, dt=dt)),
              "predicted_disk_margin": dm,
              "predicted_disk_margin_top_of_gain_range": dm_top, "top_of_gain_range": float(gain_top),
              "gain_range_margin": bool(check_top),
              "predicted_noise_sigma_nm": sig, "closed_loop_spectral_radius": rho,
              "spectral_radius_small_signal_gain": closed_loop_spectral_radius(Pup, Ke, Ky, 0),
              "loop_delay_samples": delay_samples, "reference_prefilter": prefilter}
    text = rule.text + ("; " + PREFILTER_RULE if prefilter is not None else "")
    return BenchDesign("lqg", K, Gd.noutputs, text, params)


def _seek_bandwidth(G, rule: LqgRule, **kw) -> BenchDesign:
    """A bandwidth scan (:meth:`LqgRule.bandwidth`): ``rule`` at each of its control weights, smallest first,
    until its pick meets every check.
    """
    import dataclasses

    levels, picks = [], []
    for w in rule.control_weights:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)          # a weight whose pick fails: the next weight
            try:
                d = design_lqg(G, rule.at_control_weight(w), **kw)
            except ValueError as exc:                             # no member stable with the disk margin
                levels.append({"control_weight": w, "error": str(exc)[:200]})
                continue
        p = d.parameters
        levels.append({"control_weight": w, "robust_rule_met": p["robust_rule_met"], "mu_peak": p["mu_peak"],
                       "predicted_bandwidth_S_hz": p["predicted_bandwidth_S_hz"],
                       "members_tried": len(p["tried"])})
        picks.append(d)
        if p["robust_rule_met"]:
            break
    if not picks:
        raise ValueError(f"G: no LQG loop of the bandwidth rule is stable with the disk margin at any control weight "
                         f"{rule.control_weights}")
    d = picks[-1]
    if not d.parameters["robust_rule_met"]:
        d = min(picks, key=lambda x: math.inf if x.parameters["mu_peak"] is None else x.parameters["mu_peak"])
        warnings.warn(f"G: at no control weight of {rule.control_weights} does the robust LQG rule meet every "
                      f"check (taken: R_u {d.parameters['control_weight']:g}, mu {d.parameters['mu_peak']}); "
                      "parameters['robust_rule_met'] is False", stacklevel=3)
    params = dict(d.parameters, rule="bandwidth", bandwidth_search=levels)
    return dataclasses.replace(d, tuning_rule=rule.scan_clause + d.tuning_rule, parameters=params)


class _Member(NamedTuple):
    """A member of a rule's ladder and, once checked, its loop figures."""

    sigma_nm: float
    scale: float
    inflation: float
    ru: float
    dn: float
    K: object
    rho: float
    gain: float = 1.0
    response: object = None
    disk_margin: dict | None = None
    vertices: dict | None = None
    mu: float | None = None
    disk_margin_top: dict | None = None


def _mixed_mu_peak(Gloop, K, n_error: int) -> float:
    """Mixed-mu upper bound over :data:`~nanosim.design.uncertainty.STAGE_UNCERTAINTY` of the loop (``inf`` when a
    centre loop is unstable), as ``robustness.json`` reports it.
    """
    from nanosim.design.robustness import LoopPlant, analyze_controller
    s = analyze_controller(K, LoopPlant.identified(Gloop, 0), n_error=n_error).summary
    return float("inf") if s.get("mu_peak") is None else float(s["mu_peak"])


