"""report.md and report.html: every figure and the paper-vs-simulation table of a run folder."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from nanosim import constants as C
from nanosim.fileio import write_text
from nanosim import paper as P
from nanosim.paper import PAPER, PAPER_CONTOUR_SPEED_UM_S, PAPER_STEP_UM
from nanosim.pipeline import artifacts as A
from nanosim.pipeline.blocks import EM, to_html, to_markdown

__all__ = ["architecture_section", "design_warnings", "pass_count", "write_report"]

# (section, label, paper value, unit, getter on the run's json dicts, acceptance test, band text)


def _load(run: Path, name: str) -> dict:
    p = run / name
    return json.loads(p.read_text()) if p.is_file() else {}


def _get(d, *keys):
    for k in keys:
        if isinstance(d, dict) and k in d:
            d = d[k]
        elif isinstance(d, list) and isinstance(k, int) and -len(d) <= k < len(d):
            d = d[k]
        else:
            return None
    return d


B = P.BANDS


def _load_or_none(run: Path, name: str):
    p = run / name
    return json.loads(p.read_text()) if p.is_file() else None


def _num(v) -> bool:
    """A number (not a bool, not NaN): what a band can be checked on."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and not math.isnan(v)


def _check(band_key: str):
    """(check, text) of a band; a missing or non-numeric value is outside every band."""
    return (lambda v: _num(v) and B[band_key].ok(v)), B[band_key].text


_MEASURED = ((lambda v: _num(v)), "measured (no band)")
S_STAGE, S_IDENT, S_DESIGN, S_LOOP = ("Stage model (Sec. 3)", "Identification (Table 1)", "H-infinity design (Sec. 4)",
                                      "Closed loop on the MuJoCo stage (Sec. 5)")


def _rows(run: Path):
    """Rows (section, label, paper, simulation, unit, ok, band) of the paper-vs-simulation table.

    The rows with a band (``ok`` not None) are the checks of ``compare_to_paper.py`` (same
    quantities, same bands, a missing file or value counted as outside), so both count the same;
    rows without a band are shown for comparison only.
    """
    modes, ident, des, met = (_load_or_none(run, n) for n in (A.MODES_JSON, A.IDENTIFY_JSON, A.DESIGN_JSON,
                                                              A.METRICS_JSON))
    rows = []

    def add(section, label, paper, sim, unit, check=None, band=""):
        ok = None if check is None else bool(check(sim) if callable(check) else check)
        rows.append((section, label, paper, sim, unit, ok, band))

    def missing(section, name):
        add(section, f"{name} of the run", None, None, "", lambda v: False, "present")

    if modes is None:
        missing(S_STAGE, A.MODES_JSON)
    else:
        below = [m for m in modes.get("modes", []) if m.get("freq_hz", 0) < 1000]
        found = [m["freq_hz"] for m in below]
        # the stage's modes against the paper's unwarped (its Tustin d2c reports f_w = (fs/pi) tan(pi f/fs))
        for f, f_paper, axis in zip(P.STAGE_MODES_HZ, P.PAPER_MODES_HZ, P.PAPER_MODE_AXES):
            near = min(found, key=lambda x: abs(x - f)) if found else None
            add(S_STAGE, f"mode near {f:.1f} Hz ({axis}; the paper's {f_paper:.0f} Hz unwarped)", f, near, "Hz",
                lambda v, f=f: _num(v) and abs(v - f) <= P.MODE_REL_TOL * f, f"within {100 * P.MODE_REL_TOL:g} %")
        for m in below:
            add(S_STAGE, f"damping ratio of the {m['freq_hz']:.0f} Hz mode", None, m.get("damping_ratio"), "-",
                *_check("mode_damping"))
        g = modes.get("static_gain_um_per_V")
        if g is not None:
            ref = C.STATIC_GAIN_SCALE_UM_PER_V * C.JACOBIAN_J
            err = float(np.abs(np.array(g) - ref).max() / np.abs(ref).max())
            add(S_STAGE, "static gain vs 3.0 um/V x J (max error / max element)", 0.0, err, "-",
                lambda v: v <= P.STATIC_GAIN_REL_TOL, f"<= {P.STATIC_GAIN_REL_TOL:g}")
        cv = modes.get("constraint_violation_ratio")
        add(S_STAGE, "loop-closure violation at full stroke", None, 100 * cv if _num(cv) else None, "%",
            _num(cv) and cv < P.CLOSURE_VIOLATION_MAX, f"< {100 * P.CLOSURE_VIOLATION_MAX:g} %")
    if ident is None:
        missing(S_IDENT, A.IDENTIFY_JSON)
    else:
        fit = ident.get("fit_percent")
        for i, ax in enumerate(C.AXES):
            for j, act in enumerate(C.ACTUATORS):
                add(S_IDENT, f"fit {act} -> {ax}", float(P.PAPER_FIT_PERCENT[i, j]), _get(fit, i, j), "%",
                    *_check("fit_percent"))
        add(S_IDENT, "total model order", 39, ident.get("total_order"), "states")
    if des is None:
        missing(S_DESIGN, A.DESIGN_JSON)
    else:
        spec = [
            ("gamma", PAPER["gamma"], des.get("gamma"), "-", *_check("gamma")),
            ("controller order", PAPER["order"], des.get("controller_order"), "states", *_check("controller_order")),
            ("peak sigma(S), nominal model", PAPER["S_nom"], des.get("S_peak_nominal"), "-", *_check("S_peak_nominal")),
            ("peak sigma(S), full model", PAPER["S_full"], des.get("S_peak_full"), "-", *_check("S_peak_full")),
            ("S bandwidth (design)", PAPER["bwS"],
             (des.get("exported_controller") or {}).get("parameters", {}).get("predicted_bandwidth_S_hz",
                                                                             des.get("bandwidth_S_hz")),
             "Hz", *_check("bandwidth_S_design_hz")),
            ("T bandwidth (design)", PAPER["bwT"], des.get("bandwidth_T_hz"), "Hz", *_check("bandwidth_T_design_hz")),
        ]
        for label, paper, v, unit, check, band in spec:
            if label == "controller order" and des.get("damping_loop") is not None:
                band += f"; here {des.get('reduced_order')}-state model + damping loop"
            add(S_DESIGN, label, paper, v, unit, check, band)
    if met is None:
        missing(S_LOOP, A.METRICS_JSON)
        return rows
    c1000 = next((c for c in met.get("contouring", [])
                  if round(c.get("speed_um_s", 0)) == PAPER_CONTOUR_SPEED_UM_S), {})
    none = (None, "")
    spec = [
        ("S bandwidth on the stage", PAPER["bwS"], met.get("bandwidth_S_hz"), "Hz", *_check("bandwidth_S_stage_hz")),
        ("T bandwidth on the stage", PAPER["bwT"], met.get("bandwidth_T_hz"), "Hz", *_MEASURED),
        ("2 um step rise time", PAPER["rise"], _get(met, "step_2um", "rise_ms"), "ms", *_MEASURED),
        ("2 um step peak time", PAPER["peak"], _get(met, "step_2um", "peak_ms"), "ms", *none),
        ("2 um step settling (2 %), +X after 1 s", PAPER["settle"], _get(met, "step_2um", "settling_ms"), "ms",
         *_check("settling_ms")),
        ("2 um step overshoot, +X after 1 s", PAPER["over"], _get(met, "step_2um", "overshoot_percent"), "%",
         *_check("overshoot_percent")),
        ("2 um step settling (2 %), worst case", PAPER["settle"], _get(met, "step_2um_worst", "settling_ms"), "ms",
         *none),
        ("2 um step overshoot, worst case", PAPER["over"], _get(met, "step_2um_worst", "overshoot_percent"), "%",
         *none),
        ("resolution sigma, open loop", PAPER["sig_o"], _get(met, "resolution_sigma_nm", "open_loop"), "nm",
         *_check("sigma_open_nm")),
        ("resolution sigma, closed loop", PAPER["sig_c"], _get(met, "resolution_sigma_nm", "closed_loop"), "nm",
         *_check("sigma_closed_nm")),
        ("95.45 % band, open loop", PAPER["s2_o"], _get(met, "resolution_2sigma_nm", "open_loop"), "nm", *none),
        ("95.45 % band, closed loop", PAPER["s2_c"], _get(met, "resolution_2sigma_nm", "closed_loop"), "nm", *none),
        ("99.73 % band, open loop", PAPER["s3_o"], _get(met, "resolution_3sigma_nm", "open_loop"), "nm", *none),
        ("99.73 % band, closed loop", PAPER["s3_c"], _get(met, "resolution_3sigma_nm", "closed_loop"), "nm", *none),
        ("output hysteresis, open loop", PAPER["hyst_o"], _get(met, "hysteresis", "open_loop_percent"), "%",
         *_check("hysteresis_open_percent")),
        ("hysteresis, closed loop (20 um)", PAPER["hyst_c"], _get(met, "hysteresis", "closed_loop_nm"), "nm",
         *_check("hysteresis_closed_nm")),
        ("creep drift over 10 s, open loop", None, _get(met, "creep", "open_loop_drift_nm"), "nm",
         *_check("creep_open_nm")),
        ("creep drift over 10 s, closed loop", 0.0, _get(met, "creep", "closed_loop_drift_nm"), "nm",
         *_check("creep_closed_nm")),
        ("contour error at 1000 um/s, mean", PAPER["contour_mean"], c1000.get("mean_error_nm"), "nm",
         *_check("contour_mean_nm")),
        ("contour error at 1000 um/s, max", PAPER["contour_max"], c1000.get("max_error_nm"), "nm", *_MEASURED),
        ("axis tracking error at 1000 um/s", PAPER["axis_err"], c1000.get("axis_tracking_error_um"), "um", *none),
    ]
    for label, paper, v, unit, check, band in spec:
        add(S_LOOP, label, paper, v, unit, check, band)
    return rows


def _staircase_rows(run: Path):
    """(target nm, plateau nm, within the band) of the 10 nm staircase (Fig. 17), if it ran."""
    plateaus = _get(_load(run, A.METRICS_JSON), "small_steps", "plateau_means_nm") or []
    return [(10.0 * i, p, _num(p) and abs(p - 10.0 * i) <= P.SMALL_STEP_TOL_NM)
            for i, p in enumerate(plateaus) if i]


# Thresholds of the design warnings (engineering limits, not paper figures).
DISCRETIZATION_MAX_REL_ERROR = 0.01        # discrete vs continuous controller below 500 Hz
CONTROLLER_POLE_MAX_RAD_S = 1e6            # a pole faster than this is a numerical artefact at 4 kHz sampling
CLOSED_LOOP_MIN_DAMPING = 0.005            # least closed-loop damping ratio worth a warning


def design_warnings(des: dict) -> list[str]:
    """Warnings computed from ``design.json``'s own fields (empty if the design is clean).

    Parameters
    ----------
    des : dict
        Content of ``design.json``.

    Returns
    -------
    list of str
        One sentence per warning, with the measured value and the limit.
    """
    out = []
    if des.get("discretization_within_1_percent") is False:
        err = des.get("discretization_max_rel_error", des.get("discretization_max_rel_error_below_500hz"))
        band = des.get("discretization_check_band_hz", 500.0)      # the key before the band had its own
        where = des.get("discretization_worst_freq_hz")
        out.append("Controller discretization: the discrete controller differs from the continuous one by "
                   + (f"{100 * err:.1f} %" if _num(err) else "more than 1 %")
                   + (f" (at {where:.0f} Hz)" if _num(where) else "")
                   + (f" below {band:g} Hz" if _num(band) else "")
                   + f" (limit {100 * DISCRETIZATION_MAX_REL_ERROR:g} %).")
    eo = des.get("Eo_max_dB_below_140Hz")
    if _num(eo) and eo > P.PAPER_REDUCTION_ERROR_MAX_DB_BELOW_140HZ:
        out.append(f"Model reduction: the relative reduction error reaches {eo:.1f} dB below 140 Hz "
                   f"(paper: under {P.PAPER_REDUCTION_ERROR_MAX_DB_BELOW_140HZ:g} dB, Fig. 10).")
    fast = des.get("controller_fastest_pole_rad_s")
    if _num(fast) and fast > CONTROLLER_POLE_MAX_RAD_S:
        out.append(f"Controller: a pole at {fast:.3g} rad/s ({fast / (2 * math.pi):.3g} Hz), faster than "
                   f"{CONTROLLER_POLE_MAX_RAD_S:.0e} rad/s and far above the 4 kHz sampling: a numerically stiff "
                   "state of the H-infinity synthesis.")
    for key, model in (("nominal", "design (nominal) model"), ("twin", "linear twin")):
        z, hz = des.get(f"closed_loop_min_damping_{key}"), des.get(f"closed_loop_min_damping_{key}_hz")
        if _num(z) and z < CLOSED_LOOP_MIN_DAMPING:
            out.append(f"Closed loop with the {model}: least damping ratio {z:.4f}"
                       + (f" at {hz:.0f} Hz" if _num(hz) else "") + f" (below {CLOSED_LOOP_MIN_DAMPING:g}); "
                       "the loop rings at that frequency.")
    for key, model in (("nominal", "design model"), ("full", "full identified model"), ("twin", "linear twin"),
                       ("discrete_full", "full model, discrete controller")):
        if des.get(f"stable_{key}") is False:
            out.append(f"Closed loop with the {model} is UNSTABLE.")
    n_unst = des.get("full_model_unstable_poles")
    if _num(n_unst) and n_unst > 0:
        out.append(f"The identified full model has {n_unst:g} unstable pole(s).")
    return out


def _fmt(v):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    if isinstance(v, (int, np.integer)):
        return str(v)
    return f"{v:.4g}"


def _diff(p, s):
    if p is None or s is None or not isinstance(p, (int, float)) or not isinstance(s, (int, float)):
        return ""
    d = s - p
    return f"{d:+.3g}" + (f" ({100 * d / p:+.0f} %)" if p else "")


def _figures(run: Path):
    """(caption, relative path) of every figure of the run, in registry order, then the twin folder's.

    Registered figures come first (:data:`nanosim.pipeline.artifacts.FIGURES`); any other PNG in
    the folder is listed after them under its file name, so nothing the run made is left out.
    """
    out, seen = [], set()
    for prefix, folder in (("", run), ("Linear twin: ", run / A.TWIN_DIR)):
        if not folder.is_dir():
            continue
        for art in A.FIGURES:
            for p in sorted(folder.glob(art.name)):
                rel = p.relative_to(run).as_posix()
                if rel not in seen:
                    seen.add(rel)
                    caption = art.caption + (f", {p.stem}" if art.is_pattern else "")
                    out.append((prefix + caption, rel))
        for p in sorted(folder.rglob("*.png")):
            rel = p.relative_to(run).as_posix()
            in_twin = rel.startswith(f"{A.TWIN_DIR}/")
            if rel in seen or (folder == run and in_twin):
                continue
            seen.add(rel)
            out.append((prefix + p.stem, rel))
    return out


TWIN_KEYS = [
    ("S bandwidth (Hz)", ("bandwidth_S_hz",)), ("T bandwidth (Hz)", ("bandwidth_T_hz",)),
    ("2 um step overshoot (%)", ("step_2um", "overshoot_percent")),
    ("2 um step rise (ms)", ("step_2um", "rise_ms")),
    ("closed-loop sigma (nm)", ("resolution_sigma_nm", "closed_loop")),
    ("open-loop hysteresis (%)", ("hysteresis", "open_loop_percent")),
    ("closed-loop hysteresis (nm)", ("hysteresis", "closed_loop_nm")),
    ("open-loop creep drift (nm)", ("creep", "open_loop_drift_nm")),
    ("closed-loop creep drift (nm)", ("creep", "closed_loop_drift_nm")),
    ("tracking rms, triangle 5 Hz (nm)", ("tracking", 0, "rms_error_nm")),
    ("tracking rms, triangle 40 Hz (nm)", ("tracking", 3, "rms_error_nm")),
    ("contour error at 1000 um/s, mean (nm)", ("contouring", -1, "mean_error_nm")),
]


def _twin_rows(run: Path):
    """(label, MuJoCo value, linear-twin value) for the closed-loop metrics, if a twin run exists."""
    mj, tw = _load(run, A.METRICS_JSON), _load(run / A.TWIN_DIR, A.METRICS_JSON)
    if not tw:
        return []

    return [(label, _get(mj, *keys), _get(tw, *keys)) for label, keys in TWIN_KEYS]


def exported_controller(des: dict) -> tuple[str, int | None]:
    """``(architecture, order)`` of the controller ``controller.npz`` holds, from ``design.json``."""
    e = des.get("exported_controller") or {}
    return (e.get("architecture", des.get("architecture", "mixsyn")),
            e.get("controller_order", des.get("controller_order")))


def run_acceptance_doc(run) -> dict:
    """The exported controller and the controller bench's acceptance
    (:func:`~nanosim.pipeline.scorecard.run_acceptance`) of one run folder.
    """
    from nanosim.pipeline.scorecard import run_acceptance
    run = Path(run)
    arch, order = exported_controller(_load(run, A.DESIGN_JSON))
    return {"controller": arch, "controller_order": order,
            "criteria": run_acceptance(_load_or_none(run, A.METRICS_JSON), _load_or_none(run, A.ROBUSTNESS_JSON))}


def architecture_section(des: dict) -> str | None:
    """One paragraph on the controller structure the Sec. 5 numbers were measured with."""
    if not des:
        return None
    order = des.get("reduced_order")
    dl = des.get("damping_loop")
    zt = des.get("closed_loop_min_damping_twin")
    zt_hz = des.get("closed_loop_min_damping_twin_hz")
    ring = (f" Least-damped closed-loop pole with the linear twin (50 Hz - 1 kHz): zeta = {zt:.4f} at "
            f"{zt_hz:.0f} Hz." if zt is not None and zt_hz is not None else "")
    if exported_controller(des)[0] != "mixsyn":
        return _exported_text(des.get("exported_controller") or {}, des)
    if dl is None:
        text = (f"Controller: the paper's single H-infinity loop (paper weights, {order}-state design model, "
                f"{des.get('controller_order')} states).{ring}")
    else:
        text = (f"Controller: the paper's H-infinity mixed-sensitivity design (same weights Wp, Wu, Wt) on a "
                f"{order}-state design model, around an inner active-damping loop (band-limited velocity "
                f"feedback, +{dl['zeta_added']:g} damping at {dl['mode_hz']:.0f} Hz, low-pass "
                f"{dl['lowpass_hz']:g} Hz): u = K e + Ky y. The paper's single loop leaves the first XY pair "
                f"lightly damped in closed loop; `nanosim pipeline --paper-design` reproduces that set-up."
                f"{ring}")
    return text


def _exported_text(exported: dict, des: dict) -> str:
    """The controller the Sec. 5 numbers were measured with, when it is a bench design, not the H-infinity one."""
    p = exported.get("parameters", {})
    text = (f"Controller: the bench's `{exported.get('architecture')}` design "
            f"({exported.get('controller_order', '?')} states), tuning rule: {exported.get('tuning_rule', 'n/a')}.")
    pf = p.get("reference_prefilter")
    if pf and pf.get("notches"):
        notches = ", ".join(f"{n['freq_hz']:.0f} Hz (zeta {n['zeta_zero']:.3f} -> {n['zeta_pole']:g})"
                            for n in pf["notches"])
        text += (f" Reference prefilter (two degrees of freedom, {pf['prefilter_states']} of the states): notches at "
                 f"{notches}, the closed loop's ringing pairs; the feedback loop, its margins and mu are those of "
                 "the design without it.")
    eq = p.get("reference_lag_equalizer")
    if eq:
        lags = ", ".join(f"{v:.3f}" for v in np.diag(eq["lag_matrix_ms"]))
        text += (f" Lag equalizer ({eq['prefilter_states']} states): the axes' ramp lags on the identified model "
                 f"({lags} ms) all become the slowest's, {eq['common_lag_ms']:.3f} ms, with no cross lag, so a "
                 "straight path stays straight.")
    st = p.get("reference_step_filter")
    if st:
        m = st["piezo_step_model"]
        parts = "; ".join(f"{''.join(f['axes'])}: zeros {f['fz_hz']:.0f} Hz (zeta {f['zeta_z']:.2f}), poles "
                          f"{f['fp_hz']:.0f} Hz (zeta {f['zeta_p']:.2f})" for f in st["filters"])
        text += (f" Step filter ({st['prefilter_states']} states; {parts}): shapes the {PAPER_STEP_UM:g} um step for "
                 f"the piezo it drives, a {m['step_piezo_V']:.1f} V excursion at gains "
                 f"{m['gains'][0]:.3f}-{m['gains'][-1]:.3f} of the identified model's with "
                 f"{100 * m['creep_per_decade']:.1f} % creep per decade; predicted worst settling on that model "
                 f"{st['predicted_settling_ms_worst']:.2f} ms, overshoot at most {st['overshoot_limit_percent']:g} %.")
    if des.get("architecture_note"):
        text += f" {des['architecture_note']}."
    return text


def pass_count(run_dir) -> tuple[int, int]:
    """(rows inside their band, rows with a band) of the run's paper-vs-simulation table.

    The same rows and bands as ``compare_to_paper.py``, so both tools count the same.
    """
    rows = _rows(Path(run_dir))
    return sum(1 for r in rows if r[5] is True), sum(1 for r in rows if r[5] is not None)


def _blocks(run: Path):
    """The report as blocks: ("h", level, text), ("p", text), ("ul", items), ("table", header, rows, marks)."""
    rows = _rows(run)
    met, des = _load(run, A.METRICS_JSON), _load(run, A.DESIGN_JSON)
    timing = _stage_seconds(run)
    n_ok, n_band = pass_count(run)
    warnings = design_warnings(des)
    stairs = _staircase_rows(run)
    out = [("h", 1, "nanosim report"),
           ("p", f"Simulated reproduction of {EM}Robust Control of a Parallel-Kinematic Nanopositioner{EM} "
                 "(J. Dyn. Sys., Meas., Control 130, 2008): MuJoCo stage -> identification -> H-infinity design -> "
                 f"closed-loop experiments. Plant for Sec. 5: {met.get('plant', 'n/a')}. "
                 f"{n_ok} of {n_band} checked quantities are inside their acceptance bands"
                 f"{'; ' + str(len(warnings)) + ' design warning(s), see Warnings' if warnings else ''}.")]
    if timing:
        out.append(("p", "Stage wall times (s): " + ", ".join(f"{k} {v}" for k, v in timing.items())))
    out += _controllers_blocks(run, des)
    if des:
        exported = exported_controller(des)[0]
        if exported != "mixsyn":
            out += [("h", 2, "Warnings"),
                    ("p", f"These concern the H-infinity reference design that design.json describes, not the "
                          f"exported `{exported}` controller (its loop is in \"Controllers\" and \"Robustness\").")]
        else:
            out.append(("h", 2, "Warnings"))
        out += [("ul", warnings) if warnings else
                ("p", "None: discretization error, reduction error below 140 Hz, controller poles, closed-loop "
                      "damping and stability are all within their limits (from design.json).")]
    out += [("h", 2, "Paper vs simulation"),
            ("p", f"{n_ok} of {n_band} rows with a band are inside it (the same rows and bands as "
                  "compare_to_paper.py; a missing file or value counts as outside). Rows without a band are "
                  "shown for comparison; those marked 'measured (no band)' count as inside once measured, as "
                  "compare_to_paper.py counts them, and are not coloured."),
            ("table", ["section", "quantity", "paper", "simulation", "difference", "unit", "band", "ok"],
             [[sec, label, _fmt(p), _fmt(v), _diff(p, v), u, band,
               "" if ok is None else ("counted" if band == _MEASURED[1] and ok else ("yes" if ok else "NO"))]
              for sec, label, p, v, u, ok, band in rows],
             [None if r[6] == _MEASURED[1] and r[5] else r[5] for r in rows])]     # no band: nothing to colour
    if stairs:
        out += [("h", 2, "10 nm staircase (Fig. 17)"),
                ("p", f"{sum(ok for *_, ok in stairs)} of {len(stairs)} plateaus within "
                      f"{P.SMALL_STEP_TOL_NM:g} nm of their target (not counted above)."),
                ("table", ["plateau", "target (nm)", "mean (nm)", "difference", "ok"],
                 [[str(k), _fmt(t), _fmt(v), _diff(t, v), "yes" if ok else "NO"]
                  for k, (t, v, ok) in enumerate(stairs, 1)], [ok for *_, ok in stairs])]
    out += protocol_blocks(met) + noise_budget_blocks(met)
    twin_rows = _twin_rows(run)
    if twin_rows:
        out += [("h", 2, "MuJoCo stage vs linear twin (same experiments, same code path)"),
                ("p", "Both plants have the same DAC, amplifier, piezo hysteresis and creep, gauge and ADC; "
                      "only the mechanics differ (MuJoCo vs the 12-state linear twin)."),
                ("table", ["quantity", "MuJoCo", "linear twin", "difference"],
                 [[lab, _fmt(a), _fmt(b), _diff(b, a)] for lab, a, b in twin_rows], None)]
    out += _robustness_blocks(run)
    out += _compensation_blocks(run)
    out += _scan_blocks(run)
    from nanosim.pipeline.budget import report_blocks as budget_blocks
    out += budget_blocks(run)
    out += _stage_v2_blocks(run)
    out.append(("h", 2, "Figures"))
    shown = {b[2] for b in out if b[0] == "fig"}        # a section's own figure is not repeated
    out += [("fig", title, rel) for title, rel in _figures(run) if rel not in shown]
    return out


def protocol_blocks(met: dict) -> list:
    """The experiment protocol (``loop_protocol``) and the 2 um step of every case (``step_2um_cases``)."""
    proto, cases = met.get("loop_protocol"), met.get("step_2um_cases") or []
    if not proto and not cases:
        return []
    out = [("h", 2, "Experiment protocol and the 2 um steps (Fig. 18)")]
    if proto:
        out.append(("p", f"Every closed-loop record starts from one stated state: the controller at the home "
                         f"reading ({proto.get('controller_start')}); the approach, "
                         f"{proto.get('approach')}, in {_fmt(proto.get('approach_s'))} s; a hold of "
                         f"{_fmt(proto.get('hold_s'))} s at the first reference; then the record. The 2 um steps "
                         "replace the hold by the case's own and step 10 ms into the record, each case on a "
                         "fresh stage. The headline step is +X after the 1 s hold."))
    if cases:
        w = met.get("step_2um_worst") or {}
        out.append(("table", ["step", "hold (s)", "rise (ms)", "peak (ms)", "settling 2 % (ms)", "overshoot (%)"],
                    [[f"{'+' if c.get('sign', 1) > 0 else '-'}{c.get('axis')}", _fmt(c.get("hold_s")),
                      _fmt(c.get("rise_ms")), _fmt(c.get("peak_ms")), _fmt(c.get("settling_ms")),
                      _fmt(c.get("overshoot_percent"))] for c in cases], None))
        if w:
            out.append(("p", f"Worst case: settling {_fmt(w.get('settling_ms'))} ms ({w.get('settling_case')}), "
                             f"overshoot {_fmt(w.get('overshoot_percent'))} % ({w.get('overshoot_case')}); "
                             f"paper: {_fmt(PAPER['settle'])} ms, {_fmt(PAPER['over'])} %."))
    return out


def noise_budget_blocks(met: dict) -> list:
    """The per-source noise budget (``noise_budget``): sigma and share, open and closed loop."""
    b = met.get("noise_budget") or {}
    src = b.get("sources") or {}
    if not src:
        return []
    pct = (lambda v: _fmt(100 * v) if _num(v) else "")
    rows = [[name, _fmt(r.get("open_loop_nm")), pct(r.get("open_loop_share")), _fmt(r.get("sensor_nm")),
             pct(r.get("sensor_share")), _fmt(r.get("table_nm")), pct(r.get("table_share"))]
            for name, r in src.items()]
    ratio = b.get("budget_sum_over_total") or {}
    return [("h", 2, "Noise budget (Fig. 16)"),
            ("p", f"Each source alone (every other source off, the piezo and the loop unchanged), "
                  f"{_fmt(b.get('record_s'))} s records on {b.get('axis', 'X')}; the open-loop record starts "
                  f"{_fmt(b.get('open_loop_rest_s'))} s after the stage came to rest at home, the closed-loop one "
                  f"after the approach and a hold of {_fmt((b.get('closed_loop_protocol') or {}).get('hold_s'))} s. "
                  "Shares are of the sum "
                  f"of variances; the sums over the measured totals are {_fmt(ratio.get('open_loop'))} (open loop), "
                  f"{_fmt(ratio.get('sensor'))} (closed loop, reading) and {_fmt(ratio.get('table'))} (closed loop, "
                  "table). The figure's third row shows each source's PSD."),
            ("table", ["source", "open loop (nm)", "share (%)", "closed loop, reading (nm)", "share (%)",
                       "closed loop, table (nm)", "share (%)"], rows, None)] + _quantizer_blocks(src, ratio)


def _quantizer_blocks(src: dict, ratio: dict) -> list:
    """The quantizers' marginal shares (every other source on), when the budget has them."""
    marg = [(name, r) for name, r in src.items() if _num(r.get("sensor_marginal_nm"))]
    if not marg:
        return []
    parts = [f"{name} {_fmt(r['sensor_marginal_nm'])} nm of the reading and {_fmt(r.get('table_marginal_nm'))} nm "
             f"of the table (the loop without it: {_fmt(r.get('sensor_without_nm'))} nm)" for name, r in marg]
    return [("p", "An undithered quantizer's error depends on the signal it quantizes, so its record alone is not its "
                  "share. Measured with every other source on (the total's variance less the variance without it): "
                  + "; ".join(parts) + ". With these in place of their values alone the sums over the measured "
                  f"totals are {_fmt(ratio.get('sensor_marginal'))} (reading) and "
                  f"{_fmt(ratio.get('table_marginal'))} (table).")]


def _stage_seconds(run: Path) -> dict:
    """The pipeline's stage wall times: ``timings.json`` (or ``pipeline.json`` of a run folder written before it)."""
    from nanosim.pipeline.timings import read_timings
    return (read_timings(run, A.PIPELINE_JSON).get("stage_seconds")
            or _load(run, A.PIPELINE_JSON).get("stage_seconds", {}))


def _controllers_blocks(run: Path, des: dict) -> list:
    """The "Controllers" section: the exported controller, its acceptance on this run, and the bench."""
    from nanosim.design.architectures import BENCH
    from nanosim.pipeline.scorecard import DEFAULT_RULE, format_value
    arch = architecture_section(des)
    has_metrics = (run / A.METRICS_JSON).is_file()
    if not arch and not has_metrics:
        return []
    out = [("h", 2, "Controllers")]
    if arch:
        out.append(("p", arch))
    if has_metrics:
        rows = run_acceptance_doc(run)["criteria"]
        n_ok = sum(1 for r in rows if r["pass"])
        n_meas = sum(1 for r in rows if r["pass"] is not None)
        out += [("p", "Acceptance against the bench specification (nanosim/pipeline/scorecard.py, ACCEPTANCE: the "
                      "paper's measured figures, a multiloop disk margin with the loop's delay and mu over the "
                      f"uncertainty set), this run: {n_ok} of {n_meas} "
                      "measured criteria met. The feedback loop's S bandwidth measured directly (a PRBS at the "
                      "reading) is measured by `nanosim compare` only. Its targets are the paper's measured figures "
                      "(the bench asks a controller to do as well as the paper's, e.g. a contour error below the "
                      "paper's 40 nm); the "
                      "bands of the paper-vs-simulation table and of the Monte Carlo's default spec are one source "
                      "(nanosim.paper.BANDS), the tolerance of the reproduction around those figures (e.g. below "
                      "100 nm), which is wider."),
                ("table", ["criterion", "target", "this run", "met"],
                 [[r["label"], r["criterion"], format_value(r["value"], r["unit"], with_unit=True),
                   "n/a" if r["pass"] is None else ("yes" if r["pass"] else "NO")] for r in rows],
                 [r["pass"] for r in rows])]
    out.append(("p", f"The bench: `nanosim compare --controllers {' '.join(BENCH)} --model {A.MODEL_NPZ} --seeds 0-4 "
                     "--out DIR` designs each architecture from this run's identified model by its stated rule, runs "
                     "it through the Section 5 suite and the robustness analysis on every seed and writes "
                     f"scorecard.md/.html/.json. Default rule: {DEFAULT_RULE}"))
    return out


def _robustness_blocks(run: Path) -> list:
    """The "Robustness" section from ``robustness.json`` (empty without it)."""
    rob = _load(run, A.ROBUSTNESS_JSON)
    if not rob.get("plants"):
        return []
    keys = [("loop_delay_samples", "delay beyond the model [samples]"), ("peak_So", "peak sigma_max(S_o)"),
            ("peak_Si", "peak sigma_max(S_i)"), ("peak_To", "peak sigma_max(T_o)"),
            ("peak_KS", "peak sigma_max(KS) [V/V]"), ("peak_SG", "peak sigma_max(SG) [V/V]"),
            ("dm_input_alpha", "multiloop disk margin, input"), ("dm_output_alpha", "multiloop disk margin, output"),
            ("dm_input_output_alpha", "disk margin, input + output"),
            ("dm_output_phase_margin_deg", "disk phase margin, output [deg]"),
            ("least_damped_visible_zeta", "least damped visible closed-loop pole, zeta"),
            ("least_damped_visible_freq_hz", "  its frequency [Hz]"),
            ("mu_peak", "mixed mu peak over the parametric set (real modes and gains)"),
            ("mu_peak_freq_hz", "  its frequency [Hz]"), ("mu_centre_stable", "  centre loops stable"),
            ("mu_covering_peak", "mu of the unstructured complex covering (conservative)"),
            ("sampled_worst", "worst sampled spectral radius")]
    plants = rob["plants"]
    u = rob.get("uncertainty_set", {})
    return [("h", 2, "Robustness"),
            ("p", "The exported discrete controller on the loop as run, with the linear twin (bench delays and filters "
                  "added) and with the identified model (robustness.json). Uncertainty set: piezo gain per channel "
                  f"{u.get('input_gain_range_factor')} of nominal ({_gain_ranges_on_plants(plants)}), modal "
                  f"frequencies x{u.get('freq_scale_range_factor')}, "
                  f"modal damping x{u.get('damping_scale_range_factor')}, delay +{u.get('extra_delay_samples_range')} "
                  "samples beyond the loop as run. The mixed mu bound treats each mode's frequency and damping and "
                  "each piezo gain as real parameters: below 1 proves stability of every plant of the set; empty "
                  "means a centre loop is unstable. The complex covering (every modal change one complex block) "
                  "is far more conservative; the sampled spectral radius closes the loop at the set's vertices."),
            ("table", ["quantity"] + [plants[k].get("plant", k) for k in plants],
             [[lab] + [_fmt(plants[k].get(key)) for k in plants] for key, lab in keys], None)]


def _gain_ranges_on_plants(plants: dict) -> str:
    """The set's piezo-gain range as each plant's analysis mapped it (robustness.json ``uncertainty_set``)."""
    parts = []
    for k, p in plants.items():
        rng = (p.get("uncertainty_set") or {}).get("input_gain_range_on_plant_factor")
        if rng:
            parts.append(f"{p.get('plant', k)}: x{_fmt(rng[0])}-{_fmt(rng[1])} of its own gain")
    return "; ".join(parts) or "on every plant as given"


def _compensation_blocks(run: Path) -> list:
    """The "Hysteresis compensation" section from ``compensation.json`` (:mod:`nanosim.pipeline.compensation`)."""
    from nanosim.pipeline.compensation import report_blocks
    return report_blocks(run)


def _scan_blocks(run: Path) -> list:
    """The "Scan" section from ``scan.json`` (``nanosim scan --out`` this run, or its ``scan/`` folder)."""
    from nanosim.pipeline.scan import report_blocks
    return report_blocks(run) or report_blocks(run / "scan")


def _stage_v2_blocks(run: Path) -> list:
    """The stage model's validation (fitted or predicted), seeds and ablation tables.

    See :mod:`nanosim.pipeline.predictions`.
    """
    from nanosim.pipeline.predictions import report_blocks
    return report_blocks(run)


def write_report(run_dir) -> tuple[Path, Path]:
    """Write report.md and report.html into ``run_dir`` from its json files and figures.

    Sections: headline with the pass count, controller, design warnings (:func:`design_warnings`),
    paper vs simulation (the rows of :func:`pass_count`), 10 nm staircase, MuJoCo vs linear twin,
    robustness, hysteresis compensation (``compensation.json``), and every figure of the run
    (:data:`nanosim.pipeline.artifacts.FIGURES` first, then any other PNG).
    """
    run = Path(run_dir)
    blocks = _blocks(run)
    return write_text(run / A.REPORT_MD, to_markdown(blocks)), write_text(run / A.REPORT_HTML, to_html(blocks))
