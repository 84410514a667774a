"""The controller scorecard: metrics, acceptance against the bench specification, the default rule, and its files.

``scorecard.json`` holds, per controller, every seed's metrics, their mean, spread
(standard deviation), minimum, maximum and worst case, the acceptance verdict per
criterion (on the worst case over the seeds) and the robustness figures;
``scorecard.md`` and ``scorecard.html`` show the same as a table.

The bench specification is :data:`ACCEPTANCE`: the metrics of :data:`METRICS` that carry a target, the
paper's measured figures (:mod:`nanosim.paper`), a multiloop disk margin of at least
:data:`~nanosim.design.robustness.DISK_MARGIN_TARGET` with the loop's delay, and mu < 1 over the
stage's uncertainty set.

The default rule
---------------------------------------------
Among the bench designs, the default is the one that meets the most acceptance
criteria on every seed (worst case over the seeds); a tie goes to the design that
is robustly stable over the uncertainty set (mu < 1), then to the larger worst-case
multiloop disk margin, then to the higher worst-case feedback S bandwidth.
"""
from __future__ import annotations

import html
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nanosim.fileio import write_json, write_text
from nanosim.design.robustness import DISK_MARGIN_TARGET
from nanosim.paper import PAPER, PAPER_CONTOUR_SPEED_UM_S
from nanosim.pipeline import artifacts as A

__all__ = ["Metric", "METRICS", "ACCEPTANCE", "DEFAULT_RULE", "flatten_metrics", "robustness_metrics", "scorecard",
           "choose_default", "write_scorecard", "markdown_table", "run_acceptance", "format_value", "worst_of",
           "PARAMETER_UNITS", "scorecard_units"]


@dataclass(frozen=True)
class Metric:
    """One scorecard row.

    Attributes
    ----------
    key : str
        Key in the flattened metrics (units in the name).
    label : str
    unit : str
    higher_is_better : bool
    target : float or None
        The acceptance level of the bench specification (None: reported only).
    strict : bool
        The target is a strict bound (``mu < 1``).
    per_seed : bool
        False for the seed-independent robustness figures.
    """

    key: str
    label: str
    unit: str
    higher_is_better: bool
    target: float | None = None
    strict: bool = False
    per_seed: bool = True

    def passes(self, value) -> bool | None:
        """Acceptance of ``value`` (None without a target or a value)."""
        if self.target is None or value is None or math.isnan(value):
            return None
        if self.higher_is_better:
            return value > self.target if self.strict else value >= self.target
        return value < self.target if self.strict else value <= self.target

    def worst(self, values) -> float | None:
        """The worst of ``values`` (the lowest if higher is better); None entries are skipped, None if none is left."""
        v = [float(x) for x in values if x is not None]
        if not v:
            return None
        return min(v) if self.higher_is_better else max(v)

    @property
    def criterion(self) -> str:
        """``>= 32 Hz`` style text."""
        if self.target is None:
            return ""
        op = (">" if self.strict else ">=") if self.higher_is_better else ("<" if self.strict else "<=")
        return f"{op} {self.target:g}" + (f" {self.unit}" if self.unit else "")


METRICS: tuple[Metric, ...] = (
    # the bandwidth experiment's S (I - T, or the feedback loop's by the indirect method for two degrees of
    # freedom) and nanosim compare's direct measurement of the feedback loop's S (nanosim.pipeline.compare)
    Metric("bandwidth_S_hz", "S bandwidth from the reference record (measured)", "Hz", True, PAPER["bwS"]),
    Metric("bandwidth_S_feedback_hz", "S bandwidth of the feedback loop (measured, PRBS at the reading)", "Hz",
           True, PAPER["bwS"]),
    Metric("bandwidth_T_hz", "T bandwidth (measured)", "Hz", True),
    Metric("step_settling_ms", "2 um step, 2 % settling", "ms", False, PAPER["settle"]),
    Metric("step_overshoot_percent", "2 um step, overshoot", "%", False, 10.0),
    Metric("step_rise_ms", "2 um step, rise 10-90 %", "ms", False),
    Metric("sigma_table_nm", "closed-loop sigma, true table X", "nm", False, PAPER["sig_c"]),
    Metric("sigma_sensor_nm", "closed-loop sigma, sensor X", "nm", False),
    Metric("contour_mean_1000_nm", "contour error, mean at 1000 um/s", "nm", False, PAPER["contour_mean"]),
    Metric("contour_max_1000_nm", "contour error, max at 1000 um/s", "nm", False),
    Metric("tracking_rms_sine_20hz_nm", "tracking error rms, 20 Hz sine", "nm", False),
    Metric("small_steps_max_error_nm", "10 nm staircase, largest plateau error", "nm", False),
    Metric("hysteresis_closed_loop_nm", "closed-loop hysteresis", "nm", False),
    Metric("creep_closed_loop_drift_nm", "closed-loop creep drift", "nm", False),
    Metric("multiloop_disk_margin", "multiloop disk margin alpha (identified model = the loop as run)", "", True,
           DISK_MARGIN_TARGET, per_seed=False),
    Metric("disk_margin_input_output", "disk margin alpha, inputs and outputs at once", "", True, per_seed=False),
    Metric("multiloop_disk_margin_twin", "multiloop disk margin alpha (linear twin, as the loop runs it)", "", True,
           per_seed=False),
    Metric("mu_peak", "mu upper bound over the uncertainty set", "", False, 1.0, strict=True, per_seed=False),
    Metric("peak_So", "peak sigma(S_o), identified model", "", False, per_seed=False),
    Metric("bandwidth_So_model_hz", "S_o bandwidth, identified model", "Hz", True, per_seed=False),
)
ACCEPTANCE: tuple[str, ...] = tuple(m.key for m in METRICS if m.target is not None)
DEFAULT_RULE = ("Among the bench designs, the default is the one that meets the most of the bench specification's "
                "acceptance criteria on every seed (worst case over the seeds; the S bandwidth counts twice, reference "
                "to error and the feedback loop's); a tie goes to the design that is robustly stable over the "
                "uncertainty set (mu < 1), then to the larger worst-case multiloop disk margin, then to the higher "
                "worst-case feedback S bandwidth.")
_BY_KEY = {m.key: m for m in METRICS}
_ALPHA = "disk-margin alpha, dimensionless (as robustness.json's *_alpha)"
# the metrics without a unit (Metric.unit ""): what their numbers are
_UNITLESS = {"multiloop_disk_margin": _ALPHA, "disk_margin_input_output": _ALPHA,
             "multiloop_disk_margin_twin": _ALPHA,
             "mu_peak": "structured singular value, dimensionless (robustly stable if < 1)",
             "peak_So": "largest singular value of S_o, dimensionless, absolute (not dB)"}
# scorecard.json's "units" for the designs' own parameters (controllers/<name>/parameters)
PARAMETER_UNITS = {
    "*_hz, *_band_hz": "Hz (integral_gain_hz: the integrator's gain as a frequency)",
    "*_V": "volts (controller V)", "*_nm": "nanometres", "*_s": "seconds", "*_samples": "samples of the control "
    "period", "*order*": "states",
    "gamma*": "dimensionless, absolute (H-infinity norm bound, not dB)",
    "*disk_margin*, predicted_disk_margin/*, tried/*/multiloop_disk_margin": _ALPHA,
    "*mu_peak": "structured singular value, dimensionless", "*zeta*": "damping ratio",
    "*spectral_radius*": "|z| of the discrete closed-loop poles",
    "*_rel_error": "fraction (0.01 = 1 %)",
    "damped_peak_gain, open_loop_peak_gain": "sigma_max of G(z) G(1)^-1 with and without the PPF damping loop, "
                                            "largest over peak_band_hz: a factor of the static gain, absolute "
                                            "(not dB)",
    "other numbers": "dimensionless factors (gains, ratios, weights, scales)",
}


def scorecard_units() -> dict:
    """``scorecard.json``'s ``units``: every metric's (from :data:`METRICS`) and the parameters'."""
    return {"metrics": {m.key: m.unit or _UNITLESS.get(m.key, "dimensionless") for m in METRICS},
            "metrics_where": "controllers/<name>/seeds/<seed>/<key>, controllers/<name>/summary/<key>/{mean, std, "
                             "min, max, worst} (n: a count), controllers/<name>/robustness/<key>, "
                             "controllers/<name>/acceptance/<key>/worst",
            "robustness/sampled_all_stable, sampled_parameter_set_stable": "true if every sampled member of the "
                                                                          "uncertainty set gives a stable loop",
            "parameters": dict(PARAMETER_UNITS)}


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else (math.inf if x > 0 else -math.inf)


def flatten_metrics(m: dict) -> dict:
    """The per-seed scorecard values from one ``metrics.json`` (missing experiments give None)."""
    out: dict = {k.key: None for k in METRICS if k.per_seed}
    out["bandwidth_S_hz"] = _num(m.get("bandwidth_S_hz"))
    out["bandwidth_S_feedback_hz"] = _num(m.get("bandwidth_S_feedback_hz"))
    bt = _num(m.get("bandwidth_T_hz"))
    out["bandwidth_T_hz"] = bt if bt is not None and math.isfinite(bt) and bt >= 0 else None   # no -3 dB crossing
    step = m.get("step_2um") or {}
    if step:
        settle = step.get("settling_ms")
        out["step_settling_ms"] = math.inf if settle is None else _num(settle)
        out["step_overshoot_percent"] = _num(step.get("overshoot_percent"))
        out["step_rise_ms"] = _num(step.get("rise_ms"))
    table = m.get("resolution_sigma_table_nm") or {}
    out["sigma_table_nm"] = _num(table.get("closed_loop")) if table else None
    sensor = m.get("resolution_sigma_nm") or {}
    out["sigma_sensor_nm"] = _num(sensor.get("closed_loop")) if sensor else None
    for c in m.get("contouring") or []:
        if abs(c.get("speed_um_s", 0) - PAPER_CONTOUR_SPEED_UM_S) < 1e-6:
            out["contour_mean_1000_nm"] = _num(c.get("mean_error_nm"))
            out["contour_max_1000_nm"] = _num(c.get("max_error_nm"))
    for c in m.get("tracking") or []:
        if c.get("waveform") == "sine" and abs(c.get("freq_hz", 0) - 20.0) < 1e-6:
            out["tracking_rms_sine_20hz_nm"] = _num(c.get("rms_error_nm"))
    ss = m.get("small_steps") or {}
    if ss.get("plateau_means_nm") is not None and ss.get("targets_nm") is not None:
        out["small_steps_max_error_nm"] = float(np.max(np.abs(np.subtract(ss["plateau_means_nm"],
                                                                           ss["targets_nm"]))))
    hy = m.get("hysteresis") or {}
    out["hysteresis_closed_loop_nm"] = _num(hy.get("closed_loop_nm")) if hy else None
    cr = m.get("creep") or {}
    out["creep_closed_loop_drift_nm"] = _num(cr.get("closed_loop_drift_nm")) if cr else None
    return out


def robustness_metrics(doc: dict | None, bandwidth_So_model_hz: float | None = None) -> dict:
    """The seed-independent scorecard values from ``robustness.json`` (None for a controller object)."""
    out = {k.key: None for k in METRICS if not k.per_seed}
    if not doc:
        return out
    ident = doc.get("plants", {}).get("identified", {})
    twin = doc.get("plants", {}).get("twin", {})

    def ml(p):
        vals = [p.get("dm_input_alpha"), p.get("dm_output_alpha")]
        vals = [v for v in vals if v is not None]
        return min(vals) if vals else None
    out["multiloop_disk_margin"] = ml(ident)
    out["disk_margin_input_output"] = ident.get("disk_margin_alpha")
    out["multiloop_disk_margin_twin"] = ml(twin) if twin else None
    # mixed mu; null with an unstable centre loop: a member of the set is unstable, mu = inf
    out["mu_peak"] = math.inf if ident.get("mu_centre_stable") is False else ident.get("mu_peak")
    out["peak_So"] = ident.get("peak_So")
    out["bandwidth_So_model_hz"] = _num(bandwidth_So_model_hz)
    out["sampled_all_stable"] = ident.get("sampled_all_stable")
    return out


def run_acceptance(metrics_doc: dict | None, robustness_doc: dict | None) -> list[dict]:
    """The acceptance criteria (:data:`ACCEPTANCE`) of one run folder's ``metrics.json`` and ``robustness.json``.

    Returns
    -------
    list of dict
        Per criterion: ``key``, ``label``, ``unit``, ``criterion`` (text), ``higher_is_better``, ``value``
        (None when the run did not measure it, e.g. the feedback-loop S bandwidth outside ``nanosim
        compare``) and ``pass`` (True, False or None).
    """
    vals = {**flatten_metrics(metrics_doc or {}), **robustness_metrics(robustness_doc)}
    out = []
    for key in ACCEPTANCE:
        m = _BY_KEY[key]
        v = vals.get(key)
        out.append({"key": key, "label": m.label, "unit": m.unit, "criterion": m.criterion,
                    "higher_is_better": m.higher_is_better, "value": v, "pass": m.passes(v) if v is not None else None})
    return out


def worst_of(key: str, values) -> float | None:
    """The worst of ``values`` for the scorecard metric ``key`` (:meth:`Metric.worst`)."""
    return _BY_KEY[key].worst(values)


def format_value(v, unit: str = "", with_unit: bool = False) -> str:
    """A scorecard number as text: ``n/a``, ``inf`` (``not settled`` for a time in ms), else 3 significant digits;
    ``with_unit`` appends ``unit`` to a number.
    """
    txt = _fmt(v, unit)
    return f"{txt} {unit}" if with_unit and unit and v is not None and math.isfinite(v) else txt


def _stats(values: list, metric: Metric) -> dict:
    v = [x for x in values if x is not None]
    if not v:
        return {"mean": None, "std": None, "min": None, "max": None, "worst": None, "n": 0}
    a = np.array(v, float)
    with np.errstate(invalid="ignore"):
        mean = float(a.mean())
        std = float(a.std()) if len(a) > 1 else 0.0
    return {"mean": _num(mean), "std": _num(std) if math.isfinite(std) else None, "min": float(a.min()),
            "max": float(a.max()), "worst": metric.worst(v), "n": len(v)}


def scorecard(specs, per_seed: dict, robustness: dict, config, *, model_path=None, So_bandwidths=None) -> dict:
    """The scorecard document (``scorecard.json``).

    Parameters
    ----------
    specs : list of ControllerSpec
    per_seed : dict
        ``{name: {seed: metrics.json content}}``.
    robustness : dict
        ``{name: robustness.json content}`` (linear controllers).
    config : CompareConfig
    model_path : path or None
    So_bandwidths : dict or None
        ``{name: S_o bandwidth of the identified model [Hz]}``.
    """
    from nanosim.pipeline.characterize import plant_description

    So_bandwidths = So_bandwidths or {}
    ctrls = {}
    for spec in specs:
        seeds = per_seed.get(spec.name, {})
        flat = {int(s): flatten_metrics(m) for s, m in seeds.items()}
        rob = robustness_metrics(robustness.get(spec.name), So_bandwidths.get(spec.name))
        summary, acceptance = {}, {}
        for met in METRICS:
            vals = [f[met.key] for f in flat.values()] if met.per_seed else [rob.get(met.key)]
            st = _stats(vals, met)
            summary[met.key] = st
            if met.target is not None:
                acceptance[met.key] = {"criterion": met.criterion, "worst": st["worst"],
                                       "pass": met.passes(st["worst"]) if st["worst"] is not None else None}
        n_pass = sum(1 for a in acceptance.values() if a["pass"])
        not_run = [k for k, a in acceptance.items() if a["pass"] is None]      # --only, --no-robustness, objects
        ctrls[spec.name] = {
            "source": spec.source, "linear": spec.is_lti,
            "tuning_rule": spec.design.tuning_rule if spec.design is not None else None,
            "parameters": spec.design.parameters if spec.design is not None else None,
            "seeds": {str(s): v for s, v in flat.items()}, "robustness": rob, "summary": summary,
            "acceptance": acceptance, "acceptance_met": n_pass, "acceptance_total": len(acceptance) - len(not_run),
            "acceptance_not_measured": not_run,
            "sampled_parameter_set_stable": rob.get("sampled_all_stable"),
        }
    doc = {"controllers": ctrls, "seeds": list(config.seeds),
           "plant": plant_description(config.twin),
           "experiments": list(config.only) if config.only else "all registered",
           "model": None if model_path is None else str(model_path),
           "metrics": [{"key": m.key, "label": m.label, "unit": m.unit, "higher_is_better": m.higher_is_better,
                        "criterion": m.criterion, "per_seed": m.per_seed} for m in METRICS],
           "acceptance": {k: _BY_KEY[k].criterion for k in ACCEPTANCE}, "default_rule": DEFAULT_RULE}
    name, why = choose_default(doc)
    doc["default"] = name
    doc["default_reason"] = why
    doc["units"] = scorecard_units()
    return doc


def choose_default(doc: dict) -> tuple[str | None, str]:
    """The default by :data:`DEFAULT_RULE` among the bench designs of ``doc``; ``(name, reason)``."""
    cands = [(n, c) for n, c in doc["controllers"].items() if c["source"] == "bench"]
    if not cands:
        return None, "no bench design in this comparison"

    def w(c, key):
        v = c["summary"][key]["worst"]
        return -math.inf if v is None else v
    def robust(c):                                  # the mu criterion's own verdict (mu < 1 over the set)
        return bool(c["acceptance"].get("mu_peak", {}).get("pass"))
    key = lambda nc: (nc[1]["acceptance_met"], robust(nc[1]), w(nc[1], "multiloop_disk_margin"),  # noqa: E731
                      w(nc[1], "bandwidth_S_feedback_hz"))
    best = max(cands, key=key)
    c = best[1]
    failed = [k for k, a in c["acceptance"].items() if a["pass"] is False]
    unmeasured = [k for k, a in c["acceptance"].items() if a["pass"] is None]
    why = (f"meets {c['acceptance_met']} of {c['acceptance_total']} measured criteria on every seed"
           + (f" (not: {', '.join(failed)})" if failed else " (all)")
           + (f"; not measured in this comparison: {', '.join(unmeasured)}" if unmeasured else ""))
    return best[0], why


def _fmt(v, unit=""):
    if v is None:
        return "n/a"
    if math.isinf(v):
        return "not settled" if unit == "ms" else ("inf" if v > 0 else "-inf")
    a = abs(v)
    s = f"{v:.3g}" if a < 10 else (f"{v:.1f}" if a < 1000 else f"{v:.0f}")
    return s


def _cell(c: dict, met: Metric, n_seeds: int) -> tuple[str, bool | None]:
    st = c["summary"][met.key]
    if st["n"] == 0:
        return "n/a", None
    txt = _fmt(st["mean"], met.unit)
    if met.per_seed and n_seeds > 1 and st["std"] is not None and math.isfinite(st["mean"] or 0):
        txt += f" ± {_fmt(st['std'])} (worst {_fmt(st['worst'], met.unit)})"
    ok = c["acceptance"].get(met.key, {}).get("pass")
    return txt, ok


def markdown_table(doc: dict) -> str:
    """The scorecard as a Markdown table (metrics as rows, controllers as columns)."""
    names = list(doc["controllers"])
    n_seeds = len(doc["seeds"])
    lines = ["| metric | target | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
    for met in METRICS:
        cells = []
        for n in names:
            txt, ok = _cell(doc["controllers"][n], met, n_seeds)
            cells.append(txt + ("" if ok is None else (" ✓" if ok else " ✗")))
        unit = f" [{met.unit}]" if met.unit else ""
        lines.append(f"| {met.label}{unit} | {met.criterion} | " + " | ".join(cells) + " |")
    lines.append("| **criteria met on every seed** | | " + " | ".join(
        f"**{doc['controllers'][n]['acceptance_met']} / {doc['controllers'][n]['acceptance_total']}**"
        for n in names) + " |")
    return "\n".join(lines)


def _markdown(doc: dict) -> str:
    seeds = ", ".join(str(s) for s in doc["seeds"])
    parts = ["# Controller scorecard\n",
             f"Plant: {doc['plant']}; seeds {seeds}; experiments: "
             f"{doc['experiments'] if isinstance(doc['experiments'], str) else ', '.join(doc['experiments'])}; "
             f"identified model: {doc['model'] or 'n/a'}.\n",
             "Cells: mean ± standard deviation over the seeds (worst case); ✓/✗: acceptance against "
             "the bench specification (nanosim/pipeline/scorecard.py, ACCEPTANCE) on the worst case. Robustness "
             "rows are per design (the identified model, which is the loop as run, and the "
             "linear twin with the loop's delays and the bench's amplifier and gauge filters; mu over the stage's "
             "uncertainty set).\n",
             markdown_table(doc), "",
             f"**Default rule.** {doc['default_rule']}", "",
             (f"**Default:** `{doc['default']}` -- {doc['default_reason']}." if doc["default"] is not None
              else f"**Default:** none -- {doc['default_reason']}."), "", "## Designs", ""]
    for n, c in doc["controllers"].items():
        rule = c["tuning_rule"] or ("user controller" + ("" if c["linear"] else " object (not analysed: no "
                                                          "state-space matrices)"))
        stable = c.get("sampled_parameter_set_stable")
        extra = "" if stable is None else f" Sampled parameter set {'stable' if stable else 'NOT stable'}."
        parts.append(f"- **{n}** ({c['source']}): {rule}.{extra}")
    parts += ["", "## Figures", ""] + [f"![{cap}]({name})" for name, cap in A.COMPARE_FIGURES]
    return "\n".join(parts) + "\n"


def _html(doc: dict) -> str:
    names = list(doc["controllers"])
    n_seeds = len(doc["seeds"])
    head = "".join(f"<th>{html.escape(n)}</th>" for n in names)
    rows = []
    for met in METRICS:
        tds = []
        for n in names:
            txt, ok = _cell(doc["controllers"][n], met, n_seeds)
            cls = "" if ok is None else (' class="ok"' if ok else ' class="bad"')
            tds.append(f"<td{cls}>{html.escape(txt)}</td>")
        unit = f" [{met.unit}]" if met.unit else ""
        rows.append(f"<tr><td>{html.escape(met.label + unit)}</td><td>{html.escape(met.criterion)}</td>"
                    + "".join(tds) + "</tr>")
    rows.append("<tr><th>criteria met on every seed</th><td></td>" + "".join(
        f"<th>{doc['controllers'][n]['acceptance_met']} / {doc['controllers'][n]['acceptance_total']}</th>"
        for n in names) + "</tr>")
    designs = "".join(f"<li><b>{html.escape(n)}</b> ({html.escape(c['source'])}): "
                      f"{html.escape(c['tuning_rule'] or 'user controller')}</li>"
                      for n, c in doc["controllers"].items())
    figs = "".join(f'<figure><img src="{n}" alt="{html.escape(cap)}"><figcaption>{html.escape(cap)}</figcaption>'
                   f"</figure>" for n, cap in A.COMPARE_FIGURES)
    seeds = ", ".join(str(s) for s in doc["seeds"])
    default = "none" if doc["default"] is None else f"<code>{html.escape(str(doc['default']))}</code>"
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>Controller scorecard</title>
<style>body{{font-family:sans-serif;max-width:1400px;margin:2em auto}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:4px 8px;text-align:left}}td.ok{{background:#e3f5e1}}td.bad{{background:#fbe3e3}}
img{{max-width:100%}}</style></head><body><h1>Controller scorecard</h1>
<p>Plant: {html.escape(doc['plant'])}; seeds {seeds}; identified model: {html.escape(str(doc['model']))}.
Cells: mean &plusmn; standard deviation over the seeds (worst case); green/red: acceptance against the bench
specification (nanosim/pipeline/scorecard.py, ACCEPTANCE) on the worst case.</p>
<table><tr><th>metric</th><th>target</th>{head}</tr>{''.join(rows)}</table>
<p><b>Default rule.</b> {html.escape(doc['default_rule'])}</p>
<p><b>Default:</b> {default} &mdash; {html.escape(doc['default_reason'])}.</p>
<h2>Designs</h2><ul>{designs}</ul><h2>Figures</h2>{figs}</body></html>
"""


def write_scorecard(out, doc: dict) -> None:
    """``scorecard.json``, ``scorecard.md`` and ``scorecard.html`` into ``out``."""
    out = Path(out)
    write_json(out / A.SCORECARD_JSON, doc)
    write_text(out / A.SCORECARD_MD, _markdown(doc))
    write_text(out / A.SCORECARD_HTML, _html(doc))
