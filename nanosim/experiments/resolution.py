"""Resolution: the reading at rest, open and closed loop, with its PSD (paper Fig. 16) and a noise budget.

Closed-loop sigma is reported twice: from the sensor reading (what the paper
measured, which includes the gauge's own noise and the ADC's quantization),
and from the true table position (the motion itself). The open-loop record
starts :data:`OPEN_REST_S` after the stage was made (at home, zero command);
the closed-loop record follows :data:`RESOLUTION_PROTOCOL`: the common approach
and a hold of :data:`STEADY_HOLD_S`, a steady state. The approach excites the
first mode pair, which a design that inverts the plant leaves at open-loop
damping (the paper: damping factors below 0.01; at zeta = 0.004 and 176 Hz the
time constant 1 / (zeta omega) is 0.23 s); 2 s is about nine of them, so the
record holds noise, not the approach's ring.

The noise budget runs both records again with one noise source at a time
(every other source off, the piezo and the loop unchanged; :func:`noise_sources`):
the broadband input-side sources (DAC electronics, DAC quantization,
amplifier), the floor, the sensor-side sources (gauge, ADC quantization), and
the low-frequency drift (the legs' thermal expansion). It reports each
source's sigma, its share of the sum of variances, open and closed loop, and
each source's PSD. For a linear chain the variances add up to the total (the
``budget_sum_over_total`` ratios check it); the quantizers, alone, are not
dithered and need not add. Each quantizer's marginal share is measured as well:
the closed loop with every source on but that one, its variance subtracted from
the total's. An undithered DAC whose command follows the drift and the creep
steps through its codes, and each step of one LSB rings the modes the loop
leaves lightly damped: how often it steps depends on the other sources (alone,
only the creep after the approach moves it), so its share alone and its
marginal share differ, either way.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy import signal

from nanosim.artifact_names import FIG16_RESOLUTION
from nanosim.experiments.loop import FS, LOOP_PROTOCOL, StageFactory, run_closed_loop
from nanosim.experiments.registry import Experiment, register
from nanosim.plant.floor import FloorConfig
from nanosim.plant.noise import stream_seed
from nanosim.plots.experiments import fig_resolution

__all__ = ["ResolutionResult", "resolution", "noise_sources", "noise_sources_without", "noise_budget",
           "QUANTIZERS", "OPEN_REST_S", "RECORD_S",
           "STEADY_HOLD_S", "RESOLUTION_PROTOCOL"]

OPEN_REST_S = 0.3           # at rest from home before the open-loop record [s]
RECORD_S = 4.0              # the records at rest [s]
STEADY_HOLD_S = 2.0         # hold at the origin before the closed-loop records [s]
RESOLUTION_PROTOCOL = LOOP_PROTOCOL.with_hold(STEADY_HOLD_S)
_NPERSEG = 2048             # Welch segments (0.5 s, 2 Hz resolution)


@dataclass(frozen=True)
class ResolutionResult:
    """Readings at rest (nm), their sigma and 95.45 / 99.73 % bands, Welch PSDs (nm^2/Hz) and the noise budget.

    ``sigma_nm`` is from the sensor reading, ``sigma_table_nm`` from the true
    table position; ``budget`` maps each source to its sigma (open loop, closed
    loop sensor and table) and shares; ``budget_psd`` maps each source to its
    open- and closed-loop reading PSDs (nm^2/Hz on ``psd_freq_hz``).
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
    budget_psd: dict = field(default_factory=dict)


def _bands(x_nm):
    dev = np.abs(x_nm - x_nm.mean())
    return float(x_nm.std()), float(np.percentile(dev, 95.45)), float(np.percentile(dev, 99.73))


# The electronics switch of each source (the floor is a mechanical input, switched by its own config).
_SWITCHES = {"DAC electronics": "dac_noise", "DAC quantization": "dac_quantization", "amplifier": "amplifier_noise",
             "thermal drift": "thermal_drift", "floor vibration": None, "gauge": "sensor_noise",
             "ADC quantization": "adc_quantization"}
# The sources that do not superpose: an undithered quantizer's error depends on the signal it quantizes (the DAC's
# on the command that follows the drift and the creep, stepping through its codes), so alone it is not its share.
QUANTIZERS = ("DAC quantization", "ADC quantization")


def _active_sources(config) -> list:
    """The sources that are on in ``config`` (with a level above zero), in the order of the chain."""
    e = config.electronics
    level = {"DAC electronics": e.dac_noise_V, "amplifier": e.amplifier_noise_V, "thermal drift": e.thermal_drift_K,
             "floor vibration": config.floor.accel_psd_m2_s4_Hz if config.floor.enabled else 0.0}
    return [name for name, flag in _SWITCHES.items()
            if (flag is None or getattr(e, flag)) and level.get(name, 1.0) > 0]


def _with_sources(config, on) -> object:
    """``config`` with exactly the sources in ``on`` switched on (the piezo and the loop unchanged)."""
    flags = {flag: name in on for name, flag in _SWITCHES.items() if flag is not None}
    floor = config.floor if "floor vibration" in on else FloorConfig.off()
    return replace(config, electronics=replace(config.electronics, **flags), floor=floor)


def noise_sources(config) -> dict:
    """``{source: StageConfig}`` with only that noise source on.

    Sources, in the order of the chain: ``DAC electronics`` (white and flicker),
    ``DAC quantization``, ``amplifier``, ``thermal drift``, ``floor vibration``,
    ``gauge``, ``ADC quantization``. Sources that are off in ``config`` are left out.
    """
    return {name: _with_sources(config, {name}) for name in _active_sources(config)}


def noise_sources_without(config) -> dict:
    """``{source: StageConfig}`` with every source of ``config`` on except that one (:func:`noise_sources`'s names)."""
    active = _active_sources(config)
    return {name: _with_sources(config, set(active) - {name}) for name in active}


def _open_record(stage, n: int):
    """The open-loop record: ``OPEN_REST_S`` at rest from home, then ``n`` samples at zero command."""
    stage.run(np.zeros((int(round(OPEN_REST_S * FS)), 3)))
    return stage.run(np.zeros((n, 3)))


def _psd(x_nm):
    return signal.welch(x_nm - x_nm.mean(), fs=FS, nperseg=min(_NPERSEG, len(x_nm)))


def _shares(rows: dict, key: str) -> None:
    tot = sum(r[key] ** 2 for r in rows.values())
    for r in rows.values():
        r[key.replace("_nm", "_share")] = float(r[key] ** 2 / tot) if tot > 0 else 0.0


def noise_budget(stage, controller, seed=0, duration_s=RECORD_S, axis=0, open_loop=True, spectra=None,
                 open_seed=None, total_nm=None) -> dict:
    """Sigma (nm) with one noise source at a time, open loop and closed loop, and each source's share.

    ``stage`` must offer ``variant(config, seed)`` (:class:`~nanosim.plant.stage.Stage`,
    :class:`~nanosim.plant.twin.TwinStage`). Per source: ``open_loop_nm`` (the reading,
    open-loop record) and, closed loop, ``sensor_nm`` (the reading) and ``table_nm``
    (the true position), each with its ``*_share`` of the sum of variances. A dict passed as
    ``spectra`` receives ``{source: (freq_hz, psd_open, psd_closed)}`` (nm^2/Hz; ``psd_open``
    None without ``open_loop``). The open-loop records use ``open_seed`` (default ``seed``): with the
    seed of a measured total each source draws the very noise it adds there.

    ``total_nm`` (``{"sensor_nm": ..., "table_nm": ...}``, the closed-loop sigmas of the record with
    every source on and the same ``seed``) adds, for each quantizer (:data:`QUANTIZERS`), its marginal
    share: the closed loop again with every source on but that one (``sensor_without_nm``,
    ``table_without_nm``) and ``sensor_marginal_nm = sqrt(total^2 - without^2)`` (0 when negative), the
    same for the table. A linear source's marginal variance is its variance alone; an undithered
    quantizer's is not, since its error depends on the signal it quantizes.
    """
    n = int(duration_s * FS)
    rows = {}
    without = noise_sources_without(stage.config) if total_nm else {}
    for name, cfg in noise_sources(stage.config).items():
        row, po = {}, None
        if open_loop:
            st = stage.variant(cfg, seed if open_seed is None else open_seed)
            y_open = _open_record(st, n).sensor_um[:, axis] * 1e3
            row["open_loop_nm"] = float(y_open.std())
            _, po = _psd(y_open)
        cl = run_closed_loop(stage.variant(cfg, seed), controller, np.zeros((n, 3)), protocol=RESOLUTION_PROTOCOL)
        y_closed = cl.y_um[:, axis] * 1e3
        row.update(sensor_nm=float(y_closed.std()), table_nm=float(cl.table_um[:, axis].std() * 1e3))
        if name in QUANTIZERS and name in without:
            rest = run_closed_loop(stage.variant(without[name], seed), controller, np.zeros((n, 3)),
                                   protocol=RESOLUTION_PROTOCOL)
            for key, sig in (("sensor", float((rest.y_um[:, axis] * 1e3).std())),
                             ("table", float(rest.table_um[:, axis].std() * 1e3))):
                row[f"{key}_without_nm"] = sig
                row[f"{key}_marginal_nm"] = float(np.sqrt(max(total_nm[f"{key}_nm"] ** 2 - sig ** 2, 0.0)))
        rows[name] = row
        if spectra is not None:
            f, pc = _psd(y_closed)
            spectra[name] = (f, po, pc)
    for key in ("open_loop_nm", "sensor_nm", "table_nm") if open_loop else ("sensor_nm", "table_nm"):
        _shares(rows, key)
    return rows


def _marginal_sum(rows: dict, key: str) -> float:
    """The root of the sum of variances with each quantizer's marginal sigma in place of its sigma alone."""
    return float(np.sqrt(sum(r.get(f"{key}_marginal_nm", r[f"{key}_nm"]) ** 2 for r in rows.values())))


def resolution(factory: StageFactory, controller, seed=0, duration_s=RECORD_S, axis=0,
               budget=True) -> ResolutionResult:
    """Sensor reading and table position at rest on ``axis``, open and closed loop, ``duration_s`` seconds.

    With ``budget`` (and a stage that has ``variant``) also the noise budget
    (:func:`noise_budget`, records of the same length, one source at a time).
    """
    n = int(duration_s * FS)
    tr = _open_record(factory(stream_seed(seed, "resolution", 0)), n)
    y_open = tr.sensor_um[:, axis] * 1e3
    stc = factory(stream_seed(seed, "resolution", 1))
    cl = run_closed_loop(stc, controller, np.zeros((n, 3)), protocol=RESOLUTION_PROTOCOL)
    y_closed = cl.y_um[:, axis] * 1e3
    so, so2, so3 = _bands(y_open)
    sc, sc2, sc3 = _bands(y_closed)
    f, po = _psd(y_open)
    _, pc = _psd(y_closed)
    table = {"open_loop": float(tr.table_um[:, axis].std() * 1e3),
             "closed_loop": float(cl.table_um[:, axis].std() * 1e3)}
    bud, spectra = {}, {}
    if budget and hasattr(stc, "variant"):
        ref = {"open_loop_nm": so, "sensor_nm": sc, "table_nm": table["closed_loop"]}
        rows = noise_budget(stc, controller, seed=stream_seed(seed, "resolution", 1), duration_s=duration_s,
                            axis=axis, spectra=spectra, open_seed=stream_seed(seed, "resolution", 0),
                            total_nm={"sensor_nm": sc, "table_nm": ref["table_nm"]})
        tot = {k: float(np.sqrt(sum(r[k] ** 2 for r in rows.values())))
               for k in ("open_loop_nm", "sensor_nm", "table_nm")}
        ratio = (lambda x, k: x / ref[k] if ref[k] else 0.0)
        bud = {"sources": rows, "record_s": float(duration_s), "axis": "XYZ"[axis],
               "open_loop_rest_s": OPEN_REST_S, "closed_loop_protocol": RESOLUTION_PROTOCOL.describe(),
               "quantizers_marginal": [q for q in QUANTIZERS if q in rows],
               "budget_sum_over_total": {"open_loop": ratio(tot["open_loop_nm"], "open_loop_nm"),
                                         "sensor": ratio(tot["sensor_nm"], "sensor_nm"),
                                         "table": ratio(tot["table_nm"], "table_nm"),
                                         "sensor_marginal": ratio(_marginal_sum(rows, "sensor"), "sensor_nm"),
                                         "table_marginal": ratio(_marginal_sum(rows, "table"), "table_nm")}}
    return ResolutionResult(open_y_nm=y_open, closed_y_nm=y_closed,
                            sigma_nm={"open_loop": so, "closed_loop": sc},
                            band2_nm={"open_loop": so2, "closed_loop": sc2},
                            band3_nm={"open_loop": so3, "closed_loop": sc3},
                            psd_freq_hz=f, psd_open=po, psd_closed=pc, sigma_table_nm=table, budget=bud,
                            budget_psd=spectra)


def _metrics(r: ResolutionResult) -> dict:
    out = {"resolution_sigma_nm": r.sigma_nm, "resolution_2sigma_nm": r.band2_nm,
           "resolution_3sigma_nm": r.band3_nm, "resolution_sigma_table_nm": r.sigma_table_nm}
    if r.budget:
        out["noise_budget"] = r.budget
    return out


register(Experiment("resolution", run=lambda ctx: resolution(ctx.factory, ctx.controller, seed=ctx.seed),
                    metrics=_metrics, figure=lambda r, ctx: fig_resolution(r), figure_name=FIG16_RESOLUTION,
                    order=30, cost=5))
