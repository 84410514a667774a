"""report.md and report.html: every figure and the paper-vs-simulation table of a run folder."""
from __future__ import annotations

import html
import json
import math
from pathlib import Path

import numpy as np

from nanosim import constants as C
from nanosim.fileio import write_text
from nanosim import paper as P
from nanosim.paper import PAPER
from nanosim.pipeline import artifacts as A

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


def _band(key: str):
    """(check, text) of the acceptance band ``key`` of :data:`nanosim.paper.BANDS`."""
    return B[key].ok, B[key].text


def _rows(run: Path):
    modes, ident, des, met = (_load(run, n) for n in (A.MODES_JSON, A.IDENTIFY_JSON, A.DESIGN_JSON, A.METRICS_JSON))
    rows = []

    def add(section, label, paper, sim, unit, ok=None, band=""):
        rows.append((section, label, paper, sim, unit, ok, band))

    found = [m["freq_hz"] for m in modes.get("modes", [])]
    for f, axis in zip(P.PAPER_MODES_HZ, P.PAPER_MODE_AXES):
        near = min(found, key=lambda x: abs(x - f)) if found else None
        add("Stage model (Sec. 3)", f"mode near {f:.0f} Hz ({axis})", f, near, "Hz",
            None if near is None else abs(near - f) <= P.MODE_REL_TOL * f, f"within {100 * P.MODE_REL_TOL:g} %")
    g = modes.get("static_gain_um_per_V")
    if g is not None:
        ref = C.STATIC_GAIN_SCALE_UM_PER_V * C.JACOBIAN_J
        err = float(np.abs(np.array(g) - ref).max() / np.abs(ref).max())
        add("Stage model (Sec. 3)", "static gain vs 3.0 um/V x J (max error / max element)", 0.0, err, "-",
            err <= P.STATIC_GAIN_REL_TOL, f"<= {P.STATIC_GAIN_REL_TOL:g}")
    cv = modes.get("constraint_violation_ratio")
    add("Stage model (Sec. 3)", "loop-closure violation at full stroke", None, None if cv is None else 100 * cv, "%",
        None if cv is None else cv < P.CLOSURE_VIOLATION_MAX, f"< {100 * P.CLOSURE_VIOLATION_MAX:g} %")
    fit = ident.get("fit_percent")
    for i, ax in enumerate(C.AXES):
        for j, act in enumerate(C.ACTUATORS):
            v = _get(fit, i, j)
            add("Identification (Table 1)", f"fit {act} -> {ax}", float(P.PAPER_FIT_PERCENT[i, j]), v, "%",
                None if v is None else B["fit_percent"].ok(v), B["fit_percent"].text)
    add("Identification (Table 1)", "total model order", 39, ident.get("total_order"), "states", None, "")
    spec = [
        ("gamma", PAPER["gamma"], des.get("gamma"), "-", B["gamma"].ok, B["gamma"].text),
        ("controller order", PAPER["order"], des.get("controller_order"), "states",
         (lambda v: v == 19) if des.get("damping_loop") is None else None,
         "= 19" if des.get("damping_loop") is None else "(14-state model + damping loop)"),
        ("peak sigma(S), nominal model", PAPER["S_nom"], des.get("S_peak_nominal"), "-", *_band("S_peak_nominal")),
        ("peak sigma(S), full model", PAPER["S_full"], des.get("S_peak_full"), "-", *_band("S_peak_full")),
        ("S bandwidth (design)", PAPER["bwS"], des.get("bandwidth_S_hz"), "Hz", *_band("bandwidth_S_design_hz")),
        ("T bandwidth (design)", PAPER["bwT"], des.get("bandwidth_T_hz"), "Hz", *_band("bandwidth_T_design_hz")),
    ]
    for label, p, v, u, ok, band in spec:
        add("H-infinity design (Sec. 4)", label, p, v, u, None if (v is None or ok is None) else ok(v), band)
    c1000 = next((c for c in met.get("contouring", []) if round(c.get("speed_um_s", 0)) == 1000), {})
    spec = [
        ("S bandwidth on the stage", PAPER["bwS"], met.get("bandwidth_S_hz"), "Hz", *_band("bandwidth_S_stage_hz")),
        ("T bandwidth on the stage", PAPER["bwT"], met.get("bandwidth_T_hz"), "Hz", None, ""),
        ("2 um step rise time", PAPER["rise"], _get(met, "step_2um", "rise_ms"), "ms", None, ""),
        ("2 um step peak time", PAPER["peak"], _get(met, "step_2um", "peak_ms"), "ms", None, ""),
        ("2 um step settling (2 %)", PAPER["settle"], _get(met, "step_2um", "settling_ms"), "ms",
         *_band("settling_ms")),
        ("2 um step overshoot", PAPER["over"], _get(met, "step_2um", "overshoot_percent"), "%",
         *_band("overshoot_percent")),
        ("resolution sigma, open loop", PAPER["sig_o"], _get(met, "resolution_sigma_nm", "open_loop"), "nm",
         *_band("sigma_open_nm")),
        ("resolution sigma, closed loop", PAPER["sig_c"], _get(met, "resolution_sigma_nm", "closed_loop"), "nm",
         *_band("sigma_closed_nm")),
        ("95.45 % band, open loop", PAPER["s2_o"], _get(met, "resolution_2sigma_nm", "open_loop"), "nm", None, ""),
        ("95.45 % band, closed loop", PAPER["s2_c"], _get(met, "resolution_2sigma_nm", "closed_loop"), "nm", None, ""),
        ("99.73 % band, open loop", PAPER["s3_o"], _get(met, "resolution_3sigma_nm", "open_loop"), "nm", None, ""),
        ("99.73 % band, closed loop", PAPER["s3_c"], _get(met, "resolution_3sigma_nm", "closed_loop"), "nm", None, ""),
        ("output hysteresis, open loop", PAPER["hyst_o"], _get(met, "hysteresis", "open_loop_percent"), "%",
         *_band("hysteresis_open_percent")),
        ("hysteresis, closed loop (20 um)", PAPER["hyst_c"], _get(met, "hysteresis", "closed_loop_nm"), "nm",
         *_band("hysteresis_closed_nm")),
        ("creep drift over 10 s, open loop", None, _get(met, "creep", "open_loop_drift_nm"), "nm",
         *_band("creep_open_nm")),
        ("creep drift over 10 s, closed loop", 0.0, _get(met, "creep", "closed_loop_drift_nm"), "nm",
         *_band("creep_closed_nm")),
        ("contour error at 1000 um/s, mean", PAPER["contour_mean"], c1000.get("mean_error_nm"), "nm",
         *_band("contour_mean_nm")),
        ("contour error at 1000 um/s, max", PAPER["contour_max"], c1000.get("max_error_nm"), "nm", None, ""),
        ("axis tracking error at 1000 um/s", PAPER["axis_err"], c1000.get("axis_tracking_error_um"), "um", None, ""),
    ]
    for label, p, v, u, ok, band in spec:
        add("Closed loop on the MuJoCo stage (Sec. 5)", label, p, v, u,
            None if (v is None or ok is None) else ok(v), band)
    for i, p in enumerate(_get(met, "small_steps", "plateau_means_nm") or []):
        t = 10.0 * i
        if i:
            add("Closed loop on the MuJoCo stage (Sec. 5)", f"10 nm staircase, plateau {i}", t, p, "nm",
                abs(p - t) <= P.SMALL_STEP_TOL_NM, f"within {P.SMALL_STEP_TOL_NM:g} nm")
    return rows


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


def _architecture(des: dict) -> list[str]:
    """One paragraph on the controller structure the Sec. 5 numbers were measured with."""
    if not des:
        return []
    order = des.get("reduced_order")
    dl = des.get("damping_loop")
    zt = des.get("closed_loop_min_damping_twin")
    zt_hz = des.get("closed_loop_min_damping_twin_hz")
    ring = (f" Least-damped closed-loop pole with the linear twin (50 Hz - 1 kHz): zeta = {zt:.4f} at "
            f"{zt_hz:.0f} Hz." if zt is not None and zt_hz is not None else "")
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
    return ["## Controller", "", text, ""]


def pass_count(run_dir) -> tuple[int, int]:
    """(rows inside their band, rows with a band) of the run's paper-vs-simulation table."""
    rows = _rows(Path(run_dir))
    return sum(1 for r in rows if r[5] is True), sum(1 for r in rows if r[5] is not None)


def write_report(run_dir) -> tuple[Path, Path]:
    """Write report.md and report.html into ``run_dir`` from its json files and figures."""
    run = Path(run_dir)
    rows = _rows(run)
    timing = _load(run, A.PIPELINE_JSON).get("stage_seconds", {})
    met = _load(run, A.METRICS_JSON)
    n_ok = sum(1 for r in rows if r[5] is True)
    n_band = sum(1 for r in rows if r[5] is not None)
    paper_title = "Robust Control of a Parallel-Kinematic Nanopositioner"
    rest = ("(J. Dyn. Sys., Meas., Control 130, 2008): MuJoCo stage -> identification -> H-infinity design -> "
            f"closed-loop experiments. Plant for Sec. 5: {met.get('plant', 'n/a')}. "
            f"{n_ok} of {n_band} checked quantities are inside their acceptance bands.")
    md = ["# nanosim report", "", f"Simulated reproduction of *{paper_title}* {rest}", ""]
    if timing:
        md += ["Stage wall times (s): " + ", ".join(f"{k} {v}" for k, v in timing.items()), ""]
    md += _architecture(_load(run, A.DESIGN_JSON))
    md += ["## Paper vs simulation", "", "| section | quantity | paper | simulation | difference | unit | band | ok |",
           "|---|---|---|---|---|---|---|---|"]
    for sec, label, p, s, u, ok, band in rows:
        mark = "" if ok is None else ("yes" if ok else "**NO**")
        md.append(f"| {sec} | {label} | {_fmt(p)} | {_fmt(s)} | {_diff(p, s)} | {u} | {band} | {mark} |")
    twin_rows = _twin_rows(run)
    if twin_rows:
        md += ["", "## MuJoCo stage vs linear twin (same experiments, same code path)", "",
               "Both plants have the same DAC, amplifier, piezo hysteresis and creep, gauge and ADC; "
               "only the mechanics differ (MuJoCo vs the 12-state linear twin).", "",
               "| quantity | MuJoCo | linear twin | difference |", "|---|---|---|---|"]
        md += [f"| {lab} | {_fmt(a)} | {_fmt(b)} | {_diff(b, a)} |" for lab, a, b in twin_rows]
    md += ["", "## Figures", ""]
    figs = _figures(run)
    for title, rel in figs:
        md += [f"### {title}", "", f"![{title}]({rel})", ""]
    md_path = write_text(run / A.REPORT_MD, "\n".join(md) + "\n")
    h = ["<!doctype html><html><head><meta charset='utf-8'><title>nanosim report</title>",
         "<style>body{font-family:sans-serif;max-width:1200px;margin:auto;padding:1em}"
         "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;padding:3px 6px}"
         "tr.no{background:#fde2e2}tr.yes{background:#e6f4e6}img{max-width:100%}</style></head><body>",
         "<h1>nanosim report</h1>",
         f"<p>Simulated reproduction of <em>{html.escape(paper_title)}</em> {html.escape(rest)}</p>"]
    if timing:
        h.append("<p>Stage wall times (s): " + html.escape(", ".join(f"{k} {v}" for k, v in timing.items())) + "</p>")
    h.append("<h2>Paper vs simulation</h2><table><tr><th>section</th><th>quantity</th><th>paper</th>"
             "<th>simulation</th><th>difference</th><th>unit</th><th>band</th><th>ok</th></tr>")
    for sec, label, p, s, u, ok, band in rows:
        cls = "" if ok is None else (" class='yes'" if ok else " class='no'")
        cells = [sec, label, _fmt(p), _fmt(s), _diff(p, s), u, band, "" if ok is None else ("yes" if ok else "NO")]
        h.append(f"<tr{cls}>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in cells) + "</tr>")
    h.append("</table>")
    if twin_rows:
        h.append("<h2>MuJoCo stage vs linear twin (same experiments, same code path)</h2><table>"
                 "<tr><th>quantity</th><th>MuJoCo</th><th>linear twin</th><th>difference</th></tr>")
        for lab, a, b in twin_rows:
            h.append("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in (lab, _fmt(a), _fmt(b), _diff(b, a)))
                     + "</tr>")
        h.append("</table>")
    h.append("<h2>Figures</h2>")
    for title, rel in figs:
        h.append(f"<h3>{html.escape(title)}</h3><img src='{html.escape(rel)}' alt='{html.escape(title)}'>")
    h.append("</body></html>")
    html_path = write_text(run / A.REPORT_HTML, "\n".join(h) + "\n")
    return md_path, html_path
