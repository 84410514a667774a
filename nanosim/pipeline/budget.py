"""``nanosim budget``: the closed-loop noise budget of a controller, analytic, with its figures.

Each noise source's spectrum through the transfer functions of the discrete loop with the linear
twin (:mod:`nanosim.experiments.noise_budget`): per-source sigma of the reading and of the table
(the true position), their shares, the stacked PSD and the cumulative amplitude spectrum (Fleming,
"Measuring and predicting resolution in nanopositioning systems", Mechatronics 24 (2014) 605).
With ``simulate_s`` it is checked against the simulated budget: the twin in closed loop with one
source at a time (:func:`nanosim.experiments.resolution.noise_budget`) and with all of them, records of
``simulate_s`` seconds, beside the analytic budget weighted for a record of that length.

Files: ``budget.json`` (sigmas, shares, source levels, the check, units), ``budget.npz`` (the spectra)
and the figures ``fig_budget_psd.png``, ``fig_budget_cas.png``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nanosim import constants as C
from nanosim.fileio import save_figure, write_json, write_npz
from nanosim.pipeline import artifacts as A

__all__ = ["run_budget", "report_blocks", "BUDGET_UNITS"]

BUDGET_UNITS = {
    "sigma_sensor_nm": "nm rms of the reading (sensor noise and ADC included), per source and total",
    "sigma_table_nm": "nm rms of the true table position, per source and total",
    "share_table": "fraction of the table variance (the sources are independent: the shares add to 1)",
    "psd_*": "one-sided PSD, nm^2/Hz (budget.npz)",
    "freq_hz": "Hz",
    "levels": "the sources' levels as the stage configuration has them: V per sample (controller V at the DAC, "
              "input-referred amplifier), nm per sample (gauge), (m/s^2)^2/Hz (floor), V (LSB)",
    "check/record_s": "s",
    "check/ratio_total_table": "analytic / simulated total table sigma (record-weighted analytic)",
}


def _levels(cfg) -> dict:
    e, fl = cfg.electronics, cfg.floor
    return {"dac_noise_V": e.dac_noise_V if e.dac_noise else 0.0,
            "dac_flicker_corner_Hz": e.dac_flicker_corner_Hz if e.dac_noise else None,
            "amplifier_noise_V": e.amplifier_noise_V if e.amplifier_noise else 0.0,
            "gauge_noise_std_nm": e.sensor_noise_std_nm if e.sensor_noise else 0.0,
            "floor_accel_psd_m2_s4_Hz": fl.accel_psd_m2_s4_Hz if fl.enabled else 0.0,
            "dac_lsb_V": e.dac_lsb_V if e.dac_quantization else None,
            "adc_lsb_V": e.adc_lsb_V if e.adc_quantization else None,
            "computation_delay_samples": e.computation_delay_samples,
            "amplifier_bandwidth_Hz": e.amplifier_bandwidth_Hz, "gauge_bandwidth_Hz": e.gauge_bandwidth_Hz}


def _shares(sig: dict) -> dict:
    tot = sig["total"] ** 2
    return {k: (v * v / tot if tot > 0 else 0.0) for k, v in sig.items() if k != "total"}


def run_budget(out_dir, controller_npz, *, axis: int = 0, simulate_s: float | None = None, seed: int = 0,
               mjcf=None, progress=None) -> dict:
    """The analytic noise budget of ``controller_npz`` into ``out_dir`` (module docstring).

    Parameters
    ----------
    out_dir : path
        Run folder (staged by the caller).
    controller_npz : path
        ``controller.npz`` at the loop's period.
    axis : int
        0, 1, 2: X, Y, Z.
    simulate_s : float, optional
        Also simulate the budget on the twin with records of this length [s].
    seed : int
        Seed of the simulated check's noise.
    mjcf : path, optional
        Stage MJCF (default: the bundled stage).
    progress : callable, optional
        ``progress(message)`` after each step.

    Returns
    -------
    dict
        The content of ``budget.json``.
    """
    import control as ct

    from nanosim.design.architectures.common import closed_loop_spectral_radius, split_2dof
    from nanosim.design.controller import DiscreteController
    from nanosim.experiments.loop import run_closed_loop
    from nanosim.experiments.noise_budget import analytic_budget, loop_model
    from nanosim.experiments.resolution import noise_budget
    from nanosim.pipeline.characterize import make_factory
    from nanosim.plant.noise import stream_seed
    from nanosim.plots.budget import figure_budget_cas, figure_budget_psd

    say = progress or (lambda msg: None)
    out = Path(out_dir)
    ctrl = DiscreteController.from_npz(controller_npz, expected_dt=C.CONTROL_PERIOD_S)
    c = ctrl.config
    factory, base = make_factory(True, mjcf=mjcf)
    say("linearizing the stage (mechanics, piezo small-signal gain and creep)")
    lm = loop_model(base)
    K = ct.ss(c.Akd, c.Bkd, c.Ckd, c.Dkd, c.dt)
    Ke, Ky = split_2dof(K, c.n_error) if c.Bkd.shape[1] > c.n_error else (K, None)
    rho = closed_loop_spectral_radius(lm.Gm, Ke, Ky, lm.config.electronics.computation_delay_samples)
    if rho >= 1.0:
        raise ValueError(f"controller: the loop with the twin is unstable (closed-loop spectral radius {rho:.4f} >= 1):"
                         " it has no noise budget")
    ab = analytic_budget(ctrl, lm, axis=axis)
    say(f"analytic budget: total {ab.sigma_table_nm['total']:.3f} nm (table), {ab.sigma_sensor_nm['total']:.3f} nm "
        "(reading)")
    name = C.AXES[axis]
    doc = {
        "controller": str(controller_npz), "axis": name,
        "method": "analytic: each source's PSD through the closed-loop transfer functions of the discrete loop "
                  "with the linear twin (piezo small-signal gain and creep, amplifier lag, gauge filter, "
                  "computation delay), no simulation",
        "quantization": "the DAC and ADC quantizers are nonlinear; each is treated as white noise of step^2/12 "
                        "per sample",
        "band_hz": [float(ab.freq_hz[0]), float(ab.freq_hz[-1])],
        "sigma_sensor_nm": ab.sigma_sensor_nm, "sigma_table_nm": ab.sigma_table_nm,
        "share_table": _shares(ab.sigma_table_nm), "share_sensor": _shares(ab.sigma_sensor_nm),
        "levels": _levels(lm.config), "closed_loop_spectral_radius": rho,
        "units": BUDGET_UNITS,
    }
    simulated = None
    if simulate_s:
        say(f"simulating the budget on the twin ({len(ab.sigma_table_nm) - 1} sources + all, {simulate_s:g} s "
            "records)")
        rec = analytic_budget(ctrl, lm, axis=axis, record_s=simulate_s)
        st = factory(stream_seed(seed, "budget", 0))
        rows = noise_budget(st, ctrl, seed=stream_seed(seed, "budget", 1), duration_s=simulate_s, axis=axis)
        ctrl.reset()
        cl = run_closed_loop(factory(stream_seed(seed, "budget", 1)), ctrl, np.zeros((int(simulate_s / c.dt), 3)))
        simulated = {k: r["table_nm"] for k, r in rows.items()}
        simulated["total"] = float(cl.table_um[:, axis].std() * 1e3)
        sim_sensor = {k: r["sensor_nm"] for k, r in rows.items()}
        sim_sensor["total"] = float(cl.y_um[:, axis].std() * 1e3)
        doc["check"] = {
            "plant": "linear twin (same electromechanics), closed loop at rest from the bench's settle move",
            "record_s": simulate_s, "seed": seed,
            "analytic_record_weighted_table_nm": rec.sigma_table_nm,
            "analytic_record_weighted_sensor_nm": rec.sigma_sensor_nm,
            "simulated_table_nm": simulated, "simulated_sensor_nm": sim_sensor,
            "ratio_total_table": rec.sigma_table_nm["total"] / simulated["total"] if simulated["total"] else None,
            "ratio_total_sensor": (rec.sigma_sensor_nm["total"] / sim_sensor["total"]
                                   if sim_sensor["total"] else None),
            "weighting": "analytic spectra times 1 - sinc^2(f T): the variance a record of T seconds keeps about "
                         "its mean",
        }
        say(f"simulated total {simulated['total']:.3f} nm (table); analytic for the record "
            f"{rec.sigma_table_nm['total']:.3f} nm")
    write_npz(out / A.BUDGET_NPZ, freq_hz=ab.freq_hz,
              sources=np.array(list(ab.psd_table_nm2_hz)),
              psd_table_nm2_hz=np.array(list(ab.psd_table_nm2_hz.values())),
              psd_sensor_nm2_hz=np.array(list(ab.psd_sensor_nm2_hz.values())),
              units=np.array("freq_hz: Hz; psd_*: one-sided nm^2/Hz, one row per source (sources)"))
    write_json(out / A.BUDGET_JSON, doc)
    save_figure(figure_budget_psd(ab.freq_hz, ab.psd_table_nm2_hz, f"Noise budget, {name} table position: "
                                  "stacked PSD per source (analytic)"), out / A.FIG_BUDGET_PSD)
    save_figure(figure_budget_cas(ab.freq_hz, ab.psd_table_nm2_hz, ab.sigma_table_nm,
                                  f"Cumulative amplitude spectrum, {name} table position", simulated=simulated),
                out / A.FIG_BUDGET_CAS)
    return doc


def report_blocks(run) -> list:
    """The report's "Noise budget" section from ``budget.json`` (empty without it)."""
    import json
    p = Path(run) / A.BUDGET_JSON
    if not p.is_file():
        return []
    doc = json.loads(p.read_text())
    st, sy, share = doc["sigma_table_nm"], doc["sigma_sensor_nm"], doc["share_table"]
    chk = doc.get("check") or {}
    sim = chk.get("simulated_table_nm", {})
    header = ["source", "table sigma (nm)", "share of the table variance", "reading sigma (nm)"]
    if sim:
        header.append(f"simulated table sigma (nm, {chk['record_s']:g} s)")
    rows = []
    for k in [*share, "total"]:
        row = [k, f"{st[k]:.3g}", f"{share[k]:.3f}" if k in share else "1", f"{sy[k]:.3g}"]
        if sim:
            row.append(f"{sim[k]:.3g}" if k in sim else "")
        rows.append(row)
    return [("h", 2, f"Noise budget, analytic ({doc['axis']} axis)"),
            ("p", f"`nanosim budget`: each source's spectrum through the closed loop with the linear twin, analytic "
                  f"({doc['quantization']}; where a quantizer is not dithered, the simulated budget measures its "
                  f"share). Controller: `{Path(doc['controller']).name}`."),
            ("table", header, rows, None)]
