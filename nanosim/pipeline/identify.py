"""Identify the stage from data, as the paper does (Sec. 3).

One experiment per actuator (step + PRBS in 50/100/200 Hz bands, at most
0.5 controller volts, 4 kHz), a 3x1 discrete model per column by subspace
identification, the 3x3 model assembled block-diagonally (39 states for
13 per column), continuous time by the inverse Tustin transform. Fit factors
are computed on a separate validation record (another PRBS seed).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import control as ct
import numpy as np

import identification as ident

from nanosim import constants as C
from nanosim.fileio import save_figure, write_json, write_npz
from nanosim.ramps import raised_cosine
from nanosim.plant.stage import StageConfig, Trace, run_open_loop_batch

AXES, ACTS = C.AXES, C.ACTUATORS


@dataclass(frozen=True)
class IdentifySettings:
    """Experiment and model settings (units in names)."""

    seed: int = 0
    order_per_column: int | None = 13
    amplitude_V: float = 0.5
    offset_piezo_V: float = 0.0          # operating point (paper: 0 V and 80 V)
    settle_s: float = 1.5                # ramp to the operating point and settle
    ideal: bool = False                  # every electromechanical effect off

    @property
    def offset_V(self) -> float:
        return self.offset_piezo_V / C.AMPLIFIER_GAIN


@dataclass(frozen=True)
class IdentifiedStage:
    """3x3 model from controller volts to sensor volts, with its evidence."""

    sysd: ct.StateSpace                   # discrete, dt = 250 us
    sysc: ct.StateSpace                   # continuous (inverse Tustin)
    columns: tuple                        # IdentifiedModel per actuator
    fit_percent: np.ndarray               # (3, 3) rows XYZ, cols ABC, validation data
    settings: IdentifySettings
    estimation: tuple                     # (u (N,), y (N, 3)) per column, deviations
    validation: tuple
    modes: list = field(default_factory=list)


def _experiment_inputs(settings: IdentifySettings, seed_offset: int):
    ex = ident.paper_excitation(fs=C.CONTROL_RATE_HZ, amplitude=settings.amplitude_V,
                                seed=settings.seed * 1000 + seed_offset)
    n_settle = int(settings.settle_s * C.CONTROL_RATE_HZ)
    ramp = settings.offset_V * raised_cosine(n_settle, 0.5)
    cmds = np.zeros((3, n_settle + len(ex.u), 3))
    for j in range(3):
        cmds[j, :n_settle, :] = ramp[:, None]
        cmds[j, n_settle:, :] = settings.offset_V
        cmds[j, n_settle:, j] += ex.u
    return ex, cmds, n_settle


def run_experiments(settings: IdentifySettings, model=None):
    """Simulate the estimation and validation experiments (6 runs in parallel)."""
    ex_e, cmd_e, n0 = _experiment_inputs(settings, 1)
    ex_v, cmd_v, _ = _experiment_inputs(settings, 2)
    cfg = StageConfig.ideal() if settings.ideal else StageConfig()
    seeds = [settings.seed * 10 + k for k in range(6)]
    traces = run_open_loop_batch(np.concatenate([cmd_e, cmd_v]), seeds=seeds, config=cfg, model=model)
    return ex_e, ex_v, traces[:3], traces[3:], n0


def _deviation(trace: Trace, n0: int, j: int, offset_V: float):
    """Input and output deviations from the operating point (record after settling)."""
    y = trace.sensor_V[n0:]
    baseline = trace.sensor_V[n0 - int(0.1 * C.CONTROL_RATE_HZ):n0].mean(axis=0)
    return trace.u_V[n0:, j] - offset_V, y - baseline


def assemble(columns) -> ct.StateSpace:
    """Block-diagonal 3x3 discrete model from three 3x1 column models."""
    n = [c.order for c in columns]
    A = np.zeros((sum(n), sum(n)))
    B = np.zeros((sum(n), 3))
    Cm = np.hstack([c.C for c in columns])
    D = np.hstack([c.D for c in columns])
    k = 0
    for j, c in enumerate(columns):
        A[k:k + n[j], k:k + n[j]] = c.A
        B[k:k + n[j], j] = c.B[:, 0]
        k += n[j]
    return ct.ss(A, B, Cm, D, columns[0].dt_s)


def identify_stage(settings: IdentifySettings = IdentifySettings(), model=None, progress=None) -> IdentifiedStage:
    """Run the experiments on the simulated stage and identify the 3x3 model."""
    ex_e, ex_v, tr_e, tr_v, n0 = run_experiments(settings, model)
    if progress:
        progress("experiments simulated")
    columns, est, val = [], [], []
    fit = np.zeros((3, 3))
    for j in range(3):
        u_e, y_e = _deviation(tr_e[j], n0, j, settings.offset_V)
        u_v, y_v = _deviation(tr_v[j], n0, j, settings.offset_V)
        col = ident.subspace_id(y_e, u_e[:, None], order=settings.order_per_column, fs=C.CONTROL_RATE_HZ,
                                max_order=20, enforce_stability=True, input_names=(ACTS[j],), output_names=AXES)
        x0 = ident.estimate_x0(col, y_v, u_v[:, None])
        yhat = ident.simulate(col, u_v[:, None], x0)
        fit[:, j] = ident.fit_percent(y_v, yhat)
        columns.append(col)
        est.append((u_e, y_e))
        val.append((u_v, y_v))
    sysd = assemble(columns)
    sysc = ident.d2c(sysd, method="tustin")
    modes = []
    for j, col in enumerate(columns):
        m = ident.modes_from_model(col.A, col.dt_s)
        modes.append({"column": ACTS[j], "freq_hz": list(map(float, m.freq_hz)),
                      "damping_ratio": list(map(float, m.damping))})
    return IdentifiedStage(sysd=sysd, sysc=sysc, columns=tuple(columns), fit_percent=fit, settings=settings,
                           estimation=tuple(est), validation=tuple(val), modes=modes)


def save_model(path, result: IdentifiedStage) -> Path:
    """``model.npz``: continuous A..D, discrete Ad..Dd, dt, names and units."""
    sc, sd = result.sysc, result.sysd
    return write_npz(path, A=sc.A, B=sc.B, C=sc.C, D=sc.D, Ad=sd.A, Bd=sd.B, Cd=sd.C, Dd=sd.D, dt=sd.dt,
                     input_names=np.array(ACTS), output_names=np.array(AXES),
                     input_units=np.array("controller V"), output_units=np.array("sensor V (5 um/V)"),
                     order_per_column=np.array([c.order for c in result.columns]))


def merged_modes(result: IdentifiedStage, tol: float = 0.004):
    """Modes seen in the columns, merged when within ``tol`` relative frequency."""
    all_modes = sorted((f, z) for m in result.modes for f, z in zip(m["freq_hz"], m["damping_ratio"]) if f > 20)
    merged = []
    for f, z in all_modes:
        if merged and abs(f - merged[-1][0][-1]) <= tol * f:
            merged[-1][0].append(f)
            merged[-1][1].append(z)
        else:
            merged.append(([f], [z]))
    return [{"freq_hz": float(np.median(fs)), "damping_ratio": float(np.median(zs)), "seen_in_columns": len(fs)}
            for fs, zs in merged]


def identify_json(result: IdentifiedStage, extra: dict | None = None) -> dict:
    s = result.settings
    out = {
        "fit_percent": result.fit_percent.round(2).tolist(),
        "fit_rows": list(AXES), "fit_cols": list(ACTS),
        "order_per_column": [c.order for c in result.columns],
        "total_order": int(sum(c.order for c in result.columns)),
        "modes_hz": merged_modes(result),
        "column_modes": result.modes,
        "settings": {"seed": s.seed, "order_per_column": s.order_per_column, "amplitude_V": s.amplitude_V,
                     "offset_piezo_V": s.offset_piezo_V, "ideal_stage": s.ideal,
                     "excitation": "step + PRBS 50/100/200 Hz, 1 s each, 4 kHz, one actuator at a time",
                     "validation": "separate record with another PRBS seed"},
        "dc_gain_sensor_V_per_V": np.real(ct.dcgain(result.sysc)).round(5).tolist(),
        "units": {"fit_percent": "%", "modes_hz": "Hz", "dc_gain_sensor_V_per_V": "sensor V per controller V"},
    }
    if extra:
        out.update(extra)
    return out


# -- figures -------------------------------------------------------------------
def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def figure_time_fit(result: IdentifiedStage, path, col: int = 0, row: int = 0):
    """Paper Fig. 4: input signal, measured output, model output, close-up."""
    plt = _plt()
    u, y = result.validation[col]
    model = result.columns[col]
    yhat = ident.simulate(model, u[:, None], ident.estimate_x0(model, y, u[:, None]))
    t = np.arange(len(u)) / C.CONTROL_RATE_HZ
    fig, ax = plt.subplots(4, 1, figsize=(8, 8.5), sharex=False)
    ax[0].plot(t, u, lw=0.6)
    ax[0].set_ylabel("command (V)")
    ax[0].set_title(f"(a) input to actuator {ACTS[col]}")
    ax[1].plot(t, y[:, row] * C.SENSOR_UM_PER_V, lw=0.6)
    ax[1].set_ylabel(f"{AXES[row]} (um)")
    ax[1].set_title("(b) measured output (simulated stage, validation record)")
    ax[2].plot(t, yhat[:, row] * C.SENSOR_UM_PER_V, lw=0.6, color="tab:orange")
    ax[2].set_ylabel(f"{AXES[row]} (um)")
    ax[2].set_title(f"(c) identified model output, fit {result.fit_percent[row, col]:.1f} %")
    sl = slice(int(1.9 * C.CONTROL_RATE_HZ), int(2.0 * C.CONTROL_RATE_HZ))
    ax[3].plot(t[sl], y[sl, row] * 5, label="measured")
    ax[3].plot(t[sl], yhat[sl, row] * 5, "--", label="model")
    ax[3].set_ylabel(f"{AXES[row]} (um)")
    ax[3].set_xlabel("time (s)")
    ax[3].set_title("(d) close-up")
    ax[3].legend()
    fig.tight_layout()
    return save_figure(fig, path)


def _bode_grid(models, labels, path, title, fmin=1.0, fmax=1000.0, styles=None):
    plt = _plt()
    f = np.logspace(np.log10(fmin), np.log10(fmax), 800)
    fig, ax = plt.subplots(3, 3, figsize=(11, 8), sharex=True)
    for m, lab, sty in zip(models, labels, styles or [{}] * len(models)):
        H = ident.frequency_response(m, f) if not isinstance(m, tuple) else m[1]
        fr = f if not isinstance(m, tuple) else m[0]
        for i in range(3):
            for j in range(3):
                ax[i, j].semilogx(fr, 20 * np.log10(np.abs(H[i, j]) + 1e-20), label=lab, **sty)
    for i in range(3):
        ax[i, 0].set_ylabel(f"to {AXES[i]} (dB, sensor V/V)")
        for j in range(3):
            ax[i, j].grid(True, which="both", alpha=0.3)
            if i == 0:
                ax[i, j].set_title(f"from actuator {ACTS[j]}")
            if i == 2:
                ax[i, j].set_xlabel("frequency (Hz)")
    ax[0, 0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)


def figure_singular_values(result: IdentifiedStage, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    for j, c in enumerate(result.columns):
        sv = c.singular_values[:30]
        ax.semilogy(np.arange(1, len(sv) + 1), sv, "o-", ms=3, label=f"column {ACTS[j]} (order {c.order})")
    ax.axvline(13.5, color="0.5", ls="--", lw=0.8)
    ax.set_xlabel("index")
    ax.set_ylabel("singular value (scaled data)")
    ax.set_title("Subspace singular values for order selection")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    return save_figure(fig, path)


def figure_parametric_vs_h1(result: IdentifiedStage, path, col: int = 0, row: int = 0):
    """Paper Fig. 6: parametric model vs non-parametric H1 estimate, with coherence."""
    plt = _plt()
    u, y = result.estimation[col]
    h1 = ident.h1_estimate(u, y, fs=C.CONTROL_RATE_HZ, nperseg=2048)
    f = h1.freq_hz
    Hm = ident.frequency_response(result.columns[col], f)
    band = (f >= 2) & (f <= 1000)
    fig, ax = plt.subplots(2, 1, figsize=(8, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax[0].semilogx(f[band], 20 * np.log10(np.abs(h1.H[row, 0, band])), ":", label="H1 estimate (non-parametric)")
    ax[0].semilogx(f[band], 20 * np.log10(np.abs(Hm[row, 0, band])), label="subspace model")
    ax[0].set_ylabel("magnitude (dB, sensor V/V)")
    ax[0].set_title(f"Actuator {ACTS[col]} to {AXES[row]}: time-domain model vs frequency-domain estimate")
    ax[0].legend()
    ax[0].grid(True, which="both", alpha=0.3)
    ax[1].semilogx(f[band], h1.coherence[row, 0, band])
    ax[1].set_ylabel("coherence")
    ax[1].set_xlabel("frequency (Hz)")
    ax[1].set_ylim(0, 1.05)
    ax[1].grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, path)


def run_identify(out_dir, seed: int = 0, order: int | None = 13, ideal: bool = False,
                 operating_points_piezo_V=(0.0, 80.0), model=None, twin=None, progress=None) -> IdentifiedStage:
    """``nanosim identify``: experiments, models, figures, model.npz, identify.json."""
    out = Path(out_dir)
    results = []
    for op in operating_points_piezo_V:
        s = IdentifySettings(seed=seed, order_per_column=order, offset_piezo_V=op, ideal=ideal)
        results.append(identify_stage(s, model=model, progress=progress))
        if progress:
            progress(f"identified at {op:g} V")
    main = results[0]
    save_model(out / "model.npz", main)
    extra = {}
    if len(results) > 1:
        save_model(out / f"model_{operating_points_piezo_V[1]:g}V.npz", results[1])
        f = np.logspace(0, 3, 400)
        H0 = ident.frequency_response(results[0].sysd, f)
        H1 = ident.frequency_response(results[1].sysd, f)
        rel = np.abs(H1 - H0) / np.maximum(np.abs(H0), 1e-12)
        extra["operating_points"] = {
            "piezo_V": list(operating_points_piezo_V),
            "median_rel_difference_below_5hz": float(np.median(rel[:, :, f < 5])),
            "median_rel_difference_20_to_150hz": float(np.median(rel[:, :, (f > 20) & (f < 150)])),
            "fit_percent_second": results[1].fit_percent.round(2).tolist(),
        }
    write_json(out / "identify.json", identify_json(main, extra))
    figure_time_fit(main, out / "fig04_time_domain_fit.png")
    models = [main.sysd] + ([twin.sysd_V] if twin is not None else [])
    labels = ["identified (subspace)"] + (["linear twin (MuJoCo)"] if twin is not None else [])
    _bode_grid(models, labels, out / "fig05_identified_frequency_response.png",
               "Identified 3x3 model (controller V to sensor V)", styles=[{}, {"ls": "--", "lw": 0.8}])
    figure_parametric_vs_h1(main, out / "fig06_parametric_vs_h1.png")
    if len(results) > 1:
        _bode_grid([results[0].sysd, results[1].sysd],
                   [f"{operating_points_piezo_V[0]:g} V offset", f"{operating_points_piezo_V[1]:g} V offset"],
                   out / "fig07_operating_points.png", "Models identified at two operating points (piezo volts)",
                   fmin=0.3, styles=[{}, {"ls": "--"}])
    figure_singular_values(main, out / "singular_values.png")
    return main
