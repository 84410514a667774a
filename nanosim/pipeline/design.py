"""``nanosim design``: reduce, synthesize, discretize and export (paper Sec. 4).

The only part of the design layer that writes files. Steps (paper = DOI
10.1115/1.2936861, Sec. 4.1-4.2, Appendix B):

1. :func:`~nanosim.design.reduction.reduce_model` -- DC-matched balanced truncation;
2. :func:`~nanosim.design.reduction.multiplicative_uncertainty` -- its error ``E_o``;
3. :func:`~nanosim.design.damping.damping_loop` (``DesignConfig.damping_zeta > 0``,
   beyond the paper) -- the inner active-damping loop, closed first;
4. :func:`~nanosim.design.hinf.design_hinf` -- mixed-sensitivity synthesis on the
   (damped) reduced model, analysed with the full and twin plants;
5. :func:`~nanosim.design.discretize.discretize_controller` -- the 4 kHz controller;
6. ``controller.npz``, ``reduced_model.npz``, ``design.json``, ``design.mat`` and the
   registered design figures (:data:`nanosim.pipeline.artifacts.FIGURES`);
7. :func:`write_robustness` -- ``robustness.json`` and its figures: the exported discrete
   controller on the loop as it is run (:mod:`nanosim.design.robustness`), with the linear
   twin and with the identified model.
"""
from __future__ import annotations

import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np

from nanosim import constants, fileio
from nanosim.design.damping import damped_plant, damping_loop
from nanosim.design.discretize import (
    dc_gain_discrete,
    discrete_closed_loop,
    discretize_controller,
    error_rel_to_peak,
)
from nanosim.design.hinf import Design, design_hinf
from nanosim.design.loops import feedback_operator, stack_inputs
from nanosim.design.lti import (
    SIGN_CONVENTION,
    UNITS,
    analysis_grid_hz,
    as_ss,
    db,
    load_state_space_npz,
    single_threaded_blas,
)
from nanosim.design.reduction import multiplicative_uncertainty, reduce_model
from nanosim.design.loopresponse import delay_ss
from nanosim.design.robustness import (
    IDENTIFIED_DELAY_SAMPLES,
    STAGE_UNCERTAINTY,
    LoopPlant,
    analysis_memo,
    analyze_controller,
    controller_systems,
)
from nanosim.design.weights import Weights
from nanosim.paper import PAPER
from nanosim.pipeline import artifacts as A
from nanosim.pipeline.export import mat_beside, write_controller_exports, write_state_space_mat
from nanosim.pipeline.config import DesignConfig
from nanosim.pipeline.timings import record_timings
from nanosim.plots.design import (
    plot_closed_loop_bode,
    plot_controller_bode,
    plot_exported_loops,
    plot_hankel,
    plot_reduction_bode,
    plot_sensitivity,
    plot_T_KS,
    plot_uncertainty,
    plot_weights,
)
from nanosim.plant.stage import StageConfig
from nanosim.plots.robustness import plot_disk_margins, plot_loop_singular_values

__all__ = ["run_design", "write_robustness", "twin_loop_plant", "model_loop_delay_samples", "DELAY_PADE_ORDER"]

# Order of the Pade approximant of the loop's computation delay in the design model (per input):
# exp(-s T) at T = 250 us to 0.2 deg at 500 Hz.
DELAY_PADE_ORDER = 2

# the reference (mixsyn) design's loop figures, when another controller is exported: this prefix + the registered name
REFERENCE_FIGURE_PREFIX = "reference_"

# the damping loop's discretization is checked over 0 .. this [Hz]
DAMPING_LOOP_CHECK_BAND_HZ = 500.0

# design.json's "units": the design layer's UNITS, what each key's suffix means, and the keys without one
DESIGN_JSON_UNITS = {
    **UNITS,
    "frequencies": "Hz (keys ending in _hz; *_band_hz: the band a value was checked over)",
    "relative_errors": "fraction (0.01 = 1 %): dc_gain_rel_error; discretization_max_rel_error, "
                       "discretization_errors_by_method/* and tustin_max_rel_error, |Kd - K| / |K| over "
                       "0 .. discretization_check_band_hz; damping_loop_discretization/"
                       "max_rel_error_to_peak, |Kyd - Ky| / peak |Ky| over 0 .. its check_band_hz",
    "hankel_sv, hankel_sv_kept_min, hankel_sv_dropped_max, reduction_error_bound_hinf":
        "sensor V per controller V (Hankel singular values of the full model and the H-infinity bound of the "
        "reduction error, absolute, not dB)",
    "dc_gain_full, dc_gain_reduced": "sensor V per controller V (rows X, Y, Z; columns actuators A, B, C)",
    "damping_loop_discretization/dc_gain_abs_max": "controller V per sensor V",
    "gamma*": "dimensionless, absolute (H-infinity norm bound of the weighted closed loop, not dB)",
    "S_peak_*, sigma_S_1hz_nominal": "largest singular value of S, dimensionless, absolute (not dB)",
    "Eo_*_dB*": "dB (Eo: relative reduction error sigma_max; the band is in the key: below 140 Hz, above 600 Hz)",
    "weights/W*/num, den": "coefficients in descending powers of s, s in rad/s: W(s) = (num(s)/den(s))^power",
    "*_rad_s": "rad/s", "dt_s": "seconds", "damping_loop/gain_c_s": "seconds (c of the damping loop's Ky)",
    "closed_loop_min_damping_*": "damping ratio (dimensionless)",
    "spectral_radius*": "|z| of the discrete closed-loop poles",
    "*disk_margin/multiloop*, *disk_margin/loop_at_a_time*, tried/*/multiloop_disk_margin":
        "disk-margin alpha, dimensionless (as robustness.json's *_alpha)",
    "mu_peak": "structured singular value (dimensionless; robustly stable if < 1)",
    "*_V": "volts (controller V unless the key says otherwise)", "*_nm": "nanometres",
}

_ROBUSTNESS_UNITS = {
    "peak_<map>": "largest singular value, dimensionless for So, Si, To, Ti; controller V / sensor V for KS, "
                  "KS_fb; sensor V / controller V for SG (sensor V = 5 um)",
    "*_hz": "Hz", "*_deg": "degrees", "*_db": "dB",
    "*alpha*": "disk margin (radius of the disk of simultaneous gain/phase factors), dimensionless",
    "gain_margin_low/high": "gain factor", "spectral_radius, sampled_worst": "|z| of the closed-loop poles",
    "mu_*": "structured singular value over the uncertainty set (robustly stable if mu_peak < 1)",
    "least_damped_zeta": "damping ratio of the least damped closed-loop pole (z mapped by s = ln z / dt)",
    "least_damped_in_band_*": "the same among the poles inside least_damped_band_hz ([low, high] Hz)",
    "least_damped_visible_*": "the same among the poles that add >= 0.05 to the peak of [T_ry, S_o] (the identified "
                              "model holds one copy of each mode per column; the copies' difference stays undamped "
                              "and unobservable)",
}


class _Progress:
    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.t0 = time.perf_counter()

    def __call__(self, msg: str):
        if self.enabled:
            print(f"[nanosim.design {time.perf_counter() - self.t0:7.2f} s] {msg}", file=sys.stderr, flush=True)


def model_loop_delay_samples(model_npz) -> int:
    """Delay of the loop as run beyond the model in ``model_npz`` [samples].

    The file's ``loop_delay_samples`` if it has one, else
    :data:`nanosim.design.robustness.IDENTIFIED_DELAY_SAMPLES` (0): ``nanosim identify``
    pairs each command with the reading the controller had, so its model has the loop's
    delays. (A model identified from record rows, ``u_k`` with the reading after
    ``step(u_k)``, lacks :data:`~nanosim.design.robustness.RECORD_ROW_DELAY_SAMPLES` plus the
    computation delay: give it a ``loop_delay_samples`` entry.)
    """
    z = fileio.load_npz(model_npz, required=("A", "B", "C", "D"))
    if "loop_delay_samples" in z:
        return int(np.asarray(z["loop_delay_samples"]).ravel()[0])
    return IDENTIFIED_DELAY_SAMPLES


def _twin_as_run(G_twin, electronics, dt: float):
    """The continuous twin as the sampled loop sees it.

    The zero-order hold's half sample and the computation delay (Pade), the amplifier's
    first-order lag and the gauge's Butterworth filter.
    """
    import control as ct
    from nanosim.plant.filters import butterworth_lowpass
    if G_twin is None:
        return None
    n = G_twin.ninputs
    G = _with_input_delay(G_twin, (0.5 + electronics.computation_delay_samples) * dt)
    if electronics.amplifier_bandwidth_Hz is not None:
        wa = 2 * np.pi * electronics.amplifier_bandwidth_Hz
        G = ct.series(ct.append(*[ct.ss(ct.tf([wa], [1.0, wa]))] * n), G)
    if electronics.gauge_bandwidth_Hz is not None:
        num, den = butterworth_lowpass(electronics.gauge_bandwidth_Hz, electronics.gauge_filter_order)
        G = ct.series(G, ct.append(*[ct.ss(ct.tf(num, den))] * G.noutputs))
    return ct.ss(G.A, G.B, G.C, G.D)


def twin_loop_plant(twin_sysd) -> LoopPlant:
    """The linear twin as the bench's loop runs it, for ``nanosim design`` and ``nanosim compare``.

    ``twin_sysd``: the zero-order-hold twin (``twin.npz`` path or discrete StateSpace). The loop's
    one-sample delay, and the bench electronics of ``StageConfig()`` (the stage every experiment runs):
    its computation delay and the amplifier and gauge filters (:meth:`LoopPlant.twin`).
    """
    return LoopPlant.twin(twin_sysd, StageConfig().electronics)


def _with_input_delay(G, delay_s: float):
    """``G(s)`` behind a Pade(:data:`DELAY_PADE_ORDER`) approximant of ``exp(-s delay_s)`` per input."""
    import control as ct
    if G is None or delay_s <= 0:
        return G
    Dl = delay_ss(G.ninputs, 1, "continuous", delay_s, DELAY_PADE_ORDER, 0)
    Gs = ct.series(Dl, G)
    return ct.ss(Gs.A, Gs.B, Gs.C, Gs.D)


def write_robustness(out_dir, controller, plants: dict, *, uncertainty=STAGE_UNCERTAINTY, mu: bool = True,
                     figures: bool = True) -> dict:
    """``robustness.json`` and its figures for one discrete controller on the loop as run.

    Parameters
    ----------
    out_dir : path
        Folder (created) for ``robustness.json``, ``fig23_robustness_sigma.png`` and
        ``fig24_robustness_disk_margins.png``.
    controller : path, ControllerConfig, DiscreteController or discrete StateSpace
        See :func:`nanosim.design.robustness.analyze_controller`.
    plants : dict of str to LoopPlant
        Key -> plant as the loop runs it (e.g. ``{"twin": LoopPlant.twin(...),
        "identified": LoopPlant.identified(...)}``).
    uncertainty : UncertaintySet
    mu : bool
        Include the mu analysis.
    figures : bool
        Write the two figures (False: ``robustness.json`` only).

    Returns
    -------
    dict
        The content of ``robustness.json``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    analyses = {k: analyze_controller(controller, p, uncertainty=uncertainty, mu=mu) for k, p in plants.items()}
    # a path is recorded by its name: the folder may be a staging folder that is renamed when complete
    doc = {"controller": Path(controller).name if isinstance(controller, (str, os.PathLike))
           else type(controller).__name__,
           "loop": "u_k = K (r_k - y_k) + Ky y_k from the reading y_k; Stage.step(u_k) returns y_(k+1) and the "
                   "command reaches the DAC after the computation delay. Each plant's loop_delay_samples is the delay "
                   "beyond its model (twin: 1 + computation delay, amplifier and gauge filters added; identified "
                   "model: 0, it was identified from the readings the controller had).",
           "uncertainty_set": uncertainty.to_dict(), "units": _ROBUSTNESS_UNITS,
           "plants": {k: a.to_dict() for k, a in analyses.items()}}
    for key in ("disk_margin_alpha", "dm_input_alpha", "dm_output_alpha", "mu_peak", "peak_So", "peak_Si"):
        vals = [a.summary.get(key) for a in analyses.values() if a.summary.get(key) is not None]
        if vals:
            doc[f"worst_{key}"] = min(vals) if "alpha" in key else max(vals)
    fileio.write_json(out / A.ROBUSTNESS_JSON, doc)
    if not figures:
        return doc
    labels = {k: a.label for k, a in analyses.items()}
    by_label = {labels[k]: a for k, a in analyses.items()}
    fileio.save_figure(plot_loop_singular_values(by_label), out / A.FIG23_ROBUSTNESS_SIGMA)
    fileio.save_figure(plot_disk_margins(by_label), out / A.FIG24_ROBUSTNESS_DISK_MARGINS)
    return doc


def _export_bench(out: Path, G, dt: float, loop_delay: int, units, say, architecture: str) -> dict:
    """Overwrite ``controller.npz`` with the bench design ``architecture``
    (:data:`nanosim.design.architectures.DESIGN_RULES`); the ``design.json`` entries that describe it.
    """
    from nanosim.design.architectures import design
    bd = design(architecture, G, dt=dt, delay_samples=loop_delay)
    Akd, Bkd, Ckd, Dkd, _ = bd.matrices
    io = ("inputs [e; y]: e = r - y (n_error = 3 columns), then the measurement y in sensor volts" if bd.two_dof
          else "input e = r - y (n_error = 3 columns) in sensor volts")
    bench_units = np.array([*units[:2], io, "u = Ckd x + Dkd [e; y], x[k+1] = Akd x[k] + Bkd [e; y] (discrete only)",
                            "dt in seconds"])
    p = bd.parameters
    extra = {} if p.get("gamma") is None else {"gamma": np.float64(p["gamma"])}
    fileio.write_npz(out / A.CONTROLLER_NPZ, Akd=Akd, Bkd=Bkd, Ckd=Ckd, Dkd=Dkd, dt=np.float64(dt),
                     n_error=np.int64(bd.n_error), units=bench_units, sign_convention=np.array(SIGN_CONVENTION),
                     method=np.array(architecture), tuning_rule=np.array(bd.tuning_rule), **extra)
    write_controller_exports(out / A.CONTROLLER_NPZ, Akd, Bkd, Ckd, Dkd, dt, bd.n_error)
    dm = (p.get("predicted_disk_margin") or {}).get("multiloop")
    say(f"exported controller: {architecture} ({bd.K.nstates} states)"
        + ("" if p.get("gamma") is None else f", gamma {p['gamma']:.3f}")
        + ("" if dm is None else f", predicted multiloop disk margin {dm:.3f}"))
    return {"architecture": architecture, "controller_order": int(bd.K.nstates),
            "gamma": None if p.get("gamma") is None else float(p["gamma"]),
            "tuning_rule": bd.tuning_rule,
            "exported_controller": {"architecture": architecture, "tuning_rule": bd.tuning_rule,
                                    "controller_order": int(bd.K.nstates), "parameters": p},
            "architecture_note": (f"controller.npz holds the {architecture} design (nanosim.design.architectures; "
                                  f"nanosim design --architecture NAME exports another bench member, --paper-design "
                                  f"the paper's own); exported_controller.parameters holds its reduction, weights and "
                                  f"predictions, and fig11b, fig12, fig18, fig21 and fig22 show it; reference_design "
                                  f"and the top-level reduction, discretization, S/T peak, bandwidth and "
                                  f"closed_loop_min_* entries describe the mixed-sensitivity reference of these "
                                  f"settings (--architecture mixsyn), with loop figures "
                                  f"{REFERENCE_FIGURE_PREFIX}fig*")}


def _mode_damping(controller_npz, plants: dict) -> dict:
    """Per plant as the loop runs it: each lightly damped mode's open-loop damping and the exported controller's
    least closed-loop damping near it (:func:`nanosim.design.architectures.hinf_fourblock.mode_damping_table`).
    """
    from nanosim.design.architectures.hinf_fourblock import mode_damping_table
    from nanosim.design.robustness import controller_systems
    K, Ky = controller_systems(controller_npz)
    return {k: mode_damping_table(p.G, K, delay_samples=p.delay_samples, Ky=Ky) for k, p in plants.items()}


def _input_ref(path, out_dir) -> dict:
    """An input file as design.json records it, with its sha256.

    Its path is relative to the run folder when it lies inside it (the run folder may be a staging
    folder renamed at the end), else absolute.
    """
    from nanosim.pipeline.runfolder import run_relative, sha256_file
    return {"path": run_relative(path, out_dir), "sha256": sha256_file(Path(path))}


@single_threaded_blas
@analysis_memo()             # the design's mu checks and robustness.json: one analysis of a loop
def run_design(model_npz, out_dir, config: DesignConfig | None = None, *, twin=None, progress: bool = False,
               dt: float | None = None, figures: bool = True) -> Design:
    """Reduce, design, discretize and export (paper Sec. 4).

    Parameters
    ----------
    model_npz : path
        Identified model: continuous ``A, B, C, D`` (required; controller V ->
        sensor V) and optionally discrete ``Ad, Bd, Cd, Dd, dt``.
    out_dir : path
        Output directory (created). Files are written atomically.
    config : DesignConfig, optional
        Reduced order, damping loop (``damping_zeta = 0``: the paper's single
        loop; else the controller has inputs ``[e; y]``, ``n_error = 3``),
        weights (``None``: the paper's; a :class:`~nanosim.design.weights.Weights`,
        mapping or .json/.toml path), discretization method and ``gamma_relax``.
        Default ``DesignConfig()``.
    twin : control.StateSpace or path to an ``.npz`` with ``A, B, C, D``, optional
        Independent plant for a closed-loop stability check (its sampled loop is analysed
        with the zero-order hold's half-sample delay).
    progress : bool, default False
        Print stage messages to stderr.
    dt : float, optional
        Controller sample time [s]; default the model's ``dt`` or 1/4000.
    figures : bool, default True
        Write the PNG figures (False: the files without them, e.g. a sweep's scratch design; about half
        of the step's time).

    Returns
    -------
    Design
        With ``reduction`` and ``discretization`` set.

    Notes
    -----
    Writes ``controller.npz`` (``Ak, Bk, Ck, Dk`` continuous; ``Akd, Bkd, Ckd, Dkd,
    dt`` discrete; string arrays ``units``, ``sign_convention``, ``method``),
    ``reduced_model.npz``, ``design.json`` (its step timings in ``timings.json``), ``design.mat`` and the PNG figures of
    the ``design`` step registered in :data:`nanosim.pipeline.artifacts.FIGURES`
    (``fig08_hankel_sv.png`` ... ``fig22_controller_bode.png``).
    """
    import control as ct
    cfg = DesignConfig() if config is None else config
    damping_zeta = cfg.damping_zeta if cfg.has_damping_loop else None
    say = _Progress(progress)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    G_full, Gd_full = load_state_space_npz(model_npz)
    say(f"loaded {model_npz}: {G_full.nstates} states, {G_full.noutputs}x{G_full.ninputs}")
    W = Weights.coerce(cfg.weights)
    W.check()
    G_twin = None
    if twin is not None:
        G_twin = load_state_space_npz(twin)[0] if isinstance(twin, (str, os.PathLike)) else as_ss("twin", twin)
    if dt is None:
        dt = Gd_full.dt if Gd_full is not None else constants.CONTROL_PERIOD_S
    # delay the loop has beyond the model: into the design model unless the config says otherwise (the
    # paper: 0). The identified model has the bench's delays and filters; the twin (mechanics) gets them here.
    loop_delay = model_loop_delay_samples(model_npz)
    design_delay = loop_delay if cfg.delay_samples is None else cfg.delay_samples
    G_des = _with_input_delay(G_full, design_delay * dt)
    bench = StageConfig().electronics
    G_twin_run = _twin_as_run(G_twin, bench, dt)
    timings = {}
    t = time.perf_counter()
    red = reduce_model(G_full, cfg.reduced_order)
    timings["reduction_s"] = time.perf_counter() - t
    say(f"reduced to {red.order} states; DC gain rel. error {red.dc_gain_rel_error:.2e}; "
        f"HSV kept >= {red.hsv_kept.min() if red.hsv_kept.size else float('nan'):.3g}, "
        f"dropped <= {red.hsv_dropped.max() if red.hsv_dropped.size else 0:.3g}")
    dl = None
    if damping_zeta is not None:
        dl = damping_loop(red.G_reduced, damping_zeta, lowpass_hz=cfg.damping_lowpass_hz)
        say(f"damping loop: +{dl.zeta_added:g} damping at {dl.mode_hz:.1f} Hz, low-pass {dl.lowpass_hz:g} Hz")
    if design_delay:
        say(f"design model with the loop's computation delay: {design_delay} sample(s), Pade({DELAY_PADE_ORDER})")
    t = time.perf_counter()
    d = design_hinf(damped_plant(_with_input_delay(red.G_reduced, design_delay * dt), dl), W,
                    G_full=damped_plant(G_des, dl), G_twin=damped_plant(G_twin_run, dl), gamma_relax=cfg.gamma_relax)
    d = dataclasses.replace(d, damping=dl)
    timings["synthesis_and_analysis_s"] = time.perf_counter() - t
    say(f"H-infinity: gamma = {d.gamma:.4f}, controller order {d.controller_order}, "
        f"||S|| nominal {d.S_peak_nominal:.3f}, full {d.S_peak_full:.3f}, "
        f"BW S {d.bandwidth_S_hz:.1f} Hz, BW T {d.bandwidth_T_hz:.1f} Hz, stable full: {d.stable_full}")
    t = time.perf_counter()
    K2 = d.controller_2dof()
    disc = discretize_controller(d.K, dt, cfg.discretization)
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
    eo_db = db(eo)

    # --- artifacts
    Kd = Kd2
    io_units = (["u = Ck x + Dk e (continuous: dx/dt = Ak x + Bk e; discrete: x[k+1] = Akd x[k] + Bkd e[k])"]
                if dl is None else
                ["inputs [e; y]: e = r - y (n_error = 3 columns), then the measurement y in sensor volts",
                 "u = Ck x + Dk [e; y] (continuous: dx/dt = Ak x + Bk [e; y]; discrete likewise with Akd..Dkd)"])
    units = np.array(["e: tracking error r - y in sensor volts (X,Y,Z), 5 um/V",
                      "u: controller volts for actuators A,B,C (before the x20 amplifier)", *io_units,
                      "dt in seconds"])
    fileio.write_npz(out / A.CONTROLLER_NPZ, Ak=K2.A, Bk=K2.B, Ck=K2.C, Dk=K2.D,
                     Akd=Kd.A, Bkd=Kd.B, Ckd=Kd.C, Dkd=Kd.D, dt=np.float64(dt), gamma=np.float64(d.gamma),
                     n_error=np.int64(ny), units=units, sign_convention=np.array(SIGN_CONVENTION),
                     method=np.array(disc.method))
    write_controller_exports(out / A.CONTROLLER_NPZ, Kd.A, Kd.B, Kd.C, Kd.D, dt, ny)
    write_state_space_mat(mat_beside(out / A.REDUCED_MODEL_NPZ), red.G_reduced.A, red.G_reduced.B, red.G_reduced.C,
                          red.G_reduced.D, 0.0, units=UNITS["plant_G"])
    fileio.write_npz(out / A.REDUCED_MODEL_NPZ, A=red.G_reduced.A, B=red.G_reduced.B, C=red.G_reduced.C,
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
    fileio.write_mat(out / A.DESIGN_MAT, mat)

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
        "discretization_max_rel_error": disc.max_rel_error, "discretization_check_band_hz": disc.f_check_hz,
        "discretization_worst_freq_hz": disc.worst_freq_hz,
        "discretization_errors_by_method": disc.errors_by_method,
        "tustin_max_rel_error": disc.tustin_max_rel_error,
        "discretization_within_1_percent": disc.within_tol,
        "damping_loop_discretization": None if disc_y is None else {
            "method": disc_y.method,
            "max_rel_error_to_peak": error_rel_to_peak(dl.Ky, disc_y.Kd, DAMPING_LOOP_CHECK_BAND_HZ),
            "check_band_hz": DAMPING_LOOP_CHECK_BAND_HZ,
            "dc_gain_abs_max": float(np.abs(dc_gain_discrete(disc_y.Kd)).max())},
        "stable_discrete_full": stable_d, "spectral_radius_discrete_full": rho_d,
        "stable_discrete_full_with_plain_tustin": stable_d_tustin,
        "units": DESIGN_JSON_UNITS,
        "paper_targets": {"gamma": PAPER["gamma"], "controller_order": PAPER["order"],
                          "S_peak_nominal_max": PAPER["S_nom"], "S_peak_full_model_max": PAPER["S_full"],
                          "bandwidth_S_hz": PAPER["bwS"], "bandwidth_T_hz": PAPER["bwT"]},
        "gamma_relax": float(cfg.gamma_relax),
        "loop_delay_samples": loop_delay, "design_delay_samples": design_delay,
        "design_delay_model": f"Pade({DELAY_PADE_ORDER}) of exp(-s {design_delay} dt) per input" if design_delay
        else "none",
        "twin_analysis": None if G_twin is None else
        f"twin behind Pade({DELAY_PADE_ORDER}) of {0.5 + bench.computation_delay_samples:g} samples (zero-order hold "
        f"and computation delay), amplifier {bench.amplifier_bandwidth_Hz} Hz, gauge {bench.gauge_bandwidth_Hz} Hz",
        "inputs": {"model_npz": _input_ref(model_npz, out_dir),
                   "twin": None if twin is None else (_input_ref(twin, out_dir) if isinstance(twin, (str, os.PathLike))
                                                      else f"StateSpace, {G_twin.nstates} states")},
    })
    try:
        import control as _c
        import slycot as _s
        summary["versions"] = {"control": _c.__version__, "slycot": _s.__version__, "numpy": np.__version__}
    except Exception:  # pragma: no cover
        pass
    summary["reference_design"] = {"architecture": "mixsyn", "gamma": summary.get("gamma"),
                                   "controller_order": summary.get("controller_order"),
                                   "weights": W.to_dict()}
    if cfg.architecture != "mixsyn":
        summary.update(_export_bench(out, Gd_full if Gd_full is not None else G_full, dt, loop_delay, units, say,
                                     cfg.architecture))
    else:
        summary.update({"architecture": "mixsyn", "tuning_rule": "mixed-sensitivity S/KS/T H-infinity of these "
                        "settings (nanosim.design.hinf.design_hinf)"})
    fileio.write_json(out / A.DESIGN_JSON, summary)
    record_timings(out, {A.DESIGN_JSON: {"timings_s": timings}})

    say("robustness of the exported discrete controller on the loop as run")
    plants = {}
    if G_twin is not None:
        twin_d = load_state_space_npz(twin)[1] if isinstance(twin, (str, os.PathLike)) else None
        plants["twin"] = twin_loop_plant(twin_d if twin_d is not None else ct.c2d(G_twin, dt, "zoh"))
    # the identified discrete model is in the record-row convention; a ZOH discretization is not
    plants["identified"] = (LoopPlant.identified(Gd, delay_samples=loop_delay) if Gd is Gd_full
                            else LoopPlant.twin(Gd, label="full model"))
    write_robustness(out, out / A.CONTROLLER_NPZ, plants, figures=figures)
    summary["closed_loop_mode_damping"] = _mode_damping(out / A.CONTROLLER_NPZ, plants)
    fileio.write_json(out / A.DESIGN_JSON, summary)
    if not figures:
        say(f"done in {time.perf_counter() - t_start:.1f} s (no figures) -> {out}")
        return dataclasses.replace(d, reduction=red, discretization=disc)

    say("writing figures")
    figs = {
        A.FIG08_HANKEL_SV: plot_hankel(red),
        A.FIG09_REDUCTION_BODE: plot_reduction_bode(red),
        A.FIG10_UNCERTAINTY: plot_uncertainty(red),
    }
    loops = {A.FIG12_SENSITIVITY: plot_sensitivity(d), A.FIG18_T_KS: plot_T_KS(d),
             A.FIG21_CLOSED_LOOP_BODE: plot_closed_loop_bode(d), A.FIG22_CONTROLLER_BODE: plot_controller_bode(d, disc)}
    if cfg.architecture == "mixsyn":
        figs.update({A.FIG11B_WEIGHTS: plot_weights(W), **loops})
    else:
        # the exported controller's loop figures under the registered names, the reference's under its own
        for name, fig in loops.items():
            fileio.save_figure(fig, out / f"{REFERENCE_FIGURE_PREFIX}{name}")
        exp = summary["exported_controller"]
        Ke, Ky = controller_systems(out / A.CONTROLLER_NPZ)
        w = exp["parameters"].get("weights")
        We = Weights.from_dict({k: w[k] for k in ("Wp", "Wt", "Wu")}) if w and all(k in w for k in ("Wp", "Wt", "Wu")) \
            else None
        ex = plot_exported_loops(cfg.architecture, Gd, Ke, Ky, delay_samples=loop_delay, weights=We,
                                 gamma=exp["parameters"].get("gamma"))
        figs.update({A.FIG11B_WEIGHTS: plot_weights(We if We is not None else W),
                     A.FIG12_SENSITIVITY: ex["sensitivity"], A.FIG18_T_KS: ex["T_KS"],
                     A.FIG21_CLOSED_LOOP_BODE: ex["closed_loop_bode"], A.FIG22_CONTROLLER_BODE: ex["controller_bode"]})
    for name, fig in figs.items():
        fileio.save_figure(fig, out / A.figure(name).name)
    say(f"done in {time.perf_counter() - t_start:.1f} s -> {out}")
    return dataclasses.replace(d, reduction=red, discretization=disc)
