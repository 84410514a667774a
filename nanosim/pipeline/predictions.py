"""Stage v2 validation: what the model was fitted to and what it predicts.

:func:`validation_rows` reads a run folder and returns one row per checked
quantity, each marked ``fitted`` (a parameter was set from it) or
``predicted`` (nothing was set from it). :func:`seed_summary` aggregates the
closed-loop figures of several runs (mean, min, max), and
:func:`report_blocks` renders both, plus ``ablation.json``
(:mod:`nanosim.pipeline.ablation`) and ``paper_design_seeds.json`` when the
folder has them, as report blocks.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from nanosim.paper import (PAPER, PAPER_CONTOUR_SPEED_UM_S, PAPER_CREEP_POLE_RAD_S, PAPER_CREEP_ZERO_OVER_POLE,
                           PAPER_HYSTERESIS_INPUT_PERCENT, PAPER_OPEN_LOOP_TRAVEL_UM, PAPER_REDUCED_ORDER)
from nanosim.pipeline import artifacts as A

__all__ = ["creep_doublets", "operating_point_difference", "validation_rows", "SEED_METRICS", "seed_summary",
           "report_blocks", "is_paper_design"]

# Paper values (Sec. 3-5), all from nanosim.paper, under this table's keys.
_PAPER = {"travel_um": list(PAPER_OPEN_LOOP_TRAVEL_UM), "hyst_out_pct": PAPER["hyst_o"],
          "hyst_in_pct": PAPER_HYSTERESIS_INPUT_PERCENT, "sigma_open_nm": PAPER["sig_o"],
          "creep_pole_rad_s": PAPER_CREEP_POLE_RAD_S, "creep_zero_over_pole": PAPER_CREEP_ZERO_OVER_POLE,
          "settling_ms": PAPER["settle"], "sigma_closed_nm": PAPER["sig_c"], "contour_mean_nm": PAPER["contour_mean"],
          "bandwidth_S_hz": PAPER["bwS"]}
SEED_METRICS = {"settling_ms": ("step_2um", "settling_ms"), "overshoot_percent": ("step_2um", "overshoot_percent"),
                "bandwidth_S_hz": ("bandwidth_S_hz",), "sigma_closed_nm": ("resolution_sigma_nm", "closed_loop"),
                "sigma_closed_table_nm": ("resolution_sigma_table_nm", "closed_loop"),
                "sigma_open_nm": ("resolution_sigma_nm", "open_loop")}


def _get(d, *keys):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _load_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def _state_space(npz):
    z = np.load(npz)
    return (np.asarray(z["A"], float), np.asarray(z["B"], float), np.asarray(z["C"], float),
            np.asarray(z["D"], float))


def _freq_resp(A, B, C, D, f_hz):
    """Continuous response at ``s = j 2 pi f``, one solve per point."""
    from nanosim.design.lti import ss_response
    return ss_response(A, B, C, D, 2j * np.pi * np.asarray(f_hz, float), modal="never")


def creep_doublets(model_npz, max_rad_s: float = 300.0) -> list[dict]:
    """Real poles below ``max_rad_s`` of each input column and the nearest real zero of each output.

    Returns one dict per (column, output): ``pole_rad_s``, ``zero_rad_s``, ``zero_over_pole``
    (the paper's Appendix A: poles 29-33 rad/s, zeros 8-11 % above).
    """
    import control as ct
    A, B, C, D = _state_space(model_npz)
    out = []
    for j in range(B.shape[1]):
        cols = np.flatnonzero(np.abs(B[:, j]) > 0)
        Aj = A[np.ix_(cols, cols)]
        poles = np.linalg.eigvals(Aj)
        real = -np.sort(poles[(np.abs(poles.imag) < 1e-9) & (np.abs(poles) < max_rad_s)].real)[::-1]
        if not real.size:
            continue
        p = float(real.min())
        for i in range(C.shape[0]):
            zs = ct.ss(Aj, B[cols, j:j + 1], C[i:i + 1, cols], D[i:i + 1, j:j + 1]).zeros()
            zr = -zs[(np.abs(zs.imag) < 1e-6) & (zs.real < 0) & (np.abs(zs) < max_rad_s)].real
            if zr.size:
                z = float(zr[np.argmin(np.abs(zr - p))])
                out.append({"column": "ABC"[j], "output": "XYZ"[i], "pole_rad_s": p, "zero_rad_s": z,
                            "zero_over_pole": z / p})
    return out


def operating_point_difference(model0_npz, model80_npz) -> dict:
    """Relative difference of the 0 V and 80 V models (paper Fig. 7): below 5 Hz and at 50-150 Hz.

    ``max sigma(G80 - G0) / max sigma(G0)`` averaged over each band.
    """
    f_lo, f_hi = np.linspace(0.5, 5.0, 10), np.linspace(50.0, 150.0, 11)
    g0, g8 = _state_space(model0_npz), _state_space(model80_npz)

    def rel(f):
        H0, H8 = _freq_resp(*g0, f), _freq_resp(*g8, f)
        return float(np.mean([np.linalg.norm(b - a, 2) / np.linalg.norm(a, 2) for a, b in zip(H0, H8)]))
    return {"below_5hz": rel(f_lo), "at_50_150hz": rel(f_hi)}


def validation_rows(run) -> list[dict]:
    """Rows ``{quantity, paper, simulation, unit, status, note}`` from a run folder's files."""
    run = Path(run)
    met = _load_json(run / A.METRICS_JSON)
    rows = []

    def row(q, paper, sim, unit, status, note=""):
        rows.append({"quantity": q, "paper": paper, "simulation": sim, "unit": unit, "status": status, "note": note})

    trav = _get(met, "hysteresis", "open_loop_travel_um")
    row("open-loop travel, actuator A 0 -> 1.65 V (X, Y, Z)", _PAPER["travel_um"],
        None if trav is None else [round(float(v), 2) for v in trav], "um", "fitted",
        "static gain calibrated to 3.0 um/V x J (X and Z agree with the paper; its Y = 7.1 does not agree with J)")
    row("open-loop hysteresis, output / input", [_PAPER["hyst_out_pct"], _PAPER["hyst_in_pct"]],
        [_get(met, "hysteresis", "open_loop_percent"), _get(met, "hysteresis", "open_loop_input_percent")], "%",
        "fitted", "the thermally activated operators' weight scale fitted to the paper's Fig. 14 loop")
    row("open-loop sigma at rest", _PAPER["sigma_open_nm"], _get(met, "resolution_sigma_nm", "open_loop"), "nm",
        "fitted", "the one noise level fitted: the legs' thermal drift (tools/fit_drift_level.py, 20 stages)")
    m0, m80 = run / A.MODEL_NPZ, run / A.model_at_npz(80.0)
    if m0.is_file() and m80.is_file():
        d = operating_point_difference(m0, m80)
        row("0 V vs 80 V model difference, below 5 Hz / at 50-150 Hz (Fig. 7)", "larger below 5 Hz",
            [round(d["below_5hz"], 3), round(d["at_50_150hz"], 3)], "relative", "predicted",
            "yes" if d["below_5hz"] > d["at_50_150hz"] else "NO: not larger below 5 Hz")
    if m0.is_file():
        dbl = creep_doublets(m0)
        if dbl:
            p = [x["pole_rad_s"] for x in dbl]
            r = [x["zero_over_pole"] for x in dbl]
            row("identified real pole (creep doublet) per column", list(_PAPER["creep_pole_rad_s"]),
                [round(min(p), 1), round(max(p), 1)], "rad/s", "predicted",
                "the operators' logarithmic creep (CREEP_PER_DECADE) seen through the paper's excitation; "
                "no time constant imposed")
            row("its zero / pole ratio", list(_PAPER["creep_zero_over_pole"]), [round(min(r), 3), round(max(r), 3)],
                "", "predicted")
    paper = is_paper_design(_load_json(run / A.DESIGN_JSON))
    who = ("the paper's design (--paper-design): a prediction of the paper's measurement" if paper else
           "this run's controller, not the paper's: a comparison only (run --paper-design for the prediction)")
    for key, (q, unit) in {"settling_ms": ("2 um step settling (2 %)", "ms"),
                           "sigma_closed_nm": ("closed-loop sigma, sensor", "nm"),
                           "bandwidth_S_hz": ("S bandwidth", "Hz")}.items():
        row(q, _PAPER[key], _get(met, *SEED_METRICS[key]), unit, "predicted", who)
    row("closed-loop sigma, true table position", None, _get(met, "resolution_sigma_table_nm", "closed_loop"), "nm",
        "predicted", "not measurable on the bench")
    cont = [c for c in met.get("contouring", []) if c.get("speed_um_s") == PAPER_CONTOUR_SPEED_UM_S]
    row("contour error mean at 1000 um/s", _PAPER["contour_mean_nm"], cont[0]["mean_error_nm"] if cont else None,
        "nm", "predicted", who)
    return rows


def is_paper_design(design: dict) -> bool:
    """Whether ``design.json`` describes the paper's set-up: 10-state model, single loop, no design delay."""
    return (design.get("reduced_order") == PAPER_REDUCED_ORDER and design.get("damping_loop") is None
            and not design.get("design_delay_samples") and design.get("architecture") in (None, "paper", "mixsyn"))


def seed_summary(run_dirs) -> dict:
    """Mean, min and max of the closed-loop figures over several run folders (one per seed)."""
    per = {}
    for d in run_dirs:
        met = _load_json(Path(d) / A.METRICS_JSON)
        vals = {k: _get(met, *path) for k, path in SEED_METRICS.items()}
        cont = [c for c in met.get("contouring", []) if c.get("speed_um_s") == PAPER_CONTOUR_SPEED_UM_S]
        vals["contour_mean_nm_1000"] = cont[0]["mean_error_nm"] if cont else None
        per[str(d)] = vals
    keys = list(SEED_METRICS) + ["contour_mean_nm_1000"]
    stats = {}
    for k in keys:
        v = np.array([p[k] for p in per.values() if p[k] is not None], float)
        if v.size:
            stats[k] = {"mean": float(np.mean(v)), "min": float(np.min(v)), "max": float(np.max(v)), "n": int(v.size)}
    return {"runs": per, "stats": stats}


def _fmt(v) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, (list, tuple)):
        return ", ".join(_fmt(x) for x in v)
    if isinstance(v, float):
        return f"{v:.3g}" if abs(v) < 1e4 else f"{v:.0f}"
    return str(v)


def report_blocks(run) -> list:
    """Report blocks (see :mod:`nanosim.pipeline.report`) for the validation, seeds and ablation tables."""
    run = Path(run)
    rows = validation_rows(run)
    out = [("h", 2, "Stage v2 validation: fitted or predicted"),
           ("p", "Fitted: a model parameter was set from this paper number. Predicted: nothing was set from it."),
           ("table", ["quantity", "paper", "simulation", "unit", "status", "note"],
            [[r["quantity"], _fmt(r["paper"]), _fmt(r["simulation"]), r["unit"], r["status"], r["note"]]
             for r in rows], None)]
    seeds = _load_json(run / A.PAPER_DESIGN_SEEDS_JSON)
    if seeds.get("stats"):
        out += [("h", 2, "The paper's controller on several seeds"),
                ("table", ["quantity", "mean", "min", "max", "seeds"],
                 [[k, _fmt(s["mean"]), _fmt(s["min"]), _fmt(s["max"]), str(s["n"])]
                  for k, s in seeds["stats"].items()], None)]
    abl = _load_json(run / A.ABLATION_JSON)
    if abl.get("rows"):
        t = abl.get("targets", {})
        out += [("h", 2, "Ablation of the paper's controller"),
                ("p", f"Mechanics: {abl.get('mechanics')}; seed {abl.get('seed')}; "
                      + ("each row identified and designed anew with the paper's procedure."
                         if abl.get("redesign") else "the controller designed on the all-on stage throughout.")),
                ("table", ["row", "change", "settling (ms)", "sigma sensor (nm)", "sigma table (nm)",
                           "contour at 1000 um/s (nm)", "S bandwidth (Hz)"],
                 [["paper", "", _fmt(t.get("settling_ms")), _fmt(t.get("sigma_closed_nm")), "",
                   _fmt(t.get("contour_mean_nm_1000")), _fmt(t.get("bandwidth_S_hz"))]]
                 + [[r["name"], r["change"], _fmt(r["settling_ms"]), _fmt(r["sigma_closed_nm"]),
                     _fmt(r["sigma_closed_table_nm"]), _fmt(r["contour_mean_nm_1000"]), _fmt(r["bandwidth_S_hz"])]
                    for r in abl["rows"]], None)]
    return out
