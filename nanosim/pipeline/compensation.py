"""The pipeline's hysteresis-compensation step: the exported controller with and without the inverse-PI
feedforward and the charge drive, on the linear twin (``compensation.json`` and its figure).

For the run's controller and stage, on the linear twin (:class:`~nanosim.plant.twin.TwinStage`, the
bench's electromechanics with every effect on) and with the run's seed, three cases run the same
experiment functions as ``nanosim characterize --twin``:

* ``voltage``: the bench (voltage amplifier, no compensation);
* ``voltage_feedforward``: the inverse Prandtl-Ishlinskii feedforward, its operator identified on the
  voltage-driven twin first (:func:`~nanosim.experiments.loop.fit_feedforward`, once, shared by the
  experiments of the case; what ``--feedforward inverse-pi`` does per experiment);
* ``charge``: the charge amplifier (``ElectronicsConfig(drive="charge")``, ``--drive charge``);
* ``charge_feedforward``: both, the operator identified on the charge-driven twin (what the feedforward
  meets there is the hysteresis the charge amplifier leaves: its residual above the crossover and all of
  it below; ``--drive charge --feedforward inverse-pi``).

Each case runs the ``hysteresis`` experiment (Fig. 14: the open-loop loop, output and input hysteresis,
and the closed-loop one), the ``contouring`` experiment at the paper's 1000 um/s only, and the
``tracking`` experiment at :data:`TRACKING_FREQS_HZ`, every closed-loop record from the stated
:data:`~nanosim.experiments.loop.LOOP_PROTOCOL` start.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nanosim import constants as C
from nanosim.pipeline import artifacts as A

__all__ = ["CASES", "TRACKING_FREQS_HZ", "COMPENSATION_UNITS", "CompensationCase", "compensation_case",
           "compensation_cases",
           "compensation_doc", "write_compensation", "compensation_task", "report_blocks"]

# (key, drive, feedforward, label) of every case, in the order of the JSON, the table and the figure
CASES = (("voltage", "voltage", None, "voltage drive"),
         ("voltage_feedforward", "voltage", "inverse-pi", "voltage drive + inverse-PI feedforward"),
         ("charge", "charge", None, "charge drive"),
         ("charge_feedforward", "charge", "inverse-pi", "charge drive + inverse-PI feedforward"))
# the tracking experiment's frequencies the step runs (its triangle and sine at each): the slowest and the
# fastest of the experiment's default 5-40 Hz, both in its definition
TRACKING_FREQS_HZ = (5.0, 40.0)

COMPENSATION_UNITS = {
    "seed": "-",
    "open_loop_output_percent": "% of the X travel: the largest vertical gap between the loop's branches "
                                "(Fig. 14 open loop, actuator A 0 -> 1.65 -> 0 V in 2 s)",
    "open_loop_input_percent": "% of the command span: the largest horizontal gap between the loop's branches",
    "open_loop_travel_um": "um (X, Y, Z at the loop's top)",
    "closed_loop_hysteresis_nm": "nm (Fig. 14 closed loop: settled up/down gap of the 20 um staircase)",
    "closed_loop_ramp_lag_nm": "nm (branch gap of the closed-loop 20 um triangle)",
    "contour_speed_um_s": "um/s",
    "contour_mean_error_nm": "nm (recorded cycle of the 45 degree contour)",
    "contour_max_error_nm": "nm",
    "axis_tracking_error_um": "um (largest X or Y tracking error on the contour)",
    "contour_ramp_lag_ms": "ms (X, Y: each axis's error per reference velocity on the contour, least squares)",
    "contour_lag_difference_us": "us (X lag - Y lag; the contour error is about this times 500 um/s at 1000 um/s)",
    "freq_hz": "Hz",
    "rms_error_nm": "nm rms (tracking, X, after the first period)",
    "max_error_nm": "nm",
    "phase_lag_deg": "degrees",
    "open_loop_output_ratio": "- (case / voltage drive, open-loop output hysteresis)",
    "contour_mean_ratio": "- (case / voltage drive, mean contour error at 1000 um/s)",
    "charge_residual_fraction": "- (ElectronicsConfig.charge_residual: hysteresis left above the crossover)",
    "charge_crossover_hz": "Hz",
    "approach_s": "s",
    "hold_s": "s",
    "feedforward_fit_s": "s of command per actuator (the identification record)",
}


@dataclass(frozen=True)
class CompensationCase:
    """One case's results: the hysteresis experiment's result, the 1000 um/s contour case, the tracking cases."""

    key: str
    drive: str
    feedforward: str | None
    label: str
    hysteresis: object
    contour: object
    tracking: list


def compensation_case(controller_npz, key: str, seed: int = 0, mjcf=None) -> CompensationCase:
    """Run the case ``key`` of :data:`CASES` on the linear twin with the controller of ``controller_npz``."""
    from nanosim.design.architectures.protocol import read_controller_file
    from nanosim.design.controller import DiscreteController
    from nanosim.experiments.contouring import contouring
    from nanosim.experiments.hysteresis import hysteresis
    from nanosim.experiments.loop import resolve_feedforward
    from nanosim.experiments.tracking import tracking
    from nanosim.paper import PAPER_CONTOUR_SPEED_UM_S
    from nanosim.pipeline.characterize import make_plant_factory, stage_config

    spec = {c[0]: c for c in CASES}
    if key not in spec:
        raise ValueError(f"key: expected one of {', '.join(spec)}, got {key!r}")
    _, drive, ff, label = spec[key]
    cfg = read_controller_file(controller_npz, dt=C.CONTROL_PERIOD_S)
    factory = make_plant_factory(True, mjcf=mjcf, config=stage_config(drive))[0]
    ffm = resolve_feedforward(factory, seed, ff)           # the identified operator, shared by the case
    hy = hysteresis(factory, DiscreteController(cfg), seed=seed, feedforward=ffm)
    (co,) = contouring(factory, DiscreteController(cfg), seed=seed, speeds_um_s=(PAPER_CONTOUR_SPEED_UM_S,),
                       feedforward=ffm)
    tr = tracking(factory, DiscreteController(cfg), seed=seed, freqs_hz=TRACKING_FREQS_HZ, feedforward=ffm)
    return CompensationCase(key, drive, ff, label, hy, co, tr)


def compensation_cases(controller_npz, seed: int = 0, mjcf=None) -> list[CompensationCase]:
    """Every case of :data:`CASES`, in order (:func:`compensation_case`)."""
    return [compensation_case(controller_npz, key, seed, mjcf) for key, *_ in CASES]


def _ratio(a, b):
    return float(a / b) if b else None


def compensation_doc(cases: list[CompensationCase], *, seed: int, controller: str = A.CONTROLLER_NPZ) -> dict:
    """``compensation.json``'s content from :func:`compensation_cases` (JSON types, units in ``units``)."""
    from nanosim.experiments.loop import FIT_RATE_V_PER_S, FIT_TURNING_POINTS_V, LOOP_PROTOCOL
    from nanosim.pipeline.characterize import stage_config

    base = next(c for c in cases if c.key == "voltage")
    e = stage_config("charge").electronics
    doc_cases = {}
    for c in cases:
        h, co = c.hysteresis, c.contour
        doc_cases[c.key] = {
            "label": c.label, "drive": c.drive, "feedforward": c.feedforward,
            "open_loop_output_percent": h.open_loop_percent, "open_loop_input_percent": h.open_loop_input_percent,
            "open_loop_travel_um": np.asarray(h.open_travel_um).tolist(),
            "closed_loop_hysteresis_nm": h.closed_loop_nm, "closed_loop_ramp_lag_nm": h.closed_ramp_lag_nm,
            "contour_speed_um_s": co.speed_um_s, "contour_mean_error_nm": co.mean_error_nm,
            "contour_max_error_nm": co.max_error_nm, "axis_tracking_error_um": co.axis_tracking_error_um,
            "contour_ramp_lag_ms": list(co.ramp_lag_ms), "contour_lag_difference_us": co.lag_difference_us,
            "tracking": [{"waveform": t.waveform, "freq_hz": t.freq_hz, "rms_error_nm": t.rms_error_nm,
                          "max_error_nm": t.max_error_nm, "phase_lag_deg": t.phase_lag_deg} for t in c.tracking],
            "open_loop_output_ratio": _ratio(h.open_loop_percent, base.hysteresis.open_loop_percent),
            "contour_mean_ratio": _ratio(co.mean_error_nm, base.contour.mean_error_nm),
        }
    travel = sum(abs(b - a) for a, b in zip(FIT_TURNING_POINTS_V[:-1], FIT_TURNING_POINTS_V[1:]))
    return {
        "plant": "linear twin (TwinStage): the 12-state linearization of the MuJoCo stage in the bench's "
                 "electromechanics, every effect on (DAC, amplifier, thermally activated hysteresis and creep, "
                 "drift, floor, gauge, ADC)",
        "seed": seed, "controller": controller,
        "experiments": "hysteresis (Fig. 14), contouring at 1000 um/s (Fig. 20), tracking (Fig. 19) at "
                       + ", ".join(f"{f:g}" for f in TRACKING_FREQS_HZ) + " Hz, as nanosim characterize --twin",
        "loop_protocol": LOOP_PROTOCOL.describe(),
        "feedforward": {"kind": "inverse-pi", "identified_on": "the case's twin (voltage- or charge-driven), before "
                                                               "the case's experiments (fit_feedforward)",
                        "feedforward_fit_s": travel / FIT_RATE_V_PER_S},
        "charge_drive": {"charge_residual_fraction": e.charge_residual, "charge_crossover_hz": e.charge_crossover_Hz,
                         "with_feedforward": "the case charge_feedforward (the operator identified on the "
                                             "charge-driven twin)"},
        "cases": doc_cases,
        "units": dict(COMPENSATION_UNITS),
    }


def write_compensation(out_dir, cases: list[CompensationCase], *, seed: int) -> Path:
    """Write ``compensation.json`` and its figure into ``out_dir`` (a run folder being written)."""
    from nanosim.fileio import save_figure, write_json
    from nanosim.plots.compensation import compensation_plot

    out = Path(out_dir)
    order = [key for key, *_ in CASES]
    cases = sorted(cases, key=lambda c: order.index(c.key))
    doc = compensation_doc(cases, seed=seed)
    loops = {c.label: (c.hysteresis.open_v, np.sign(c.hysteresis.open_travel_um[0]) * c.hysteresis.open_y_um[:, 0])
             for c in cases}
    save_figure(compensation_plot(loops, doc), out / A.FIG_COMPENSATION)
    return write_json(out / A.COMPENSATION_JSON, doc)


def compensation_task(controller_npz, key: str, seed: int, mjcf=None) -> tuple:
    """One case as a pool task: ``(case, seconds)`` (:func:`compensation_case`, its wall time [s]).

    The pipeline runs the cases beside the experiments and writes them with :func:`write_compensation`
    once all are in (one writer: the process that owns the run folder; the seconds go to ``timings.json``).
    """
    t0 = time.perf_counter()
    case = compensation_case(controller_npz, key, seed, None if mjcf is None else str(mjcf))
    return case, round(time.perf_counter() - t0, 2)


def _f(v, digits: int = 3) -> str:
    return "n/a" if not isinstance(v, (int, float)) or isinstance(v, bool) or not np.isfinite(v) else f"{v:.{digits}g}"


def report_blocks(run) -> list:
    """The report's "Hysteresis compensation" section from ``compensation.json`` (empty without it)."""
    p = Path(run) / A.COMPENSATION_JSON
    if not p.is_file():
        return []
    doc = json.loads(p.read_text())
    cases = doc.get("cases") or {}
    freqs = [t.get("freq_hz") for t in (next(iter(cases.values()), {}).get("tracking") or [])
             if t.get("waveform") == "triangle"]
    header = ["case", "open-loop output hysteresis (%)", "open-loop input hysteresis (%)", "vs voltage drive",
              "closed-loop hysteresis (nm)", "contour mean at 1000 um/s (nm)", "contour max (nm)"]
    header += [f"tracking rms, {w} {_f(f)} Hz (nm)" for w in ("triangle", "sine") for f in freqs]
    rows = []
    for c in cases.values():
        tr = {(t.get("waveform"), t.get("freq_hz")): t.get("rms_error_nm") for t in c.get("tracking") or []}
        rows.append([c.get("label", ""), _f(c.get("open_loop_output_percent")), _f(c.get("open_loop_input_percent")),
                     "x" + _f(c.get("open_loop_output_ratio"), 2), _f(c.get("closed_loop_hysteresis_nm")),
                     _f(c.get("contour_mean_error_nm")), _f(c.get("contour_max_error_nm"))]
                    + [_f(tr.get((w, f))) for w in ("triangle", "sine") for f in freqs])
    ch = doc.get("charge_drive") or {}
    proto = doc.get("loop_protocol") or {}
    out = [("h", 2, "Hysteresis compensation"),
           ("p", f"The exported controller ({doc.get('controller')}) on the {doc.get('plant')}, seed "
                 f"{doc.get('seed')}, with the bench's voltage amplifier, with the inverse Prandtl-Ishlinskii "
                 f"feedforward (identified on the twin first: nanosim characterize --feedforward inverse-pi) and "
                 f"with the charge amplifier (residual fraction {_f(ch.get('charge_residual_fraction'))}, crossover "
                 f"{_f(ch.get('charge_crossover_hz'))} Hz: nanosim characterize --drive charge), and with both (the "
                 f"feedforward identified on the charge-driven twin). Experiments: "
                 f"{doc.get('experiments')}; every closed-loop record from the stated protocol (approach "
                 f"{_f(proto.get('approach_s'))} s, hold {_f(proto.get('hold_s'))} s). Numbers and units: "
                 f"{A.COMPENSATION_JSON}; the Sec. 5 tables above are the voltage drive without compensation."),
           ("table", header, rows, None),
           ("fig", "Hysteresis compensation on the linear twin: the Fig. 14 open-loop loops and the errors per case",
            A.FIG_COMPENSATION)]
    return out
