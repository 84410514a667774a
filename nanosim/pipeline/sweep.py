"""``nanosim sweep``: how flexure geometry trades bandwidth against travel and resolution.

Parameters (``--param NAME=start:stop:n``, several give their Cartesian grid):

* ``thickness.<family>`` -- notch thickness (um) of every notch of a family (``fb1``, ``fb2``,
  ``swing``, ``apa``; ``fourbar1``, ``fourbar2``, ``lever`` as aliases): the stage is rebuilt from
  its geometry (:mod:`nanosim.plant.build`), every stiffness (Paros-Weisbord, Lobontiu) and mass
  from it;
* ``length_mm.<field>`` -- a length of the chain geometry in mm (``leg_length``, ``fb1_length``,
  ``apa_arm``, ... of :class:`nanosim.plant.geometry.ChainGeometry`), rebuilt likewise;
* ``stiffness.<family>`` -- stiffness (and damping) factor of a hinge family
  (``load_model(stiffness_scale=...)``);
* ``target_mass_g`` -- mass of the table body (table, target and mount), grams;
* ``piezo_gain`` -- force-per-volt factor of the three actuators.

Per point: the modes, the static gain and the travel (per axis, the span over the
command box), a controller redesigned for that stage by the pipeline's rule
(:func:`design_for_point`: the identification experiments on the stage's linear
twin in the full electromechanics, then :func:`~nanosim.pipeline.design.run_design`
with the default design settings or the command line's), and the measured
bandwidth (PRBS, S and T) and closed-loop resolution on the point's linear twin
in the full electromechanics (the registered ``bandwidth`` and ``resolution``
experiments, points in lockstep). The points on the Pareto front of
(bandwidth up, travel up, resolution sigma down) are marked in the figure and
the table of ``report.md``; differences below :data:`PARETO_TIES` are ties, so
a point is not pushed off the front by a difference another seed could reverse.
"""
from __future__ import annotations

import itertools
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from nanosim import constants as C
from nanosim.fileio import save_figure, write_json, write_text
from nanosim.pipeline import artifacts as A
from nanosim.pipeline.config import DesignConfig, SweepConfig
from nanosim.pipeline.scaleout import open_executor, run_tasks
from nanosim.pipeline.timings import record_timings

__all__ = ["parse_param", "param_names", "check_params", "point_model", "design_for_point", "run_sweep",
           "pareto_front", "chain_length_fields", "report_markdown", "SWEEP_EXPERIMENTS"]

SWEEP_EXPERIMENTS = ("bandwidth", "resolution")
# Relative differences below these are ties on the Pareto front (pareto_front). Measured objectives: the spread
# (max - min over the mean) of the nominal stage's sweep point (--param piezo_gain=1:1:1) over seeds 0-4, measured
# 0.58 % (S bandwidth 36.40-36.62 Hz) and 1.49 % (sigma 2.016-2.046 nm); travel (from the static gain, no noise):
# one part in a thousand.
PARETO_TIES = {"bandwidth_S_hz": 0.006, "resolution_nm": 0.015, "travel_um": 1e-3}
_LABELS = {"bandwidth_S_hz": "S bandwidth, measured [Hz]", "travel_um": "travel, smallest axis [um]",
           "resolution_nm": "closed-loop resolution sigma, X [nm]"}


_ALIASES = {"fourbar1": "fb1", "fourbar2": "fb2", "lever": "apa"}
FAMILIES = ("fb1", "fb2", "swing", "apa")


def chain_length_fields() -> list[str]:
    """The chain lengths a ``length_mm.<field>`` parameter may name (the ``*_m`` fields of ``ChainGeometry``)."""
    from dataclasses import fields

    from nanosim.plant.geometry import ChainGeometry

    return [f.name[:-2] for f in fields(ChainGeometry) if f.name.endswith("_m")]


def param_names() -> str:
    """The parameter names :func:`parse_param` accepts, as one line (its error and ``--help`` use it)."""
    return (f"thickness.<family> (um) or stiffness.<family> (factor), families {', '.join(FAMILIES)} "
            f"(aliases {', '.join(f'{a}={b}' for a, b in _ALIASES.items())}; stiffness.apa only with an MJCF that "
            f"has APA notch joints); length_mm.<chain length> ({', '.join(chain_length_fields())}); "
            "target_mass_g (g); piezo_gain (factor)")


def parse_param(text: str) -> tuple[str, float, float, int]:
    """``NAME=start:stop:n`` -> ``(name, start, stop, n)``; ``ValueError`` naming what is wrong."""
    if "=" not in text:
        raise ValueError(f"--param: expected NAME=start:stop:n, got {text!r}")
    name, span = text.split("=", 1)
    name = name.strip()
    kind, _, fam = name.partition(".")
    fam = _ALIASES.get(fam, fam)
    ok = (name in ("target_mass_g", "piezo_gain") or (kind in ("thickness", "stiffness") and fam in FAMILIES)
          or (kind == "length_mm" and fam in chain_length_fields()))
    if not ok:
        raise ValueError(f"--param: unknown parameter {name!r}; expected {param_names()}")
    parts = span.split(":")
    if len(parts) != 3:
        raise ValueError(f"--param {name}: expected NAME=start:stop:n (3 fields after '='), got {span!r} "
                         f"({len(parts)} field{'s' if len(parts) != 1 else ''})")
    try:
        start, stop, n = float(parts[0]), float(parts[1]), int(parts[2])
    except ValueError:
        raise ValueError(f"--param {name}: expected start:stop:n with numbers and an integer count, got {span!r}") \
            from None
    if n < 1 or not (math.isfinite(start) and math.isfinite(stop)) or start <= 0 or stop <= 0:
        raise ValueError(f"--param {name}: expected positive start and stop and n >= 1, got {span!r}")
    return f"{kind}.{fam}" if fam else name, start, stop, n


def check_params(params, mjcf=None) -> None:
    """``ValueError`` before any work for parameters the stage cannot take.

    Thickness and length parameters rebuild the bundled stage (no ``--mjcf``); a stiffness
    family must have joints in the model (the bundled stage lumps the APA notches on the crank).
    """
    rebuilt = [name for name, *_ in params if name.partition(".")[0] in ("thickness", "length_mm")]
    if rebuilt and mjcf is not None:
        raise ValueError(f"--mjcf: expected none with --param {rebuilt[0]} (thickness and length parameters "
                         f"rebuild the bundled stage from its geometry), got {str(mjcf)!r}")
    fams = sorted({name.split(".", 1)[1] for name, *_ in params if name.startswith("stiffness.")})
    if fams:
        from nanosim.plant.mjcf import load_model

        for fam in fams:
            try:
                load_model(mjcf, stiffness_scale={fam: 1.0})
            except ValueError as exc:
                raise ValueError(f"--param stiffness.{fam}: {exc}") from None


def point_model(values: dict, mjcf=None):
    """The MjModel of one sweep point (``{parameter: value}``), from the bundled stage's geometry.

    ``thickness.<family>`` (um: the family's design web; each chain keeps its calibrated offset from
    it) and ``length_mm.<field>`` change the geometry (the stage is rebuilt, every stiffness and mass
    from it); ``stiffness.<family>`` scales a family's joints;
    ``target_mass_g`` sets the ``table`` body; ``piezo_gain`` scales the actuators.
    """
    from dataclasses import replace

    from nanosim.plant.geometry import CALIBRATED_GEOMETRY
    from nanosim.plant.mjcf import load_model
    from nanosim.plant.tolerances import model_from_geometry

    g = CALIBRATED_GEOMETRY
    chain = {}
    for name, v in values.items():
        kind, _, fam = name.partition(".")
        if kind == "thickness":
            nh = g.chain.notch(fam)
            chain[f"{fam}_notch"] = nh.with_thickness(v * 1e-6)
        elif kind == "length_mm":
            chain[f"{fam}_m"] = v * 1e-3
    if chain and mjcf is not None:
        raise ValueError("--param: thickness and length parameters rebuild the bundled stage; pass no --mjcf")
    kw = {"stiffness_scale": {name.split(".", 1)[1]: v for name, v in values.items() if name.startswith("stiffness.")}
          or None,
          "body_mass_kg": {"table": values["target_mass_g"] * 1e-3} if "target_mass_g" in values else None}
    model = model_from_geometry(replace(g, chain=replace(g.chain, **chain)), **kw) if chain else load_model(mjcf, **kw)
    if "piezo_gain" in values:
        for c in "abc":
            model.actuator_gainprm[model.actuator(f"piezo_{c}").id, 0] *= values["piezo_gain"]
    return model


def design_for_point(model, config: DesignConfig | None = None, seed: int = 0) -> tuple:
    """The pipeline's controller for one stage, on its linear twin, in a scratch folder.

    The identification experiments of ``nanosim identify`` (0 V operating point) run on the
    stage's linear twin in the full electromechanics
    (:func:`~nanosim.experiments.sysid.identify_on_twin`), the identified model goes to
    :func:`nanosim.pipeline.design.run_design` unchanged. Nothing is written outside the scratch
    folder, so it runs on any worker.

    Returns
    -------
    ControllerConfig, dict
        The exported discrete controller and a few figures of ``design.json`` and the identification.
    """
    import tempfile

    from nanosim.design.controller import DiscreteController
    from nanosim.experiments.sysid import IdentifySettings, identify_on_twin
    from nanosim.fileio import write_npz
    from nanosim.pipeline.design import run_design
    from nanosim.pipeline.identify import save_model

    ident, mech = identify_on_twin(model, IdentifySettings(seed=seed))
    with tempfile.TemporaryDirectory(prefix="nanosim-sweep-") as tmp:
        tmp = Path(tmp)
        save_model(tmp / A.MODEL_NPZ, ident)
        t = mech.sys_V
        write_npz(tmp / A.TWIN_NPZ, A=t.A, B=t.B, C=t.C, D=t.D, dt=mech.dt_s)
        run_design(tmp / A.MODEL_NPZ, tmp, config or DesignConfig(), twin=str(tmp / A.TWIN_NPZ), figures=False)
        ctrl = DiscreteController.from_npz(tmp / A.CONTROLLER_NPZ).config
        des = json.loads((tmp / A.DESIGN_JSON).read_text())
    out = {"gamma": des.get("gamma"), "controller_order": int(ctrl.n_states),
           "design_bandwidth_S_hz": des.get("bandwidth_S_hz"),
           "design_bandwidth_T_hz": des.get("bandwidth_T_hz"),
           "identification_fit_min_percent": float(np.min(ident.fit_percent)),
           "architecture": des.get("architecture", "mixsyn")}
    exp = des.get("exported_controller")
    if exp:                 # an lqg design: its own predicted figures on the identified model
        p = exp["parameters"]
        out.update(exported_predicted_bandwidth_S_hz=p.get("predicted_bandwidth_S_hz"),
                   exported_predicted_bandwidth_ref_to_error_hz=p.get("predicted_bandwidth_ref_to_error_hz"),
                   exported_predicted_bandwidth_ref_to_error_top_hz=p.get("predicted_bandwidth_ref_to_error_top_hz"),
                   exported_disk_margin=(p.get("predicted_disk_margin") or {}).get("multiloop"),
                   exported_mu_peak=p.get("mu_peak"), exported_control_weight=p.get("control_weight"),
                   exported_rule_met=p.get("robust_rule_met"))
    return ctrl, out


def run_points(task: dict, points: list, sink) -> list[dict]:
    """Worker task: model, modes, travel, redesigned controller and measured bandwidth/resolution per point."""
    from nanosim import experiments
    from nanosim.design.lti import single_threaded_blas
    from nanosim.experiments.batch_suite import MemberPlant, run_experiments_batch
    from nanosim.pipeline.mc_stats import flatten_metrics
    from nanosim.plant.runplant import RunPlant
    from nanosim.plant.modes import modal_analysis
    from nanosim.plant.stage import Stage

    experiments.load_builtin()
    design_cfg = task["design"]
    recs, plants, ctrls = [], [], []
    with single_threaded_blas():
        for idx, values in points:
            t0 = time.perf_counter()
            model = point_model(values, task.get("mjcf"))
            modes = modal_analysis(model)
            G0 = modes.static_gain_um_per_V
            span = C.COMMAND_RANGE_V[1] - C.COMMAND_RANGE_V[0]
            travel = span * np.abs(G0).sum(axis=1)
            try:
                ctrl, des = design_for_point(model, design_cfg, seed=task["seed"])
            except (ValueError, np.linalg.LinAlgError) as exc:     # a design rule that fails at this point
                ctrl, des = None, {"design_error": f"{type(exc).__name__}: {exc}"}
            rec = {"index": idx, "values": values, "modes_hz": [m.freq_hz for m in modes.below(1000.0)],
                   "static_gain_um_per_V": G0.tolist(), "travel_xyz_um": travel.tolist(),
                   "travel_um": float(travel.min()), **des, "design_seconds": round(time.perf_counter() - t0, 2)}
            plants.append(MemberPlant(twin=RunPlant.of_model(model).twin, model=model,
                                      home_um=Stage(model=model).table_um.copy(), static_gain_um_per_V=G0))
            ctrls.append(ctrl)
            recs.append(rec)
            sink.put(1)
        ok = [i for i, c in enumerate(ctrls) if c is not None]
        metrics = [{} for _ in recs]
        # one batch per controller order: a batch pads its controllers to the largest order, and padded
        # products sum in another order, so a point's bits would depend on the points sharing its chunk
        groups = {}
        for i in ok:
            groups.setdefault(ctrls[i].n_states, []).append(i)
        for members in groups.values():
            got, _ = run_experiments_batch(list(SWEEP_EXPERIMENTS), [plants[i] for i in members],
                                           [ctrls[i] for i in members], seed=task["seed"], exact=True, nthread=1,
                                           progress=lambda name, k=len(members): sink.put(k))
            for i, m in zip(members, got):
                metrics[i] = m
        sink.put((len(points) - len(ok)) * len(SWEEP_EXPERIMENTS))
    for rec, met in zip(recs, metrics):
        flat = flatten_metrics(met)
        rec["metrics"] = met
        rec["bandwidth_S_hz"] = flat.get("bandwidth_S_hz", math.nan)
        rec["bandwidth_T_hz"] = flat.get("bandwidth_T_hz", math.nan)
        rec["resolution_nm"] = flat.get("resolution_sigma_nm.closed_loop", math.nan)
        rec["first_mode_hz"] = rec["modes_hz"][0] if rec["modes_hz"] else math.nan
    return recs


def pareto_front(points: list[dict], up=("bandwidth_S_hz", "travel_um"), down=("resolution_nm",),
                 ties: dict | None = None) -> list[int]:
    """Indices of the non-dominated points (larger ``up``, smaller ``down``; NaN never on the front).

    ``ties`` maps an objective to a relative tolerance (default :data:`PARETO_TIES`): two values closer than
    it times the larger magnitude are a tie. A point is dominated when another is no worse in every
    objective beyond the tolerance and better in one beyond it, so a difference a second seed could
    reverse does not push a point off the front. ``ties={}`` gives the strict front.
    """
    ties = PARETO_TIES if ties is None else ties
    keys = list(up) + list(down)
    sign = np.array([1.0] * len(up) + [-1.0] * len(down))
    tol = np.array([ties.get(k, 0.0) for k in keys])
    V = [sign * np.array([p.get(k, math.nan) for k in keys], float) for p in points]

    def dominates(w, v):
        slack = tol * np.maximum(np.abs(w), np.abs(v))
        return bool(np.all(w >= v - slack) and np.any(w > v + slack))

    ok = [i for i, v in enumerate(V) if np.all(np.isfinite(v))]
    front = [i for i in ok if not any(dominates(V[j], V[i]) for j in ok if j != i)]
    return front if front or not ok else pareto_front(points, up, down, ties={})


def _label(values: dict) -> str:
    return ", ".join(f"{k.split('.')[-1]}={v:.4g}" for k, v in values.items())


def run_sweep(out, config: SweepConfig, *, progress: bool = True, say=None) -> dict:
    """Run the grid into ``out`` (normally a staging folder); returns ``sweep.json``'s content.

    The wall times (per point and in all) go to ``timings.json``.
    """
    from nanosim.plots.montecarlo import fig_pareto

    if not config.params:
        raise ValueError("--param: expected at least one NAME=start:stop:n")
    check_params(config.params, config.mjcf)
    out = Path(out)
    axes = [(name, np.linspace(a, b, n)) for name, a, b, n in config.params]
    grid = [dict(zip([n for n, _ in axes], (float(x) for x in combo)))
            for combo in itertools.product(*[v for _, v in axes])]
    task = {"seed": config.seed, "mjcf": str(config.mjcf) if config.mjcf else None, "design": config.design}
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
    seconds = {}                # wall times: to timings.json, not into the points' records
    for r in records:
        r["label"] = _label(r["values"])
        rel = f"{A.SWEEP_POINTS_DIR}/{A.sweep_point_json(r['index'])}"
        seconds[rel] = {"design_seconds": r.pop("design_seconds", None)}
        write_json(out / rel, r)
    front = pareto_front(records)
    for i, r in enumerate(records):
        r["pareto"] = i in front
    color = "resolution_nm"
    save_figure(fig_pareto(records, front, "travel_um", "bandwidth_S_hz", color, _LABELS), out / A.FIG_SWEEP_PARETO)
    table = [{k: r.get(k) for k in ("index", "label", "first_mode_hz", "travel_um", "bandwidth_S_hz",
                                    "bandwidth_T_hz", "resolution_nm", "gamma", "controller_order", "pareto",
                                    "exported_disk_margin", "exported_mu_peak", "exported_control_weight")}
             | {"values": r["values"]} for r in records]
    doc = {"parameters": [{"name": n, "values": v.tolist()} for n, v in axes], "seed": config.seed,
           "design": {"architecture": config.design.architecture, "settings": _design_settings(config.design)},
           "experiments": list(SWEEP_EXPERIMENTS), "points": table, "pareto": front, "pareto_ties": dict(PARETO_TIES),
           "units": {"travel_um": "um (span over the command box, smallest axis)", "bandwidth_S_hz": "Hz",
                     "resolution_nm": "nm (closed-loop sigma, X, at rest)", "first_mode_hz": "Hz",
                     "pareto_ties": "relative difference (of the larger magnitude)"}}
    write_json(out / A.SWEEP_JSON, doc)
    seconds[A.SWEEP_JSON] = {"wall_seconds": round(time.perf_counter() - t0, 2)}
    record_timings(out, seconds)
    write_text(out / A.REPORT_MD, report_markdown(doc, seconds[A.SWEEP_JSON]["wall_seconds"]))
    return doc


def _design_settings(cfg) -> dict:
    """The sweep's design settings as JSON (``DesignConfig``'s fields; a weights file by its path)."""
    import dataclasses

    return {k: (str(v) if isinstance(v, os.PathLike) else v) for k, v in dataclasses.asdict(cfg).items()}


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return f"{v:.4g}" if isinstance(v, float) else str(v)


_RULE_NOTE = {"hinf": ", the exported default: the four-block H-infinity design",
              "lqg": ": the robust lqg, the member with the least predicted noise that passes every check",
              "lqg-bandwidth": ": the robust lqg at the smallest control weight at which its pick meets every check, "
                               "so the bandwidth is the stage's and the checks', not fixed by the weights",
              "lqg-gain-range": ": the robust lqg with its disk margin over the piezo's gain range",
              "mixsyn": ": the H-infinity design of the weights"}


def report_markdown(doc: dict, wall_seconds: float) -> str:
    """``report.md`` of a sweep folder from its ``sweep.json`` document (columns follow the design rule)."""
    lines = ["# Flexure design sweep", "",
             "Parameters: " + "; ".join(f"`{p['name']}` = {', '.join(f'{x:.4g}' for x in p['values'])}"
                                        for p in doc["parameters"]), "",
             "Each point: modes, static gain and travel of the stage; a controller redesigned for it by the "
             "pipeline's rule (the identification experiments on its linear twin, then `nanosim design "
             f"--architecture {doc['design']['architecture']}`" + _RULE_NOTE.get(doc["design"]["architecture"], "")
             + "); bandwidth (PRBS, S) and closed-loop resolution measured on its linear twin with "
             "every electromechanical effect on. Pareto front: bandwidth up, travel up, resolution sigma down; "
             "relative differences below " + ", ".join(f"{v:.3g} ({k})" for k, v in doc["pareto_ties"].items()) +
             " are ties (for the measured ones, their spread over seeds 0-4 on the nominal stage).", "",
             f"![Pareto figure]({A.FIG_SWEEP_PARETO})", ""]
    hinf = doc["design"]["architecture"] in ("hinf", "mixsyn")   # the designs with a gamma
    extra = (("gamma", "gamma"),) if hinf else (("disk margin", "exported_disk_margin"), ("mu", "exported_mu_peak"),
                                                ("R_u", "exported_control_weight"))
    lines += ["| # | point | first mode [Hz] | travel [um] | S bandwidth [Hz] | T bandwidth [Hz] | resolution [nm] | "
              + "".join(f"{h} | " for h, _ in extra) + "Pareto |", "|---" * (8 + len(extra)) + "|"]
    for p in doc["points"]:
        lines.append(f"| {p['index']} | {p['label']} | {_fmt(p['first_mode_hz'])} | {_fmt(p['travel_um'])} | "
                     f"{_fmt(p['bandwidth_S_hz'])} | {_fmt(p['bandwidth_T_hz'])} | {_fmt(p['resolution_nm'])} | "
                     + "".join(f"{_fmt(p.get(k))} | " for _, k in extra) + f"{'yes' if p['pareto'] else ''} |")
    lines += ["", "gamma: the H-infinity design's closed-loop H-infinity norm." if hinf else
              "Disk margin: the exported lqg's multiloop input/output disk margin on the point's identified model; "
              "mu: its mixed-mu upper bound over the stage's uncertainty set; R_u: its LQR control weight."]
    lines += ["", f"Wall time: {wall_seconds:.1f} s."]
    return "\n".join(lines) + "\n"
