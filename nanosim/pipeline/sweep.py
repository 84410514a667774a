"""``nanosim sweep``: how flexure geometry trades bandwidth against travel and resolution.

Parameters (``--param NAME=start:stop:n``, several give their Cartesian grid):

* ``thickness.<family>`` -- notch thickness (um) of every hinge of a family (``fourbar1``,
  ``fourbar2``, ``swing``, ``lever``, ``crank_bend``); stiffness follows Paros & Weisbord,
  ``k ~ t^(5/2)`` (:func:`nanosim.plant.tolerances.notch_stiffness_ratio`), from the
  family's nominal thickness (:func:`~nanosim.plant.tolerances.default_tolerances`);
* ``stiffness.<family>`` -- stiffness (and damping) factor of a hinge family or a tendon
  (``load_model(stiffness_scale=...)``; ``crank_bend`` scales the three crank-bend tendons);
* ``target_mass_g`` -- mass of the table body (table, target and mount), grams;
* ``piezo_gain`` -- force-per-volt factor of the three actuators.

Per point: the modes, the static gain and the travel (per axis, the span over the
command box), a controller redesigned for that stage by the steps of
``nanosim design`` (:func:`design_for_point`: DC-matched balanced truncation of
the stage's linear twin with its piezo gain and creep, the inner damping loop,
the paper's H-infinity weights, 4 kHz discretization), and the measured
bandwidth (PRBS, S and T) and closed-loop resolution on the point's linear twin
in the full electromechanics (the registered ``bandwidth`` and ``resolution``
experiments, points in lockstep). The points on the Pareto front of
(bandwidth up, travel up, resolution sigma down) are marked in the figure and
the table of ``report.md``.
"""
from __future__ import annotations

import itertools
import math
import time
from pathlib import Path

import numpy as np

from nanosim import constants as C
from nanosim.fileio import save_figure, write_json, write_text
from nanosim.pipeline.config import DesignConfig, SweepConfig
from nanosim.pipeline.scaleout import open_executor, run_tasks

__all__ = ["parse_param", "point_model", "design_for_point", "run_sweep", "pareto_front", "SWEEP_EXPERIMENTS"]

SWEEP_EXPERIMENTS = ("bandwidth", "resolution")
FAMILIES = ("fourbar1", "fourbar2", "swing", "lever", "crank_bend")
FIG_PARETO = "fig_sweep_pareto.png"
_LABELS = {"bandwidth_S_hz": "S bandwidth, measured [Hz]", "travel_um": "travel, smallest axis [um]",
           "resolution_nm": "closed-loop resolution sigma, X [nm]"}


def parse_param(text: str) -> tuple[str, float, float, int]:
    """``NAME=start:stop:n`` -> ``(name, start, stop, n)``; ``ValueError`` naming what is wrong."""
    if "=" not in text:
        raise ValueError(f"--param: expected NAME=start:stop:n, got {text!r}")
    name, span = text.split("=", 1)
    name = name.strip()
    known = [f"thickness.{f}" for f in FAMILIES] + [f"stiffness.{f}" for f in FAMILIES] + ["target_mass_g",
                                                                                              "piezo_gain"]
    if name not in known and not name.startswith("stiffness."):
        raise ValueError(f"--param: unknown parameter {name!r}; expected one of {known} (or stiffness.<tendon>)")
    parts = span.split(":")
    try:
        start, stop, n = float(parts[0]), float(parts[1]), int(parts[2])
    except (IndexError, ValueError):
        raise ValueError(f"--param {name}: expected start:stop:n with numbers and an integer count, got {span!r}") \
            from None
    if len(parts) != 3 or n < 1 or not (math.isfinite(start) and math.isfinite(stop)) or start <= 0 or stop <= 0:
        raise ValueError(f"--param {name}: expected positive start and stop and n >= 1, got {span!r}")
    return name, start, stop, n


def point_model(values: dict, mjcf=None):
    """The MjModel of one sweep point (``{parameter: value}``)."""
    from nanosim.plant.mjcf import load_model
    from nanosim.plant.tolerances import default_tolerances, notch_stiffness_ratio

    base = load_model(mjcf)
    scale: dict[str, float] = {}
    nominal_t = None
    for name, v in values.items():
        kind, _, fam = name.partition(".")
        if kind in ("thickness", "stiffness"):
            if kind == "thickness":
                if nominal_t is None:
                    nominal_t = {t.name: t.nominal for t in default_tolerances(base).tolerances}
                notch = {"fourbar1": "crank_base", "fourbar2": "rocker_p_base", "swing": "h1", "lever": "lever",
                         "crank_bend": "crank_bend"}[fam]
                s = notch_stiffness_ratio(v, nominal_t[f"thickness.a_{notch}"])
            else:
                s = v
            keys = [f"{c}_crank_bend" for c in "abc"] if fam == "crank_bend" else [fam]
            for k in keys:
                scale[k] = scale.get(k, 1.0) * s
    masses = {"table": values["target_mass_g"] * 1e-3} if "target_mass_g" in values else None
    model = load_model(mjcf, stiffness_scale=scale or None, body_mass_kg=masses)
    if "piezo_gain" in values:
        for c in "abc":
            model.actuator_gainprm[model.actuator(f"piezo_{c}").id, 0] *= values["piezo_gain"]
    return model


def design_for_point(G_model, config: DesignConfig | None = None, dt: float = C.CONTROL_PERIOD_S):
    """The discrete controller ``nanosim design`` would export for the model ``G_model`` (steps 1-5 of
    :mod:`nanosim.pipeline.design`, without its files, figures and robustness analysis).

    Returns
    -------
    ControllerConfig, dict
        The controller and a few design figures (gamma, order, design bandwidths).
    """
    from nanosim.design.controller import ControllerConfig
    from nanosim.design.damping import damped_plant, damping_loop
    from nanosim.design.discretize import discretize_controller
    from nanosim.design.hinf import design_hinf
    from nanosim.design.loops import stack_inputs
    from nanosim.design.reduction import reduce_model
    from nanosim.design.weights import Weights

    cfg = config or DesignConfig()
    W = Weights.coerce(cfg.weights)
    red = reduce_model(G_model, cfg.reduced_order)
    dl = damping_loop(red.G_reduced, cfg.damping_zeta, lowpass_hz=cfg.damping_lowpass_hz) \
        if cfg.has_damping_loop else None
    d = design_hinf(damped_plant(red.G_reduced, dl), W, gamma_relax=cfg.gamma_relax)
    Kd = discretize_controller(d.K, dt, cfg.discretization).Kd
    if dl is not None:
        Kd = stack_inputs(Kd, discretize_controller(dl.Ky, dt, "tustin_modal").Kd)
    ny = G_model.noutputs
    ctrl = ControllerConfig(np.asarray(Kd.A), np.asarray(Kd.B), np.asarray(Kd.C), np.asarray(Kd.D), dt,
                            n_error=ny)
    return ctrl, {"gamma": float(d.gamma), "controller_order": int(ctrl.n_states),
                  "design_bandwidth_S_hz": float(d.bandwidth_S_hz), "design_bandwidth_T_hz": float(d.bandwidth_T_hz)}


def run_points(task: dict, points: list, sink) -> list[dict]:
    """Worker task: model, modes, travel, redesigned controller and measured bandwidth/resolution per point."""
    from nanosim import experiments
    from nanosim.design.lti import single_threaded_blas
    from nanosim.experiments.batch_suite import MemberPlant, run_experiments_batch
    from nanosim.pipeline.mc_stats import flatten_metrics
    from nanosim.plant.linearize import linearize
    from nanosim.plant.modes import modal_analysis
    from nanosim.plant.stage import Stage, StageConfig

    experiments.load_builtin()
    design_cfg = DesignConfig(**task["design"])
    recs, plants, ctrls = [], [], []
    with single_threaded_blas():
        for idx, values in points:
            t0 = time.perf_counter()
            model = point_model(values, task.get("mjcf"))
            modes = modal_analysis(model)
            G0 = modes.static_gain_um_per_V
            span = C.COMMAND_RANGE_V[1] - C.COMMAND_RANGE_V[0]
            travel = span * np.abs(G0).sum(axis=1)
            ctrl, des = design_for_point(linearize(Stage(model=model), include_piezo=True).sys_V, design_cfg)
            rec = {"index": idx, "values": values, "modes_hz": [m.freq_hz for m in modes.below(1000.0)],
                   "static_gain_um_per_V": G0.tolist(), "travel_xyz_um": travel.tolist(),
                   "travel_um": float(travel.min()), **des, "design_seconds": round(time.perf_counter() - t0, 2)}
            plants.append(MemberPlant(twin=linearize(Stage(config=StageConfig.ideal(), model=model)),
                                      home_um=Stage(model=model).table_um.copy(), static_gain_um_per_V=G0))
            ctrls.append(ctrl)
            recs.append(rec)
            sink.put(1)
        metrics, _ = run_experiments_batch(list(SWEEP_EXPERIMENTS), plants, ctrls, seed=task["seed"], exact=True,
                                           nthread=1,
                                           progress=lambda name: sink.put(len(points)))
    for rec, met in zip(recs, metrics):
        flat = flatten_metrics(met)
        rec["metrics"] = met
        rec["bandwidth_S_hz"] = flat.get("bandwidth_S_hz", math.nan)
        rec["bandwidth_T_hz"] = flat.get("bandwidth_T_hz", math.nan)
        rec["resolution_nm"] = flat.get("resolution_sigma_nm.closed_loop", math.nan)
        rec["first_mode_hz"] = rec["modes_hz"][0] if rec["modes_hz"] else math.nan
    return recs


def pareto_front(points: list[dict], up=("bandwidth_S_hz", "travel_um"), down=("resolution_nm",)) -> list[int]:
    """Indices of the non-dominated points (larger ``up``, smaller ``down``; NaN never on the front)."""
    def vec(p):
        return np.array([p.get(k, math.nan) for k in up] + [-p.get(k, math.nan) for k in down], float)

    V = [vec(p) for p in points]
    front = []
    for i, v in enumerate(V):
        if not np.all(np.isfinite(v)):
            continue
        dominated = any(np.all(np.isfinite(w)) and np.all(w >= v) and np.any(w > v) for j, w in enumerate(V) if j != i)
        if not dominated:
            front.append(i)
    return front


def _label(values: dict) -> str:
    return ", ".join(f"{k.split('.')[-1]}={v:.4g}" for k, v in values.items())


def run_sweep(out, config: SweepConfig, *, progress: bool = True, say=None) -> dict:
    """Run the grid into ``out`` (normally a staging folder); returns ``sweep.json``'s content."""
    from nanosim.plots.montecarlo import fig_pareto

    if not config.params:
        raise ValueError("--param: expected at least one NAME=start:stop:n")
    out = Path(out)
    axes = [(name, np.linspace(a, b, n)) for name, a, b, n in config.params]
    grid = [dict(zip([n for n, _ in axes], (float(x) for x in combo)))
            for combo in itertools.product(*[v for _, v in axes])]
    task = {"seed": config.seed, "mjcf": str(config.mjcf) if config.mjcf else None,
            "design": {f: getattr(config.design, f) for f in ("reduced_order", "damping_zeta", "damping_lowpass_hz",
                                                               "discretization", "gamma_relax")}
            | {"weights": str(config.design.weights) if config.design.weights else None}}
    records: list[dict] = []
    t0 = time.perf_counter()
    with open_executor(config.scheduler, config.workers) as scale:
        size = max(1, math.ceil(len(grid) / scale.workers))
        if say:
            say(f"{len(grid)} points on {scale.description}, chunks of {size}")
        chunks = [list(enumerate(grid))[k:k + size] for k in range(0, len(grid), size)]
        run_tasks(scale, run_points, [(task, c) for c in chunks], lambda t, recs: records.extend(recs),
                  total_units=len(grid) * (1 + len(SWEEP_EXPERIMENTS)), desc="sweep", progress=progress)
    records.sort(key=lambda r: r["index"])
    for r in records:
        r["label"] = _label(r["values"])
        write_json(out / "points" / f"point_{r['index']:03d}.json", r)
    front = pareto_front(records)
    for i, r in enumerate(records):
        r["pareto"] = i in front
    color = "resolution_nm"
    save_figure(fig_pareto(records, front, "travel_um", "bandwidth_S_hz", color, _LABELS), out / FIG_PARETO)
    table = [{k: r.get(k) for k in ("index", "label", "first_mode_hz", "travel_um", "bandwidth_S_hz",
                                    "bandwidth_T_hz", "resolution_nm", "gamma", "controller_order", "pareto")}
             | {"values": r["values"]} for r in records]
    doc = {"parameters": [{"name": n, "values": v.tolist()} for n, v in axes], "seed": config.seed,
           "experiments": list(SWEEP_EXPERIMENTS), "points": table, "pareto": front,
           "wall_seconds": round(time.perf_counter() - t0, 2),
           "units": {"travel_um": "um (span over the command box, smallest axis)", "bandwidth_S_hz": "Hz",
                     "resolution_nm": "nm (closed-loop sigma, X, at rest)", "first_mode_hz": "Hz"}}
    write_json(out / "sweep.json", doc)
    write_text(out / "report.md", _report(doc))
    return doc


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _report(doc: dict) -> str:
    lines = ["# Flexure design sweep", "",
             "Parameters: " + "; ".join(f"`{p['name']}` = {', '.join(f'{x:.4g}' for x in p['values'])}"
                                        for p in doc["parameters"]), "",
             "Each point: modes, static gain and travel of the stage; a controller redesigned for it (the steps of "
             "`nanosim design`); bandwidth (PRBS, S) and closed-loop resolution measured on its linear twin with "
             "every electromechanical effect on. Pareto front: bandwidth up, travel up, resolution sigma down.", "",
             f"![Pareto figure]({FIG_PARETO})", "",
             "| # | point | first mode [Hz] | travel [um] | S bandwidth [Hz] | T bandwidth [Hz] | resolution [nm] | "
             "gamma | Pareto |", "|---|---|---|---|---|---|---|---|---|"]
    for p in doc["points"]:
        lines.append(f"| {p['index']} | {p['label']} | {_fmt(p['first_mode_hz'])} | {_fmt(p['travel_um'])} | "
                     f"{_fmt(p['bandwidth_S_hz'])} | {_fmt(p['bandwidth_T_hz'])} | {_fmt(p['resolution_nm'])} | "
                     f"{_fmt(p['gamma'])} | {'yes' if p['pareto'] else ''} |")
    lines += ["", f"Wall time: {doc['wall_seconds']:.1f} s."]
    return "\n".join(lines) + "\n"
