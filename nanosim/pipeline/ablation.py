"""The paper's controller as a prediction, element by element.

Each row switches one element of the stage model (delay, amplifier, gauge,
noise spectra, hysteresis, creep, identification quality, ...) and predicts
the paper's closed-loop figures with the paper's own procedure
(:meth:`~nanosim.pipeline.config.DesignConfig.paper`: 10-state model, single
H-infinity loop, the paper's weights):

- ``redesign=True`` (the prediction): identify that stage with the paper's
  excitation, design the paper's controller on it, run the experiments on it;
- ``redesign=False`` (attribution): keep the controller designed on the
  all-on stage and change only the plant.

Mechanics: the linear twin (MuJoCo's own linearization, residualized; the
same electronics and piezo as the MuJoCo stage) by default, or MuJoCo.
Nothing here is fitted: the rows only switch modelled elements on and off.

``python tools/paper_design_ablation.py --out DIR`` writes ``ablation.json``
and ``ablation.md`` (the rows' figures); ``--mechanism CONTROLLER_NPZ`` runs
only :func:`ring_mechanism`, into ``ring_mechanism.json``.

A step of the paper's controller can ring for longer than the paper's
settling time, for two causes that the rows separate. (a) Plant inversion:
the design puts controller zeros on the first XY pair's poles (about 175 Hz),
so the closed loop keeps them at their open-loop damping
(``closed_loop_min_damping_twin`` in design.json) and every broadband input at
the plant (DAC, amplifier, floor) rings there at full resonant gain.
(b) Hysteresis with return-point memory, made to act in mid-step by creep:
see the docstring of :mod:`nanosim.plant.piezo`. :func:`ring_mechanism`
isolates (b) with every noise source off: a +2 um and a -2 um X step with
hysteresis and creep; a creep-free piezo, alone and with the Z reference first
pulled back by 0.05, 0.1 and 0.2 um (the retraction creep would have caused);
a creep-only and a linear piezo with the 0.1 um retraction. Its rows hold each
case's settling time, overshoot and rms error after 20 ms.
"""
from __future__ import annotations

import json
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from nanosim import constants as C
from nanosim.design.controller import DiscreteController
from nanosim.experiments.bandwidth import bandwidth
from nanosim.experiments.contouring import contouring
from nanosim.experiments.resolution import resolution
from nanosim.experiments.sysid import IdentifySettings, identify_stage
from nanosim.fileio import write_npz
from nanosim.paper import PAPER, PAPER_CONTOUR_SPEED_UM_S, PAPER_MODES_HZ, PAPER_PRBS_BANDS_HZ, PAPER_STEP_UM
from nanosim.pipeline import artifacts as A
from nanosim.pipeline.config import DesignConfig
from nanosim.pipeline.design import run_design
from nanosim.pipeline.identify import save_model
from nanosim.plant.electronics import ElectronicsConfig
from nanosim.plant.floor import FloorConfig, floor_model, vc_accel_psd
from nanosim.plant.linearize import linearize
from nanosim.plant.piezo import PiezoConfig
from nanosim.plant.stage import Stage, StageConfig, Trace
from nanosim.plant.twin import TwinStage

__all__ = ["AblationRow", "AblationPlant", "ablation_rows", "PAPER_TARGETS", "run_row", "run_ablation",
           "ring_mechanism", "markdown_table"]

# Paper Sec. 5, the table's header row.
PAPER_TARGETS = {"settling_ms": PAPER["settle"], "sigma_closed_nm": PAPER["sig_c"],
                 "contour_mean_nm_1000": PAPER["contour_mean"], "bandwidth_S_hz": PAPER["bwS"]}


@dataclass(frozen=True)
class AblationRow:
    """One stage variant: a name, what changed, and its :class:`StageConfig`."""

    name: str
    change: str
    config: StageConfig
    identify_ideal: bool = False          # identification quality: identify the noise-free linear stage
    model_freq_scale: float = 1.0         # identification quality: the design model's poles scaled (A, B x s)


def ablation_rows() -> list[AblationRow]:
    """The v2 stage, then one element changed at a time, then the v1 stage."""
    v2 = StageConfig()
    e, p = v2.electronics, v2.piezo
    rows = [
        AblationRow("v2", "every element on (the prediction)", v2),
        AblationRow("delay 1", "computation delay 1 sample (default 0)",
                    replace(v2, electronics=replace(e, computation_delay_samples=1))),
        AblationRow("delay 2", "computation delay 2 samples",
                    replace(v2, electronics=replace(e, computation_delay_samples=2))),
        AblationRow("no amplifier bandwidth", "amplifier instantaneous (default 10 kHz)",
                    replace(v2, electronics=replace(e, amplifier_bandwidth_Hz=None))),
        AblationRow("no gauge filter", "gauge without output filter (default 5 kHz 2-pole)",
                    replace(v2, electronics=replace(e, gauge_bandwidth_Hz=None))),
        AblationRow("gauge 1 kHz", "gauge filter 1 kHz 2-pole",
                    replace(v2, electronics=replace(e, gauge_bandwidth_Hz=1000.0))),
        AblationRow("v1 noise", "v1 noise: DAC 1.39 mV through 2 poles at 5 Hz, no flicker, amplifier or floor noise",
                    replace(v2, electronics=replace(e, dac_noise_V=1.39e-3, dac_noise_corner_Hz=5.0,
                                                    dac_flicker_corner_Hz=None, amplifier_noise=False,
                                                    thermal_drift=False),
                            floor=FloorConfig.off())),
        AblationRow("no floor", "no floor vibration", replace(v2, floor=FloorConfig.off())),
        *[AblationRow(f"floor VC-C at {f:.0f} Hz",
                      f"floor PSD {vc_accel_psd(f):.2g} (m/s^2)^2/Hz: the VC-C basis at the {f:.0f} Hz mode "
                      f"(default {C.FLOOR_ACCEL_PSD_M2_S4_HZ:.0e}, the same basis at ~11 Hz)",
                      replace(v2, floor=FloorConfig(accel_psd_m2_s4_Hz=vc_accel_psd(f))))
          for f in (PAPER_MODES_HZ[0], PAPER_MODES_HZ[2])],
        AblationRow("no noise", "no DAC, amplifier, gauge or floor noise, no thermal drift (quantization kept)",
                    replace(v2, electronics=replace(e, dac_noise=False, amplifier_noise=False, sensor_noise=False,
                                                    thermal_drift=False),
                            floor=FloorConfig.off())),
        AblationRow("no hysteresis", "piezo hysteresis off", replace(v2, piezo=replace(p, hysteresis=False))),
        AblationRow("no creep", "piezo creep off", replace(v2, piezo=replace(p, creep=False))),
        AblationRow("linear piezo", "hysteresis and creep off", replace(v2, piezo=PiezoConfig.linear())),
        AblationRow("v1 creep", "creep of v1 (10 % at 1/29 s, 1 % at 1 s and 10 s)",
                    replace(v2, piezo=PiezoConfig.calibrated_v1())),
        AblationRow("ideal identification", "controller designed on the noise-free linear stage's model", v2,
                    identify_ideal=True),
        AblationRow("model modes +1 %", "design model's poles 1 % high (A and B x 1.01, DC gain kept)", v2,
                    model_freq_scale=1.01),
        AblationRow("model modes -1 %", "design model's poles 1 % low (A and B x 0.99, DC gain kept)", v2,
                    model_freq_scale=0.99),
        AblationRow("v1 stage", "v1 electronics, v1 creep, no floor (the v1 stage model)", StageConfig.v1()),
    ]
    return rows


class AblationPlant:
    """Mechanics shared by every row: the MuJoCo model, its twin and floor model.

    ``twin=True``: rows run on the linear twin (MuJoCo's linearization) with the row's electromechanics.
    """

    def __init__(self, twin: bool, mjcf=None):
        self.base = Stage(config=StageConfig.ideal(), mjcf=mjcf)
        self.model = self.base.model
        self.twin = twin
        self.lin = linearize(self.base) if twin else None
        self.home = self.base.table_um.copy()
        self.fm = floor_model(self.model, self.base.dt_s)

    def factory(self, config: StageConfig):
        """``seed -> stage`` with this row's electromechanics on the shared mechanics."""
        if self.twin:
            return lambda seed: TwinStage(self.lin, seed=seed, config=config, home_um=self.home, floor_model=self.fm)
        return lambda seed: Stage(seed=seed, config=config, model=self.model)

    def runner(self):
        """``run_open_loop_batch`` replacement for identification on the twin."""
        if not self.twin:
            return None

        def run(u_batch, *, seeds, config=None, model=None):
            out = []
            for s, u in zip(seeds, u_batch):
                st = self.factory(config)(s)
                tr = st.run(u)
                out.append(Trace(t_s=tr.t_s, u_V=tr.u_V, piezo_V=tr.piezo_V, saturated=tr.saturated,
                                 table_um=tr.table_um, sensor_V=tr.sensor_V, sensor_um=tr.sensor_um,
                                 clipped=tr.clipped))
            return out
        return run


def _design(plant: AblationPlant, row: AblationRow, seed: int, work: Path) -> Path:
    cfg = StageConfig.ideal() if row.identify_ideal else row.config
    settings = IdentifySettings(seed=seed, ideal=row.identify_ideal, shared_poles=False, bands_hz=PAPER_PRBS_BANDS_HZ)
    res = identify_stage(settings, model=plant.model, config=cfg, runner=plant.runner())
    npz = save_model(work / A.MODEL_NPZ, res)
    if row.model_freq_scale != 1.0:
        # every pole x s, same DC gain: G_s(s) = C (s I - s A)^-1 s B + D = G(s / s_)
        import control as ct
        sc = res.sysc
        k = row.model_freq_scale
        sys_c = ct.ss(np.asarray(sc.A) * k, np.asarray(sc.B) * k, sc.C, sc.D)
        sys_d = ct.c2d(sys_c, res.sysd.dt, "tustin")
        write_npz(npz, A=sys_c.A, B=sys_c.B, C=sys_c.C, D=sys_c.D, Ad=sys_d.A, Bd=sys_d.B, Cd=sys_d.C, Dd=sys_d.D,
                  dt=res.sysd.dt)
    tw = linearize(plant.base).sys_V
    twin_npz = write_npz(work / A.TWIN_NPZ, A=tw.A, B=tw.B, C=tw.C, D=tw.D)
    try:
        run_design(npz, work, DesignConfig.paper(), twin=str(twin_npz))
    except ValueError:
        # the controller is exported before the robustness analysis; a failure there (e.g. the
        # uncertainty set's modal perturbation) does not concern this table
        if not (work / A.CONTROLLER_NPZ).is_file():
            raise
    return work / A.CONTROLLER_NPZ


def run_row(plant: AblationPlant, row: AblationRow, controller_npz, seed: int = 0) -> dict:
    """Closed-loop figures of one row with one controller (the paper's Sec. 5 quantities)."""
    ctrl = DiscreteController.from_npz(controller_npz, expected_dt=C.CONTROL_PERIOD_S)
    fac = plant.factory(row.config)
    t0 = time.perf_counter()
    bw = bandwidth(fac, DiscreteController(ctrl.config), seed=seed)
    res = resolution(fac, DiscreteController(ctrl.config), seed=seed, budget=False)
    cont = contouring(fac, DiscreteController(ctrl.config), seed=seed, speeds_um_s=(PAPER_CONTOUR_SPEED_UM_S,))[0]
    return {"settling_ms": bw.settling_ms, "overshoot_percent": bw.overshoot_percent, "rise_ms": bw.rise_ms,
            "bandwidth_S_hz": bw.bandwidth_S_hz, "sigma_closed_nm": res.sigma_nm["closed_loop"],
            "sigma_closed_table_nm": res.sigma_table_nm["closed_loop"], "sigma_open_nm": res.sigma_nm["open_loop"],
            "contour_mean_nm_1000": cont.mean_error_nm, "seconds": round(time.perf_counter() - t0, 1)}


def run_ablation(out_dir, *, seed: int = 0, twin: bool = True, redesign: bool = True, rows=None,
                 mjcf=None, log=print, progress: bool = False) -> dict:
    """Run the rows (all by default); returns the table as a dict (also the JSON's content).

    ``progress``: a bar on stderr naming the running row, with an ETA.
    """
    plant = AblationPlant(twin, mjcf)
    all_rows = ablation_rows()
    chosen = [r for r in all_rows if rows is None or r.name in rows]
    unknown = set(rows or ()) - {r.name for r in all_rows}
    if unknown:
        raise ValueError(f"rows: unknown {sorted(unknown)}; expected some of {[r.name for r in all_rows]}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = {"seed": seed, "mechanics": "twin" if twin else "mujoco", "redesign": redesign,
              "targets": PAPER_TARGETS, "rows": []}
    bar = None
    if progress:
        import sys

        from tqdm import tqdm
        bar = tqdm(total=len(chosen), desc="ablation", unit="row", file=sys.stderr)
    with tempfile.TemporaryDirectory() as tmp:
        base_ctrl = None
        if not redesign:
            base_ctrl = _design(plant, all_rows[0], seed, Path(tmp) / "v2")
        for row in chosen:
            if bar is not None:
                bar.set_postfix_str(f"running {row.name}")
            t0 = time.perf_counter()
            work = Path(tmp) / row.name.replace(" ", "_")
            work.mkdir(parents=True, exist_ok=True)
            try:
                ctrl = _design(plant, row, seed, work) if redesign else base_ctrl
                m = run_row(plant, row, ctrl, seed)
            except Exception as exc:            # one failing row (e.g. a design error) must not lose the others
                m = {k: float("nan") for k in ("settling_ms", "overshoot_percent", "rise_ms", "bandwidth_S_hz",
                                               "sigma_closed_nm", "sigma_closed_table_nm", "sigma_open_nm",
                                               "contour_mean_nm_1000")}
                m["error"] = f"{type(exc).__name__}: {exc}"
            m.update(name=row.name, change=row.change, seconds=round(time.perf_counter() - t0, 1))
            result["rows"].append(m)
            (out / A.ABLATION_PARTIAL_JSON).write_text(json.dumps(result, indent=1))
            if bar is not None:
                bar.update(1)
            log(f"{row.name:22s} settle {m['settling_ms']:7.1f} ms  sigma {m['sigma_closed_nm']:5.2f} nm "
                f"(table {m['sigma_closed_table_nm']:5.2f})  contour {m['contour_mean_nm_1000']:6.1f} nm  "
                f"S-BW {m['bandwidth_S_hz']:5.1f} Hz  ({m['seconds']} s) {m.get('error', '')}", flush=True)
    if bar is not None:
        bar.close()
    return result


def ring_mechanism(controller_npz, *, seed: int = 1, twin: bool = True, mjcf=None,
                   step_um: float = PAPER_STEP_UM) -> list:
    """The step with noise off, with and without creep and a pre-step Z retraction (see the module docstring).

    Returns rows ``{case, settling_ms, overshoot_percent, rms_after_20ms_nm}``.
    """
    from nanosim.experiments.loop import FS, run_closed_loop, step_metrics
    plant = AblationPlant(twin, mjcf)
    quiet = replace(StageConfig.ideal(), electronics=ElectronicsConfig.ideal(
        computation_delay_samples=StageConfig().electronics.computation_delay_samples))
    p = StageConfig().piezo
    cases = [("hysteresis + creep, +X step", p, step_um, 0.0), ("hysteresis + creep, -X step", p, -step_um, 0.0),
             ("hysteresis only", replace(p, creep=False), step_um, 0.0)]
    cases += [(f"hysteresis only, Z pulled back {r:g} um before the step", replace(p, creep=False), step_um, r)
              for r in (0.05, 0.1, 0.2)]
    cases += [("creep only, Z pulled back 0.1 um", replace(p, hysteresis=False), step_um, 0.1),
              ("linear piezo, Z pulled back 0.1 um", PiezoConfig.linear(), step_um, 0.1)]
    ctrl = DiscreteController.from_npz(controller_npz, expected_dt=C.CONTROL_PERIOD_S)
    out = []
    for name, pz, s_um, back in cases:
        k0, ns, nb = int(0.05 * FS), int(0.3 * FS), int(0.03 * FS)
        ref = np.zeros((k0 + ns, 3))
        ref[:nb, 2] = -back * 0.5 * (1 - np.cos(np.pi * np.arange(nb) / nb))
        ref[nb:, 2] = -back
        ref[k0:, 0] = s_um
        cl = run_closed_loop(plant.factory(replace(quiet, piezo=pz))(seed), DiscreteController(ctrl.config), ref)
        t = cl.t_s[k0:] - cl.t_s[k0]
        y = cl.y_um[k0:, 0] - cl.y_um[k0 - 40:k0, 0].mean()
        _, _, settle, over = step_metrics(t, y, s_um)
        e = y[int(0.02 * FS):] - s_um
        out.append({"case": name, "settling_ms": float(settle), "overshoot_percent": float(over),
                    "rms_after_20ms_nm": float(1e3 * np.sqrt(np.mean(e ** 2)))})
    return out


def markdown_table(result: dict) -> str:
    """The ablation as a Markdown table (paper targets in the header row)."""
    t = result["targets"]
    head = ("| row | change | settling (ms) | sigma closed, sensor (nm) | sigma closed, table (nm) | "
            "contour mean at 1000 um/s (nm) | S bandwidth (Hz) |\n|---|---|---|---|---|---|---|\n"
            f"| paper | | {t['settling_ms']:g} | {t['sigma_closed_nm']:g} | | {t['contour_mean_nm_1000']:g} | "
            f"{t['bandwidth_S_hz']:g} |\n")
    lines = [f"| {r['name']} | {r['change']} | {r['settling_ms']:.1f} | {r['sigma_closed_nm']:.2f} | "
             f"{r['sigma_closed_table_nm']:.2f} | {r['contour_mean_nm_1000']:.0f} | {r['bandwidth_S_hz']:.1f} |"
             for r in result["rows"]]
    return head + "\n".join(lines) + "\n"
