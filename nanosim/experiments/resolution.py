"""Resolution: the reading at rest, open and closed loop, with its PSD (paper Fig. 16) and a noise budget.

Closed-loop sigma is reported twice: from the sensor reading (what the paper
measured, which includes the gauge's own noise and the ADC's quantization),
and from the true table position (the motion itself). The noise budget runs
the closed loop again with one noise source at a time (every other source
off, the piezo and the loop unchanged) and reports each source's sigma and
its share of the sum of variances; for a linear loop the shares add up to the
total (the ``budget_sum_over_total`` ratio checks it).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy import signal

from nanosim.artifact_names import FIG16_RESOLUTION
from nanosim.experiments.loop import FS, StageFactory, run_closed_loop
from nanosim.experiments.registry import Experiment, register
from nanosim.plant.floor import FloorConfig
from nanosim.plant.noise import stream_seed
from nanosim.plots.experiments import fig_resolution

__all__ = ["ResolutionResult", "resolution", "noise_sources", "noise_budget"]


@dataclass(frozen=True)
class ResolutionResult:
    """Readings at rest (nm), their sigma and 95.45 / 99.73 % bands, Welch PSDs (nm^2/Hz) and the noise budget.

    ``sigma_nm`` is from the sensor reading, ``sigma_table_nm`` from the true
    table position; ``budget`` maps each source to its closed-loop sigma
    (sensor and table) and share.
    """

    open_y_nm: np.ndarray
    closed_y_nm: np.ndarray
    sigma_nm: dict
    band2_nm: dict
    band3_nm: dict
    psd_freq_hz: np.ndarray
    psd_open: np.ndarray
    psd_closed: np.ndarray
    sigma_table_nm: dict = field(default_factory=dict)
    budget: dict = field(default_factory=dict)


def _bands(x_nm):
    dev = np.abs(x_nm - x_nm.mean())
    return float(x_nm.std()), float(np.percentile(dev, 95.45)), float(np.percentile(dev, 99.73))


def noise_sources(config) -> dict:
    """``{source: StageConfig}`` with only that noise source on (quantizers count as one source).

    Sources that are off in ``config`` are left out.
    """
    e = config.electronics
    silent_e = replace(e, dac_noise=False, amplifier_noise=False, sensor_noise=False, dac_quantization=False,
                       adc_quantization=False)
    silent = replace(config, electronics=silent_e, floor=FloorConfig.off())
    out = {}
    if e.dac_noise and e.dac_noise_V > 0:
        out["DAC"] = replace(silent, electronics=replace(silent_e, dac_noise=True))
    if e.amplifier_noise and e.amplifier_noise_V > 0:
        out["amplifier"] = replace(silent, electronics=replace(silent_e, amplifier_noise=True))
    if e.sensor_noise:
        out["gauge"] = replace(silent, electronics=replace(silent_e, sensor_noise=True))
    if config.floor.enabled and config.floor.accel_psd_m2_s4_Hz > 0:
        out["floor vibration"] = replace(silent, floor=config.floor)
    if e.dac_quantization or e.adc_quantization:
        out["DAC and ADC quantization"] = replace(silent, electronics=replace(
            silent_e, dac_quantization=e.dac_quantization, adc_quantization=e.adc_quantization))
    return out


def noise_budget(stage, controller, seed=0, duration_s=2.0, axis=0) -> dict:
    """Closed-loop sigma (sensor and table, nm) with one noise source at a time, and the shares.

    ``stage`` must offer ``variant(config, seed)`` (:class:`~nanosim.plant.stage.Stage`,
    :class:`~nanosim.plant.twin.TwinStage`).
    """
    n = int(duration_s * FS)
    rows = {}
    for name, cfg in noise_sources(stage.config).items():
        controller.reset()
        cl = run_closed_loop(stage.variant(cfg, seed), controller, np.zeros((n, 3)))
        rows[name] = {"sensor_nm": float(cl.y_um[:, axis].std() * 1e3),
                      "table_nm": float(cl.table_um[:, axis].std() * 1e3)}
    for key in ("sensor", "table"):
        tot = sum(r[f"{key}_nm"] ** 2 for r in rows.values())
        for r in rows.values():
            r[f"{key}_share"] = float(r[f"{key}_nm"] ** 2 / tot) if tot > 0 else 0.0
    return rows


def resolution(factory: StageFactory, controller, seed=0, duration_s=4.0, axis=0, budget=True) -> ResolutionResult:
    """Sensor reading and table position at rest on ``axis``, open and closed loop, ``duration_s`` seconds.

    With ``budget`` (and a stage that has ``variant``) also the noise budget
    (2 s closed-loop records, one source at a time).
    """
    n = int(duration_s * FS)
    st = factory(stream_seed(seed, "resolution", 0))
    st.run(np.zeros((int(0.3 * FS), 3)))
    tr = st.run(np.zeros((n, 3)))
    y_open = tr.sensor_um[:, axis] * 1e3
    controller.reset()
    stc = factory(stream_seed(seed, "resolution", 1))
    cl = run_closed_loop(stc, controller, np.zeros((n, 3)))
    y_closed = cl.y_um[:, axis] * 1e3
    so, so2, so3 = _bands(y_open)
    sc, sc2, sc3 = _bands(y_closed)
    f, po = signal.welch(y_open - y_open.mean(), fs=FS, nperseg=2048)
    _, pc = signal.welch(y_closed - y_closed.mean(), fs=FS, nperseg=2048)
    table = {"open_loop": float(tr.table_um[:, axis].std() * 1e3),
             "closed_loop": float(cl.table_um[:, axis].std() * 1e3)}
    bud = {}
    if budget and hasattr(stc, "variant"):
        bud = noise_budget(stc, controller, seed=stream_seed(seed, "resolution", 1), axis=axis)
        tot = {k: sum(r[f"{k}_nm"] ** 2 for r in bud.values()) for k in ("sensor", "table")}
        bud = {"sources": bud, "record_s": 2.0,
               "budget_sum_over_total": {"sensor": float(np.sqrt(tot["sensor"]) / sc) if sc else 0.0,
                                         "table": float(np.sqrt(tot["table"]) / table["closed_loop"])
                                         if table["closed_loop"] else 0.0}}
    return ResolutionResult(open_y_nm=y_open, closed_y_nm=y_closed,
                            sigma_nm={"open_loop": so, "closed_loop": sc},
                            band2_nm={"open_loop": so2, "closed_loop": sc2},
                            band3_nm={"open_loop": so3, "closed_loop": sc3},
                            psd_freq_hz=f, psd_open=po, psd_closed=pc, sigma_table_nm=table, budget=bud)


def _metrics(r: ResolutionResult) -> dict:
    out = {"resolution_sigma_nm": r.sigma_nm, "resolution_2sigma_nm": r.band2_nm,
           "resolution_3sigma_nm": r.band3_nm, "resolution_sigma_table_nm": r.sigma_table_nm}
    if r.budget:
        out["noise_budget"] = r.budget
    return out


register(Experiment("resolution", run=lambda ctx: resolution(ctx.factory, ctx.controller, seed=ctx.seed),
                    metrics=_metrics, figure=lambda r, ctx: fig_resolution(r), figure_name=FIG16_RESOLUTION,
                    order=30, cost=5))
