"""``nanosim characterize``: run the Section 5 experiments, write metrics.json and figures."""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

from nanosim import constants as C
from nanosim.experiments import section5 as E
from nanosim.fileio import save_figure, write_json
from nanosim.design.controller import DiscreteController
from nanosim.plant.linearize import linearize
from nanosim.plant.modes import modal_analysis
from nanosim.plant.stage import Stage, StageConfig


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def make_factory(twin: bool, mjcf=None, config: StageConfig | None = None):
    """Stage factory: the MuJoCo stage, or the linear twin in the same electromechanics."""
    base = Stage(config=config, mjcf=mjcf)
    if not twin:
        model = base.model
        return lambda seed: Stage(seed=seed, config=config, model=model), base
    lin = linearize(Stage(config=StageConfig.ideal(), model=base.model))
    home = base.table_um.copy()
    return lambda seed: E.TwinStage(lin, seed=seed, config=config, home_um=home), base


# -- figures ---------------------------------------------------------------------------
def fig_hysteresis(r: E.HysteresisResult, path):
    plt = _plt()
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.4))
    for i, ax_name in enumerate("XYZ"):
        ax[0].plot(r.open_v, r.open_y_um[:, i], label=ax_name)
    ax[0].set_xlabel("actuator A command (controller V)")
    ax[0].set_ylabel("displacement (um)")
    ax[0].set_title(f"(a) open loop: output hysteresis {r.open_loop_percent:.1f} % of X travel")
    ax[0].legend()
    ax[0].grid(alpha=0.3)
    ref, y = r.closed.ref_um[:, 0], r.closed.y_um[:, 0]
    ax[1].plot(ref, (y - ref) * 1e3, lw=0.6, label="continuous triangle (tracking error)")
    ax[1].plot(r.closed_levels_um, (r.closed_up_um - r.closed_levels_um) * 1e3, "o-", label="settled, going up")
    ax[1].plot(r.closed_levels_um, (r.closed_down_um - r.closed_levels_um) * 1e3, "s--", label="settled, going down")
    ax[1].set_xlabel("X reference (um)")
    ax[1].set_ylabel("X output - reference (nm)")
    ax[1].set_title(f"(b) closed loop: settled hysteresis {r.closed_loop_nm:.1f} nm, ramp lag {r.closed_ramp_lag_nm:.0f} nm")
    ax[1].legend(fontsize=8, loc="center", bbox_to_anchor=(0.5, 0.7))   # in the empty band above the settled points
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def fig_creep(r: E.CreepResult, path):
    plt = _plt()
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2), sharey=False)
    for a, (y, title, d) in zip(ax, ((r.open_y_um, "open loop (inverse static gain)", r.open_drift_nm),
                                     (r.closed_y_um, "closed loop (H-infinity)", r.closed_drift_nm))):
        k0 = int(0.5 * C.CONTROL_RATE_HZ)
        for i, n in enumerate("XYZ"):
            a.plot(r.t_s, (y[:, i] - y[k0:k0 + 800, i].mean()) * 1e3, lw=0.6,
                   label=f"{n}: drift {d[i]:+.1f} nm")
        a.set_xlabel("time since reaching the origin (s)")
        a.set_ylabel("position - position at 0.5 s (nm)")
        a.set_title(f"{title}, hold {r.hold_s:.0f} s")
        a.legend(fontsize=8)
        a.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def fig_resolution(r: E.ResolutionResult, path):
    plt = _plt()
    fig, ax = plt.subplots(2, 2, figsize=(11, 7))
    t = np.arange(len(r.open_y_nm)) / C.CONTROL_RATE_HZ
    for j, (y, lab) in enumerate(((r.open_y_nm, "open_loop"), (r.closed_y_nm, "closed_loop"))):
        ax[0, j].plot(t, y - y.mean(), lw=0.4)
        s = r.sigma_nm[lab]
        ax[0, j].set_title(f"({'ab'[j]}) {lab.replace('_', ' ')}: sigma {s:.2f} nm, "
                           f"95.45 % {r.band2_nm[lab]:.1f} nm, 99.73 % {r.band3_nm[lab]:.1f} nm", fontsize=9)
        for k in (1, 2, 3):
            ax[0, j].axhline(k * s, color="0.5", lw=0.6, ls=":")
            ax[0, j].axhline(-k * s, color="0.5", lw=0.6, ls=":")
        ax[0, j].set_xlabel("time (s)")
        ax[0, j].set_ylabel("X probe (nm)")
        psd = r.psd_open if j == 0 else r.psd_closed
        ax[1, j].loglog(r.psd_freq_hz[1:], psd[1:])
        ax[1, j].set_xlabel("frequency (Hz)")
        ax[1, j].set_ylabel("PSD (nm^2/Hz)")
        ax[1, j].set_title(f"({'cd'[j]}) output PSD, no input")
        ax[1, j].grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def fig_small_steps(r: E.SmallStepsResult, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.plot(r.trace.t_s, r.trace.ref_um[:, 0] * 1e3, label="reference")
    ax.plot(r.trace.t_s, r.trace.y_um[:, 0] * 1e3, lw=0.6, label="X probe")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("X (nm)")
    txt = ", ".join(f"{m:.1f}" for m in r.plateau_mean_nm)
    ax.set_title(f"10 nm steps, plateau means (nm): {txt}", fontsize=9)
    ax.legend()
    ax.grid(alpha=0.3)
    return save_figure(fig, path)


def fig_bandwidth(r: E.BandwidthResult, path, predicted=None):
    plt = _plt()
    fig, ax = plt.subplots(1, 3, figsize=(14, 4.2))
    ax[0].semilogx(r.freq_hz, 20 * np.log10(r.sigma_S), label="measured on the stage (H1)")
    ax[1].semilogx(r.freq_hz, 20 * np.log10(r.sigma_T), label="measured on the stage (H1)")
    if predicted is not None:
        f, sS, sT = predicted
        ax[0].semilogx(f, 20 * np.log10(sS), "--", label="predicted (linear twin + K)")
        ax[1].semilogx(f, 20 * np.log10(sT), "--", label="predicted (linear twin + K)")
    for a, title, b in ((ax[0], "(a) largest singular value of S", r.bandwidth_S_hz),
                        (ax[1], "(b) largest singular value of T", r.bandwidth_T_hz)):
        a.axhline(-3.01, color="0.5", ls=":", lw=0.8)
        a.axvline(b, color="tab:red", lw=0.8)
        a.set_title(f"{title}: -3 dB at {b:.1f} Hz", fontsize=10)
        a.set_xlabel("frequency (Hz)")
        a.set_ylabel("dB")
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    k0 = int(0.01 * C.CONTROL_RATE_HZ)
    t = (r.step.t_s - r.step.t_s[k0]) * 1e3
    ax[2].plot(t, r.step.ref_um[:, 0], label="reference")
    ax[2].plot(t, r.step.y_um[:, 0], label="X probe")
    ax[2].set_xlabel("time (ms)")
    ax[2].set_ylabel("X (um)")
    ax[2].set_title(f"(c) 2 um step: rise {r.rise_ms:.1f} ms, peak {r.peak_ms:.1f} ms, settle {r.settling_ms:.1f} ms, "
                    f"overshoot {r.overshoot_percent:.1f} %", fontsize=9)
    ax[2].legend()
    ax[2].grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def fig_tracking(cases, path):
    plt = _plt()
    freqs = sorted({c.freq_hz for c in cases})
    fig, ax = plt.subplots(2, len(freqs), figsize=(3.2 * len(freqs), 6))
    for c in cases:
        i = 0 if c.waveform == "triangle" else 1
        j = freqs.index(c.freq_hz)
        a = ax[i, j]
        a.plot(c.trace.t_s * 1e3, c.trace.ref_um[:, 0], ":", label="reference")
        a.plot(c.trace.t_s * 1e3, c.trace.y_um[:, 0], label="output")
        a.set_title(f"{c.waveform} {c.freq_hz:g} Hz\nrms err {c.rms_error_nm:.0f} nm, lag {c.phase_lag_deg:.0f} deg",
                     fontsize=9)
        a.set_xlabel("time (ms)")
        if j == 0:
            a.set_ylabel("X (um)")
        a.grid(alpha=0.3)
    ax[0, 0].legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


def fig_contouring(cases, path):
    plt = _plt()
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
    v = [c.speed_um_s for c in cases]
    ax[0].loglog(v, [c.mean_error_nm for c in cases], "o-", label="mean contour error")
    ax[0].loglog(v, [c.max_error_nm for c in cases], "s--", label="max contour error")
    ax[0].set_xlabel("speed along the 45 degree line (um/s)")
    ax[0].set_ylabel("contour error (nm)")
    ax[0].set_title("(a) contour error vs speed")
    ax[0].legend()
    ax[0].grid(True, which="both", alpha=0.3)
    fast = max(cases, key=lambda c: c.speed_um_s)
    e = fast.trace.error_um
    ax[1].plot(fast.trace.t_s * 1e3, e[:, 0], label="X tracking error")
    ax[1].plot(fast.trace.t_s * 1e3, e[:, 1], "--", label="Y tracking error")
    ax[1].plot(fast.trace.t_s * 1e3, (fast.trace.y_um[:, 0] - fast.trace.y_um[:, 1]) / np.sqrt(2), label="contour error")
    ax[1].set_xlabel("time (ms)")
    ax[1].set_ylabel("error (um)")
    ax[1].set_title(f"(b) following errors at {fast.speed_um_s:g} um/s", fontsize=10)
    ax[1].legend()
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def predicted_loop(controller: DiscreteController, base: Stage, f_hz=None):
    """sigma(S), sigma(T) of the discrete loop with the linear twin (piezo small-signal gain included)."""
    tw = linearize(base, include_piezo=True)
    G = tw.sysd_V
    c = controller.config
    f = np.logspace(0, 3, 400) if f_hz is None else f_hz
    z = np.exp(2j * np.pi * f * c.dt)
    sS, sT = [], []
    for zz in z:
        Gz = G(zz)
        Kz = c.Ckd @ np.linalg.solve(zz * np.eye(len(c.Akd)) - c.Akd, c.Bkd) + c.Dkd
        Ke, Ky = Kz[:, :c.n_error], Kz[:, c.n_error:]         # u = Ke e + Ky y (Ky empty for 1-DOF)
        K_fb = Ke - Ky if Ky.size else Ke
        T = np.linalg.solve(np.eye(3) + Gz @ K_fb, Gz @ Ke)   # r -> y
        sS.append(np.linalg.svd(np.eye(3) - T, compute_uv=False)[0])
        sT.append(np.linalg.svd(T, compute_uv=False)[0])
    return f, np.array(sS), np.array(sT)


# rough cost order (longest first) so two workers finish together
_COST_ORDER = ("creep", "contouring", "resolution", "tracking", "hysteresis", "bandwidth", "small_steps")


def _run_experiment(name, factory, controller, seed, G0):
    if name == "hysteresis":
        return E.hysteresis(factory, controller, seed=seed)
    if name == "creep":
        return E.creep(factory, controller, G0, seed=seed)
    if name == "resolution":
        return E.resolution(factory, controller, seed=seed)
    if name == "small_steps":
        return E.small_steps(factory, controller, seed=seed)
    if name == "bandwidth":
        return E.bandwidth(factory, controller, seed=seed)
    if name == "tracking":
        return E.tracking(factory, controller, seed=seed)
    return E.contouring(factory, controller, seed=seed)


def _record(name, r, metrics: dict, out: Path, controller, base) -> None:
    """Metrics and figure of one experiment (main thread: matplotlib is not thread-safe)."""
    if name == "hysteresis":
        metrics["hysteresis"] = {"open_loop_percent": r.open_loop_percent,
                                 "open_loop_input_percent": r.open_loop_input_percent,
                                 "open_loop_travel_um": r.open_travel_um.tolist(),
                                 "closed_loop_nm": r.closed_loop_nm, "closed_loop_percent": r.closed_loop_percent,
                                 "closed_loop_ramp_lag_nm": r.closed_ramp_lag_nm}
        fig_hysteresis(r, out / "fig14_hysteresis.png")
    elif name == "creep":
        metrics["creep"] = {"open_loop_drift_nm": float(np.linalg.norm(r.open_drift_nm)),
                            "closed_loop_drift_nm": float(np.linalg.norm(r.closed_drift_nm)),
                            "open_loop_drift_xyz_nm": r.open_drift_nm.tolist(),
                            "closed_loop_drift_xyz_nm": r.closed_drift_nm.tolist(), "hold_s": r.hold_s}
        fig_creep(r, out / "fig15_creep.png")
    elif name == "resolution":
        metrics["resolution_sigma_nm"] = r.sigma_nm
        metrics["resolution_2sigma_nm"] = r.band2_nm
        metrics["resolution_3sigma_nm"] = r.band3_nm
        fig_resolution(r, out / "fig16_resolution.png")
    elif name == "small_steps":
        metrics["small_steps"] = {"targets_nm": r.targets_nm.tolist(), "plateau_means_nm": r.plateau_mean_nm.tolist(),
                                  "plateau_sigma_nm": r.plateau_sigma_nm.tolist()}
        fig_small_steps(r, out / "fig17_small_steps.png")
    elif name == "bandwidth":
        metrics["bandwidth_S_hz"] = r.bandwidth_S_hz
        metrics["bandwidth_T_hz"] = r.bandwidth_T_hz
        metrics["step_2um"] = {"rise_ms": r.rise_ms, "peak_ms": r.peak_ms, "settling_ms": r.settling_ms,
                               "overshoot_percent": r.overshoot_percent}
        fig_bandwidth(r, out / "fig18_bandwidth_step.png", predicted=predicted_loop(controller, base))
    elif name == "tracking":
        metrics["tracking"] = [{"waveform": c.waveform, "freq_hz": c.freq_hz, "rms_error_nm": c.rms_error_nm,
                                "max_error_nm": c.max_error_nm, "phase_lag_deg": c.phase_lag_deg} for c in r]
        fig_tracking(r, out / "fig19_tracking.png")
    elif name == "contouring":
        metrics["contouring"] = [{"speed_um_s": c.speed_um_s, "mean_error_nm": c.mean_error_nm,
                                  "max_error_nm": c.max_error_nm,
                                  "axis_tracking_error_um": c.axis_tracking_error_um} for c in r]
        fig_contouring(r, out / "fig20_contouring.png")


def run_characterize(controller_path, out_dir, *, seed: int = 0, only=None, twin: bool = False, mjcf=None,
                     progress: bool = True, workers: int | None = None) -> dict:
    """Run the experiments; write metrics.json (merged with an existing one for ``only``) and figures.

    Experiments are independent (fresh stage and controller each), so they run
    on ``workers`` threads (default: up to 2); MuJoCo steps without the GIL.
    Results do not depend on the number of workers.
    """
    from concurrent.futures import ThreadPoolExecutor, as_completed

    out = Path(out_dir)
    ctrl = DiscreteController.from_npz(controller_path)
    names = list(E.EXPERIMENTS) if not only else [only]
    unknown = [n for n in names if n not in E.EXPERIMENTS]
    if unknown:
        raise ValueError(f"only: unknown experiment {unknown[0]!r}; expected one of {list(E.EXPERIMENTS)}")
    factory, base = make_factory(twin, mjcf=mjcf)
    G0 = modal_analysis(base.model).static_gain_um_per_V if "creep" in names else None
    metrics: dict = {}
    prev = out / "metrics.json"
    if only and prev.is_file():
        import json
        metrics = json.loads(prev.read_text())
    timing = metrics.get("experiment_seconds", {})

    def task(name):
        controller = DiscreteController(ctrl.config)            # own state per experiment
        t0 = time.perf_counter()
        return name, _run_experiment(name, factory, controller, seed, G0), round(time.perf_counter() - t0, 2)

    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(names), desc="characterize", unit="exp", file=sys.stderr)
    results = {}
    workers = workers or min(2, os.cpu_count() or 1)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(task, n) for n in sorted(names, key=_COST_ORDER.index)]
        for fut in as_completed(futures):
            name, r, seconds = fut.result()
            results[name], timing[name] = r, seconds
            if bar:
                bar.set_postfix_str(name)
                bar.update(1)
    if bar:
        bar.close()
    for name in names:
        _record(name, results[name], metrics, out, ctrl, base)
    metrics["experiment_seconds"] = timing
    metrics["plant"] = "linear twin (same electromechanics)" if twin else "MuJoCo stage, every effect on"
    metrics["seed"] = seed
    metrics["units"] = {"nm": "nanometres", "um": "micrometres", "hz": "Hz", "ms": "milliseconds"}
    write_json(out / "metrics.json", metrics)
    return metrics
