"""Statistics of a population of simulated stages: flat metrics, spec and yield, worst cases, sensitivity.

Used by ``nanosim montecarlo`` (:mod:`nanosim.pipeline.montecarlo`) and
``nanosim sweep``. Everything here is plain data in, JSON-ready data out.
"""
from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy import stats

from nanosim import constants as C
from nanosim.paper import BANDS, PAPER_CONTOUR_SPEED_UM_S, PAPER_STEP_UM

__all__ = ["flatten_metrics", "unit_of", "default_spec", "load_spec", "check_spec", "evaluate_spec", "yield_table",
           "worst_cases", "sensitivity", "compare_crosscheck", "CROSSCHECK_METRICS", "CROSSCHECK_RESOLUTION",
           "CROSSCHECK_REL_TOL", "READING_QUANTA_PER_METRIC", "CONTOUR_MEAN_METRIC", "wilson_interval",
           "SPREAD_MEMBERS_PER_SIDE", "SPREAD_GAIN_STEP", "spread_gain_factors", "reading_spread",
           "crosscheck_bias"]

_UNITS = (("_hz", "Hz"), ("_nm", "nm"), ("_um", "um"), ("_ms", "ms"), ("_percent", "%"), ("_deg", "deg"),
          ("_s", "s"), ("_db", "dB"), ("_um_per_V", "um/V"))
_SKIP = {"experiment_seconds", "errors", "units", "plant", "seed"}


def _speed_label(speed_um_s) -> str:
    """The key of one contouring case in a flat metric name: ``1000um_s``."""
    return f"{float(speed_um_s):g}um_s"


# The contour error at the paper's speed, as a flat metric.
CONTOUR_MEAN_METRIC = f"contouring.{_speed_label(PAPER_CONTOUR_SPEED_UM_S)}.mean_error_nm"

# The MuJoCo-vs-twin quantities of the pipeline report.
CROSSCHECK_METRICS = ("bandwidth_S_hz", "bandwidth_T_hz", "step_2um.overshoot_percent", "step_2um.rise_ms",
                      "resolution_sigma_nm.closed_loop", "hysteresis.open_loop_percent",
                      "hysteresis.closed_loop_nm", "creep.open_loop_drift_nm", "creep.closed_loop_drift_nm",
                      "tracking.triangle_5hz.rms_error_nm", "tracking.triangle_40hz.rms_error_nm",
                      CONTOUR_MEAN_METRIC)

CROSSCHECK_REL_TOL = 0.05
# The quantum in which a metric is read off the gauge (absolute, the metric's unit): twin and MuJoCo agree when
# they differ by at most 5 % or by at most this much. One reading rounds to one ADC count (C.ADC_LSB_NM, 1.53 nm),
# so two simulators whose true positions differ by a hair can read one count apart; one instant read between
# samples is likewise resolved to one control period. Each metric here is a difference of two such readings (the
# step's peak sample minus its pre-step mean; the late window's mean minus the early one's; the settled positions
# after an up and a down move) or of two instants (the 90 % crossing minus the 10 % one), so two simulators can
# read it two quanta apart at the same physics (``tests/test_montecarlo.py`` checks the bound). Without it the
# closed-loop creep drift (0.03 nm) and hysteresis (0.25 nm) of a loop that rejects both, far below one count,
# and a 2 um step's overshoot of 8-30 nm (peaks one count apart, 0.05-0.1 count in the pre-step mean) fail a
# relative comparison on rounding alone. Averaged metrics (contour mean error, sigma) and the bandwidths are
# compared relatively only.
READING_QUANTA_PER_METRIC = 2
CROSSCHECK_RESOLUTION = {
    "step_2um.overshoot_percent": READING_QUANTA_PER_METRIC * 100.0 * C.ADC_LSB_NM / (1e3 * PAPER_STEP_UM),
    "step_2um.rise_ms": READING_QUANTA_PER_METRIC * 1e3 * C.CONTROL_PERIOD_S,
    "hysteresis.closed_loop_nm": READING_QUANTA_PER_METRIC * C.ADC_LSB_NM,
    "creep.closed_loop_drift_nm": READING_QUANTA_PER_METRIC * C.ADC_LSB_NM,
}

# The twin's reading spread at indistinguishable physics. In a loop with a quantized DAC and ADC a change far below
# any physical one (the input gain scaled by 0.1 ppm) moves which count each reading rounds to, and the loop carries
# that on: table paths part by several nm at the lightly damped 460-470 Hz modes (twin against MuJoCo up to 3-4 nm;
# twins 0-8 ppm apart 6-8 nm, tests/test_montecarlo.py; with both quantizers and the noise off, twin and MuJoCo
# paths agree to 0.09 nm rms, the twins to 0.01 nm).
# A metric read off one sample, such as the 2 um step's peak, is then a draw from a spread several counts wide (the
# overshoot of one sample reads 12.1-13.8 nm over twins whose gains differ by at most 8 ppm; the same spread for
# steps of 0.1 ppm and 1 ppm). The cross-check therefore runs each cross-checked sample's twin 2 K + 1 times, its
# input gain scaled by 1 + k SPREAD_GAIN_STEP (k = -K ... K, K = SPREAD_MEMBERS_PER_SIDE; k = 0 is the sample's
# twin), and a MuJoCo reading agrees when it lies within the reading resolution of that range. Eight ppm is less
# than 1/250 of the model's smallest relative tolerance (a link width's +/-5 um in 2.4 mm, 0.21 %).
SPREAD_MEMBERS_PER_SIDE = 8
SPREAD_GAIN_STEP = 1e-6


def spread_gain_factors(members_per_side: int = SPREAD_MEMBERS_PER_SIDE,
                        gain_step: float = SPREAD_GAIN_STEP) -> np.ndarray:
    """Input-gain factors ``1 + k gain_step``, ``k = -members_per_side ... members_per_side`` (the middle one is 1)."""
    k = np.arange(-members_per_side, members_per_side + 1)
    return 1.0 + gain_step * k


def reading_spread(flats: Sequence[dict]) -> dict:
    """Per metric of the flat records ``flats`` (one per twin of a spread): ``{min, max, mean, std, n}``
    over the finite values (``std`` with one degree of freedom; 0 for one value).
    """
    out = {}
    for m in sorted(set().union(*[set(f) for f in flats])) if flats else []:
        v = np.array([f.get(m, math.nan) for f in flats], float)
        v = v[np.isfinite(v)]
        if v.size:
            out[m] = {"min": float(v.min()), "max": float(v.max()), "mean": float(v.mean()),
                      "std": float(v.std(ddof=1)) if v.size > 1 else 0.0, "n": int(v.size)}
    return out


def unit_of(name: str) -> str:
    """Unit of a flat metric from its name (``..._hz`` -> Hz; a dotted tail inherits its parent's unit)."""
    for part in reversed(name.split(".")):
        for suffix, unit in sorted(_UNITS, key=lambda su: -len(su[0])):
            if part.endswith(suffix):
                return unit
    return "-"


def _label(item: dict) -> str:
    parts = []
    if "waveform" in item:
        parts.append(str(item["waveform"]))
    if "freq_hz" in item:
        parts.append(f"{float(item['freq_hz']):g}hz")
    if "speed_um_s" in item:
        parts.append(_speed_label(item["speed_um_s"]))
    return "_".join(parts)


def flatten_metrics(metrics: dict) -> dict[str, float]:
    """``metrics.json``-style nested metrics -> ``{dotted name: float}``.

    Lists of cases are keyed by their case (``tracking.triangle_5hz.rms_error_nm``,
    ``contouring.1000um_s.mean_error_nm``); lists of numbers by index. Adds
    ``small_steps.max_error_nm`` (largest |plateau - target|). Booleans become 0/1.
    """
    out: dict[str, float] = {}

    def walk(prefix, v):
        if isinstance(v, bool):
            out[prefix] = float(v)
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out[prefix] = float(v) if v is not None else math.nan
        elif v is None:
            out[prefix] = math.nan
        elif isinstance(v, dict):
            for k, x in v.items():
                if k not in _SKIP:
                    walk(f"{prefix}.{k}" if prefix else k, x)
        elif isinstance(v, (list, tuple)):
            if v and all(isinstance(x, dict) for x in v):
                for x in v:
                    lab = _label(x)
                    for k, y in x.items():
                        if k not in ("waveform", "freq_hz", "speed_um_s"):
                            walk(f"{prefix}.{lab}.{k}", y)
            else:
                for i, x in enumerate(v):
                    walk(f"{prefix}.{i}", x)

    walk("", {k: v for k, v in metrics.items() if k not in _SKIP})
    ss = metrics.get("small_steps")
    if isinstance(ss, dict) and "plateau_means_nm" in ss:
        err = np.abs(np.asarray(ss["plateau_means_nm"], float) - np.asarray(ss["targets_nm"], float))
        out["small_steps.max_error_nm"] = float(err.max())
    return out


def default_spec() -> dict:
    """The paper's acceptance bands on the closed loop (:data:`nanosim.paper.BANDS`) as a spec."""
    def lim(metric, key, label):
        band = BANDS[key]
        out = {"metric": metric, "unit": unit_of(metric), "label": label,
               "source": f"nanosim.paper.BANDS[{key!r}] ({band.text})"}
        if band.low is not None:
            out["min"] = float(band.low)
        if band.high is not None:
            out["max"] = float(band.high)
        return out

    return {"description": "the paper's closed-loop acceptance bands (nanosim.paper.BANDS) and a stable loop",
            "limits": [
                {"metric": "closed_loop_stable", "min": 1.0, "unit": "-", "label": "closed loop stable (twin)",
                 "source": "stability of the sampled loop"},
                lim("bandwidth_S_hz", "bandwidth_S_stage_hz", "S bandwidth"),
                lim("step_2um.settling_ms", "settling_ms", "2 um step settling"),
                lim("step_2um.overshoot_percent", "overshoot_percent", "2 um step overshoot"),
                lim("resolution_sigma_nm.closed_loop", "sigma_closed_nm", "closed-loop resolution sigma"),
                lim("hysteresis.closed_loop_nm", "hysteresis_closed_nm", "closed-loop hysteresis"),
                lim("creep.closed_loop_drift_nm", "creep_closed_nm", "closed-loop creep drift"),
                lim(CONTOUR_MEAN_METRIC, "contour_mean_nm", f"contour error at {PAPER_CONTOUR_SPEED_UM_S:g} um/s"),
            ]}


def check_spec(spec: dict, origin: str = "spec") -> dict:
    """Validate a spec (``{"limits": [{"metric", "unit", "min" and/or "max"}, ...]}``); returns it."""
    if not isinstance(spec, dict) or not isinstance(spec.get("limits"), list) or not spec["limits"]:
        raise ValueError(f"{origin}: expected a JSON object with a non-empty list 'limits'")
    for i, lim in enumerate(spec["limits"]):
        where = f"{origin}: limits[{i}]"
        if not isinstance(lim, dict) or not isinstance(lim.get("metric"), str):
            raise ValueError(f"{where}: expected an object with a 'metric' name")
        if "min" not in lim and "max" not in lim:
            raise ValueError(f"{where} ({lim['metric']}): expected 'min' and/or 'max'")
        for k in ("min", "max"):
            if k in lim and (not isinstance(lim[k], (int, float)) or isinstance(lim[k], bool)
                             or not math.isfinite(lim[k])):
                raise ValueError(f"{where} ({lim['metric']}): {k} must be a finite number, got {lim[k]!r}")
        want = unit_of(lim["metric"])
        if lim.get("unit") != want:
            raise ValueError(f"{where} ({lim['metric']}): unit must be {want!r} (from the metric's name), "
                             f"got {lim.get('unit')!r}")
    return spec


def load_spec(path) -> dict:
    """Read and validate a spec JSON file."""
    p = Path(path)
    try:
        spec = json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"--spec: cannot read {str(p)!r} as JSON ({exc})") from None
    return check_spec(spec, f"--spec {p}")


def _passes(value: float, lim: dict) -> bool:
    if value is None or not math.isfinite(value):
        return False
    return ("min" not in lim or value >= lim["min"]) and ("max" not in lim or value <= lim["max"])


def evaluate_spec(flat: dict, spec: dict) -> dict:
    """``{metric: pass}`` for one sample and ``"all"``; a missing metric fails."""
    res = {lim["metric"]: _passes(flat.get(lim["metric"], math.nan), lim) for lim in spec["limits"]}
    res["all"] = all(res.values())
    return res


def wilson_interval(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a proportion ``k / n`` (Wilson, 1927).

    ``(p + z^2 / 2n -+ z sqrt(p (1 - p) / n + z^2 / 4n^2)) / (1 + z^2 / n)`` with ``p = k / n`` and ``z``
    the two-sided normal quantile of ``confidence``; computed by
    ``scipy.stats.binomtest(k, n).proportion_ci(method="wilson")``, whose ends are 0 and 1 exactly at
    ``k = 0`` and ``k = n``. ``(nan, nan)`` for ``n = 0``.
    """
    if n == 0:
        return (math.nan, math.nan)
    ci = stats.binomtest(int(k), int(n)).proportion_ci(confidence_level=confidence, method="wilson")
    return (float(ci.low), float(ci.high))


def yield_table(flats: list[dict], spec: dict) -> list[dict]:
    """Per limit and overall: samples passing, yield (%) and its 95 % Wilson interval, median and worst."""
    n = len(flats)
    rows = []
    evals = [evaluate_spec(f, spec) for f in flats]
    for lim in spec["limits"]:
        m = lim["metric"]
        vals = np.array([f.get(m, math.nan) for f in flats], float)
        k = sum(e[m] for e in evals)
        lo, hi = wilson_interval(k, n)
        finite = vals[np.isfinite(vals)]
        worst = (float(finite.min()) if "min" in lim else float(finite.max())) if finite.size else math.nan
        rows.append({"metric": m, "label": lim.get("label", m), "unit": lim["unit"], "min": lim.get("min"),
                     "max": lim.get("max"), "n": n, "pass": int(k), "yield_percent": 100.0 * k / n if n else math.nan,
                     "ci95_percent": [100 * lo, 100 * hi],
                     "median": float(np.median(finite)) if finite.size else math.nan, "worst": worst})
    k = sum(e["all"] for e in evals)
    lo, hi = wilson_interval(k, n)
    rows.append({"metric": "all", "label": "every limit", "unit": "-", "n": n, "pass": int(k),
                 "yield_percent": 100.0 * k / n if n else math.nan, "ci95_percent": [100 * lo, 100 * hi]})
    return rows


def worst_cases(indices: list[int], flats: list[dict], spec: dict, k: int = 3) -> dict:
    """Per limit, the ``k`` samples furthest on the wrong side (index, value)."""
    out = {}
    for lim in spec["limits"]:
        m = lim["metric"]
        vals = [(i, f.get(m, math.nan)) for i, f in zip(indices, flats)]
        vals = [(i, v) for i, v in vals if v is not None and math.isfinite(v)]
        vals.sort(key=lambda iv: iv[1], reverse="max" in lim and "min" not in lim)
        out[m] = [{"sample": int(i), "value": float(v), "pass": _passes(v, lim)} for i, v in vals[:k]]
    return out


def _adjusted_r2(X: np.ndarray, y: np.ndarray) -> float:
    n, p = X.shape
    if n <= p + 2:
        return math.nan
    A = np.hstack([np.ones((n, 1)), X])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    resid = y - A @ coef
    ss_tot = float(((y - y.mean()) ** 2).sum())
    if ss_tot == 0:
        return 0.0
    r2 = 1 - float((resid ** 2).sum()) / ss_tot
    return 1 - (1 - r2) * (n - 1) / (n - p - 1)


def sensitivity(X: np.ndarray, names: list[str], groups: list[str], flats: list[dict], metrics: list[str],
                top: int = 5) -> dict:
    """Which tolerances matter: per metric, the adjusted R^2 of each tolerance group alone and the
    individual variables with the largest |Spearman rho|.

    Parameters
    ----------
    X : (N, V) normalized deviations (-1 ... 1) of every sample
    names, groups : V variable names and their groups
    flats : N flat metric dicts
    metrics : metric names to rank
    """
    out = {}
    X = np.asarray(X, float)
    for m in metrics:
        y = np.array([f.get(m, math.nan) for f in flats], float)
        ok = np.isfinite(y)
        if ok.sum() < 8 or np.ptp(y[ok]) == 0:
            continue
        Xo, yo = X[ok], y[ok]
        grp = []
        for g in dict.fromkeys(groups):
            cols = [i for i, gg in enumerate(groups) if gg == g]
            grp.append({"group": g, "adjusted_r2": _adjusted_r2(Xo[:, cols], yo), "variables": len(cols)})
        grp.sort(key=lambda d: -(d["adjusted_r2"] if math.isfinite(d["adjusted_r2"]) else -1))
        rho = []
        for i, nm in enumerate(names):
            if np.ptp(Xo[:, i]) > 0:
                r = stats.spearmanr(Xo[:, i], yo).statistic
                if math.isfinite(r):
                    rho.append((nm, float(r)))
        rho.sort(key=lambda t: -abs(t[1]))
        out[m] = {"unit": unit_of(m), "groups": grp, "top_variables": [{"name": n, "spearman_rho": r}
                                                                        for n, r in rho[:top]]}
    return out


def compare_crosscheck(twin: dict, mujoco: dict, metrics=CROSSCHECK_METRICS, rel_tol: float = CROSSCHECK_REL_TOL,
                       resolution: dict | None = None, spread: dict | None = None) -> dict:
    """Twin vs MuJoCo for one sample: ``{metric: {twin, mujoco, rel_diff, abs_diff, resolution, within_resolution,
    ok, ok_relative, ok_without_spread}}`` (with ``spread``, also ``twin_min, twin_max, twin_mean, spread_gap,
    within_spread``), ``all_ok``, ``all_ok_relative`` and ``all_ok_without_spread``.

    Compares ``metrics`` (default: the pipeline report's MuJoCo-vs-twin quantities) where both
    have them; when none is present (other experiments), every metric the two share. ``ok``: the
    relative difference is at most ``rel_tol``, or the absolute one at most the metric's
    ``resolution`` (default :data:`CROSSCHECK_RESOLUTION`; 0 for a metric not in it), or (given the
    twin's ``spread``, :func:`reading_spread` of its runs at indistinguishable physics) the MuJoCo
    reading lies within ``resolution`` of the twin's range ``[min, max]`` (``spread_gap``: its distance
    from the range, 0 inside); ``ok_relative``: the relative test alone; ``ok_without_spread``: ``ok``
    without the spread.
    """
    res = CROSSCHECK_RESOLUTION if resolution is None else resolution
    names = [m for m in metrics if m in twin and m in mujoco] or sorted(set(twin) & set(mujoco))
    rows = {}
    for m in names:
        a, b = twin.get(m, math.nan), mujoco.get(m, math.nan)
        if not (math.isfinite(a) and math.isfinite(b)):
            continue
        rel = abs(a - b) / max(abs(b), abs(a), 1e-12) if a != b else 0.0
        q = float(res.get(m, 0.0))
        within = abs(a - b) <= q * (1 + 1e-9)
        ok = rel <= rel_tol or within
        row = {"twin": a, "mujoco": b, "rel_diff": rel, "abs_diff": abs(a - b), "resolution": q,
               "within_resolution": within, "ok": ok, "ok_relative": rel <= rel_tol, "ok_without_spread": ok}
        if spread is not None and m in spread:
            lo, hi = float(spread[m]["min"]), float(spread[m]["max"])
            gap = max(lo - b, b - hi, 0.0)
            row.update(twin_min=lo, twin_max=hi, twin_mean=float(spread[m]["mean"]), spread_gap=gap,
                       within_spread=gap <= q * (1 + 1e-9))
            row["ok"] = row["ok"] or row["within_spread"]
        rows[m] = row
    return {"metrics": rows, "all_ok": all(r["ok"] for r in rows.values()) if rows else False,
            "all_ok_relative": all(r["ok_relative"] for r in rows.values()) if rows else False,
            "all_ok_without_spread": all(r["ok_without_spread"] for r in rows.values()) if rows else False}


def crosscheck_bias(cross: Sequence[dict]) -> dict:
    """The systematic MuJoCo-minus-twin difference of each metric over the cross-checked samples.

    Per sample the difference is taken from the mean of the twin's spread (``twin_mean``, the twin's own
    reading without a spread), so the reading spread of one sample averages out over the samples.

    Parameters
    ----------
    cross : sequence of dict
        :func:`compare_crosscheck` results, one per sample.

    Returns
    -------
    dict
        ``{metric: {n, mean_diff, std_err, mean_diff_percent}}``: the mean difference in the metric's unit, its
        standard error (NaN for one sample) and the mean of the per-sample differences relative to the twin, %.
    """
    diffs: dict = {}
    for c in cross:
        for m, r in c["metrics"].items():
            centre = float(r.get("twin_mean", r["twin"]))
            diffs.setdefault(m, []).append((float(r["mujoco"]) - centre, centre))
    out = {}
    for m, rows in diffs.items():
        d = np.array([x for x, _ in rows])
        rel = np.array([x / abs(c) for x, c in rows if c != 0.0])
        out[m] = {"n": int(d.size), "mean_diff": float(d.mean()),
                  "std_err": float(d.std(ddof=1) / math.sqrt(d.size)) if d.size > 1 else math.nan,
                  "mean_diff_percent": float(100 * rel.mean()) if rel.size else math.nan}
    return out
