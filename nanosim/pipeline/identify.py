"""Identify the stage from data, as the paper does (Sec. 3).

One experiment per actuator (step + PRBS in the paper's 50/100/200 Hz bands
and a 1 kHz band for the sixth mode, the paper's 740 Hz: ``IdentifyConfig.bands_hz``; at most
0.5 controller volts, 4 kHz), a 3x1 discrete model per column by subspace
identification, the 3x3 model assembled block-diagonally (39 states for
13 per column), continuous time by the inverse Tustin transform. Fit factors
are computed on a separate validation record (another PRBS seed). The
resonances the columns share are then re-estimated jointly, one pole per mode
(``IdentifyConfig.shared_poles``; ``--per-column-poles`` keeps the paper's
per-column estimates).
"""
from __future__ import annotations

from pathlib import Path

import control as ct
import numpy as np

import identification as ident
from nanosim import constants as C
from nanosim.experiments.sysid import (IdentifiedStage, IdentifySettings, identify_stage, merge_close_modes,
                                      merged_modes)
from nanosim.fileio import save_figure, write_json, write_npz
from nanosim.pipeline import artifacts as A
from nanosim.pipeline.config import IdentifyConfig
from nanosim.plots.identify import (figure_bode_grid, figure_parametric_vs_h1, figure_singular_values,
                                    figure_time_fit)

__all__ = ["save_model", "identify_json", "residual_bands", "tustin_modes", "run_identify", "RESIDUAL_BANDS_HZ",
           "run_identify_data", "model_npz_from_mat", "save_model_mat"]

# where the input-disturbance model of a design (the LQG's hysteresis/creep state) can be checked: below the
# first resonance (~175 Hz), where the model's gain is large and the gauge noise referred to the input small
RESIDUAL_BANDS_HZ = ((0.5, 2.0), (2.0, 5.0), (5.0, 10.0), (10.0, 20.0), (20.0, 50.0), (50.0, 100.0))

AXES, ACTS = C.AXES, C.ACTUATORS

# identify.json's units of its operating_points entry (a second operating point was identified)
OPERATING_POINTS_UNITS = {
    "operating_points/piezo_V": "piezo volts (the offset of each operating point)",
    "operating_points/bands_hz": "Hz ([low, high] of each band of median_rel_difference)",
    "operating_points/median_rel_difference": "fraction (0.01 = 1 %): |H_second - H_first| / |H_first| per "
                                               "element of the 3x3 frequency response, median over the band's "
                                               "frequencies and the elements, one value per band of bands_hz",
    "operating_points/second_point_fit_percent": "% (fit factors of the model identified at the second "
                                                 "operating point, rows X, Y, Z, columns A, B, C)",
}


def save_model(path, result: IdentifiedStage) -> Path:
    """``model.npz``: continuous A..D, discrete Ad..Dd, dt, names and units; and ``model.mat`` beside it."""
    sc, sd = result.sysc, result.sysd
    save_model_mat(Path(path).with_suffix(".mat"), sd, sc, ACTS, AXES, "controller V -> sensor V (5 um/V)")
    return write_npz(path, A=sc.A, B=sc.B, C=sc.C, D=sc.D, Ad=sd.A, Bd=sd.B, Cd=sd.C, Dd=sd.D, dt=sd.dt,
                     input_names=np.array(ACTS), output_names=np.array(AXES),
                     input_units=np.array("controller V"), output_units=np.array("sensor V (5 um/V)"),
                     order_per_column=np.array([c.order for c in result.columns]))


def tustin_modes(result: IdentifiedStage, tol: float = 0.004, zeta_max: float = 0.05) -> list[dict]:
    """Lightly damped modes of the continuous model ``result.sysc`` (the discrete model by Tustin's d2c).

    These are the modes as the paper reports them (Sec. 3: its discrete model converted by Tustin without
    prewarping), each at f_w = (fs / pi) tan(pi f / fs) (:func:`nanosim.paper.tustin_warp_hz`) of the
    discrete model's f = |log z| / (2 pi dt) in ``modes_hz``. Poles within ``tol`` relative frequency
    (the same mode in several columns) are merged; ``zeta_max`` separates resonances from the creep and
    drift poles.
    """
    m = ident.modes_from_model(np.asarray(result.sysc.A, float))
    return merge_close_modes(((f, z) for f, z in zip(m.freq_hz, m.damping) if f > 20.0 and z < zeta_max), tol)


def identify_json(result: IdentifiedStage, extra: dict | None = None) -> dict:
    """The content of ``identify.json``: fit factors, orders, modes, settings, DC gain, units."""
    s = result.settings
    out = {
        "fit_percent": result.fit_percent.round(2).tolist(),
        "fit_rows": list(AXES), "fit_cols": list(ACTS),
        "order_per_column": [c.order for c in result.columns],
        "total_order": int(sum(c.order for c in result.columns)),
        "modes_hz": merged_modes(result),
        "modes_tustin_hz": tustin_modes(result),
        "column_modes": result.modes,
        "settings": {"seed": s.seed, "order_per_column": s.order_per_column, "amplitude_V": s.amplitude_V,
                     "offset_piezo_V": s.offset_piezo_V, "ideal_stage": s.ideal, "shared_poles": s.shared_poles,
                     "prbs_bands_hz": list(s.bands_hz),
                     "excitation": "step + PRBS in prbs_bands_hz, 1 s each, 4 kHz, one actuator at a time",
                     "validation": "separate record with another PRBS seed"},
        "dc_gain_sensor_V_per_V": np.real(ct.dcgain(result.sysc)).round(5).tolist(),
        "units": {"fit_percent": "%", "modes_hz": "Hz (discrete model's poles, s = log(z) / dt)",
                  "modes_tustin_hz": "Hz (continuous model by Tustin's d2c, as the paper reports its modes)",
                  "dc_gain_sensor_V_per_V": "sensor V per controller V",
                  "input_referred_residual": "controller V / sqrt(Hz)"},
        "input_referred_residual": residual_bands(result),
    }
    if result.shared is not None:
        sh = result.shared
        out["shared_poles"] = {
            "method": "the lightly damped poles several columns share, re-estimated from all three records "
                      "(variable projection), one pole per mode",
            "freq_hz": sh.freq_hz.round(4).tolist(), "damping_ratio": sh.damping.round(6).tolist(),
            "column_freq_hz_before": [[None if np.isnan(v) else round(float(v), 4) for v in row]
                                      for row in sh.freq_hz_before],
            "column_damping_ratio_before": [[None if np.isnan(v) else round(float(v), 6) for v in row]
                                            for row in sh.damping_before],
            "weighted_cost_before": sh.cost_before, "weighted_cost_after": sh.cost_after,
        }
    if extra:
        out.update(extra)
    return out


def residual_bands(result: IdentifiedStage) -> dict:
    """The validation records' residual, referred to each column's actuator input
    (:func:`identification.input_referred_residual`), as the ASD [controller V / sqrt(Hz)] in
    :data:`RESIDUAL_BANDS_HZ`: what the linear model leaves to a disturbance model (hysteresis, creep, noise).
    """
    rows = []
    for col, (u, y) in zip(result.columns, result.validation):
        r = ident.input_referred_residual(col, u, y, fs=C.CONTROL_RATE_HZ, nperseg=int(C.CONTROL_RATE_HZ))
        rows.append([float(f"{r.band_asd(lo, hi):.4g}") for lo, hi in RESIDUAL_BANDS_HZ])
    return {"bands_hz": [list(b) for b in RESIDUAL_BANDS_HZ], "columns": list(ACTS), "asd_V_per_rthz": rows,
            "record": "validation, one actuator at a time, least squares over the three outputs"}


def run_identify(out_dir, config: IdentifyConfig | None = None, *, model=None, twin=None,
                 progress=None, on_model=None) -> IdentifiedStage:
    """``nanosim identify``: experiments, models, figures, ``model.npz``, ``identify.json``.

    Parameters
    ----------
    out_dir : path
        Run folder.
    config : IdentifyConfig, optional
        Seed, order per column, ideal stage, operating points, shared poles (default ``IdentifyConfig()``).
    model : mujoco.MjModel, optional
        Stage model (default: the bundled MJCF).
    twin : LinearTwin, optional
        Drawn beside the identified model in Fig. 5.
    progress : callable, optional
        ``progress(message)`` after each step.
    on_model : callable, optional
        ``on_model(path)`` as soon as ``model.npz`` (the first operating point's model, the one
        the design uses) is written, before the other operating points are identified: the
        pipeline starts the design there.
    """
    cfg = config or IdentifyConfig()
    ops = tuple(cfg.operating_points_piezo_V)
    out = Path(out_dir)
    results = []
    for op in ops:
        s = IdentifySettings(seed=cfg.seed, order_per_column=cfg.order or None, offset_piezo_V=op, ideal=cfg.ideal,
                             shared_poles=cfg.shared_poles, bands_hz=tuple(float(b) for b in cfg.bands_hz))
        results.append(identify_stage(s, model=model, progress=progress))
        if progress:
            progress(f"identified at {op:g} V")
        if len(results) == 1:
            path = save_model(out / A.MODEL_NPZ, results[0])
            if on_model is not None:
                on_model(path)
    main = results[0]
    extra = {}
    if len(results) > 1:
        save_model(out / A.model_at_npz(ops[1]), results[1])
        f = np.logspace(0, 3, 400)
        H0 = ident.frequency_response(results[0].sysd, f)
        H1 = ident.frequency_response(results[1].sysd, f)
        rel = np.abs(H1 - H0) / np.maximum(np.abs(H0), 1e-12)
        extra["operating_points"] = {
            "piezo_V": list(ops),
            # the band each median is taken over (open ends, on the 1 Hz - 1 kHz grid): [1, 5) and (20, 150) Hz
            "bands_hz": [[float(f[0]), 5.0], [20.0, 150.0]],
            "median_rel_difference": [float(np.median(rel[f < 5])), float(np.median(rel[(f > 20) & (f < 150)]))],
            "second_point_fit_percent": results[1].fit_percent.round(2).tolist(),
        }
    doc = identify_json(main, extra)
    if "operating_points" in extra:
        doc["units"].update(OPERATING_POINTS_UNITS)
    write_json(out / A.IDENTIFY_JSON, doc)
    save_figure(figure_time_fit(main), out / A.FIG04_TIME_DOMAIN_FIT)
    models = [main.sysd] + ([twin.sysd_V] if twin is not None else [])
    labels = ["identified (subspace)"] + (["linear twin (MuJoCo)"] if twin is not None else [])
    save_figure(figure_bode_grid(models, labels, "Identified 3x3 model (controller V to sensor V)",
                                 styles=[{}, {"ls": "--", "lw": 0.8}]),
                out / A.FIG05_IDENTIFIED_FREQUENCY_RESPONSE)
    save_figure(figure_parametric_vs_h1(main), out / A.FIG06_PARAMETRIC_VS_H1)
    if len(results) > 1:
        save_figure(figure_bode_grid([results[0].sysd, results[1].sysd],
                                     [f"{ops[0]:g} V offset", f"{ops[1]:g} V offset"],
                                     "Models identified at two operating points (piezo volts)",
                                     fmin=0.3, styles=[{}, {"ls": "--"}]),
                    out / A.FIG07_OPERATING_POINTS)
    save_figure(figure_singular_values(main), out / A.FIG_SINGULAR_VALUES)
    return main


# --- a user's record: nanosim identify --data FILE ------------------------------------------
DATA_VALIDATION_FRACTION = 0.3      # the last 30 % of the record is the validation record
DATA_MAX_ORDER = 40


def save_model_mat(path, sysd, sysc, input_names, output_names, units: str) -> Path:
    """``model.mat`` beside ``model.npz``: the discrete model as MATLAB's ``A, B, C, D, Ts`` and the continuous
    one as ``Ac, Bc, Cc, Dc`` (``ss(A, B, C, D, Ts)`` and ``ss(Ac, Bc, Cc, Dc)`` in MATLAB).
    """
    from nanosim.pipeline.export import write_state_space_mat
    return write_state_space_mat(path, sysd.A, sysd.B, sysd.C, sysd.D, float(sysd.dt), input_names=input_names,
                                 output_names=output_names, units=units, Ac=np.asarray(sysc.A),
                                 Bc=np.asarray(sysc.B), Cc=np.asarray(sysc.C), Dc=np.asarray(sysc.D))


def run_identify_data(data_path, out_dir, *, order: int | None = None, progress=None) -> dict:
    """``nanosim identify --data FILE``: a model from a user's record, with the stage's files and figures.

    The record (:func:`identification.load_record`: ``.npz``, ``.mat`` v5/v7.3 or ``.csv``) is centred
    (each channel's mean removed: the operating point) and split in time: the first 70 % estimate
    one MIMO model by PO-MOESP subspace identification (:func:`identification.subspace_id`, all
    inputs at once, so every mode is one pole of the one model: the shared-pole re-estimation of
    the stage's column-by-column records has nothing to merge), the last 30 % validate it (fit
    factor per output, :func:`identification.fit_percent`). Continuous time by the inverse Tustin
    transform (:func:`identification.d2c`). Writes ``model.npz`` and ``model.mat`` (same arrays as the
    stage's), ``identify.json`` (fit, order, modes, DC gain, the record's description, units) and the
    time-fit, frequency-response (against the H1 estimate) and singular-value figures.

    Parameters
    ----------
    data_path : path
        The record.
    out_dir : path
        Run folder (staged by the caller).
    order : int, optional
        Model order; None or 0: chosen from the singular values (up to :data:`DATA_MAX_ORDER`).
    progress : callable, optional
        ``progress(message)`` after each step.

    Returns
    -------
    dict
        The content of ``identify.json``.
    """
    import warnings

    from nanosim.design.lti import single_threaded_blas
    from nanosim.plots.records import figure_record_bode, figure_record_singular_values, figure_record_time_fit

    rec = ident.load_record(data_path)
    out = Path(out_dir)
    if progress:
        progress(f"read {rec.n_samples} samples, {rec.n_inputs} inputs, {rec.n_outputs} outputs, "
                 f"Ts = {rec.dt_s:g} s")
    u_mean, y_mean = rec.u.mean(axis=0), rec.y.mean(axis=0)
    u, y = rec.u - u_mean, rec.y - y_mean
    k = int(round((1.0 - DATA_VALIDATION_FRACTION) * rec.n_samples))
    fs = rec.fs
    with single_threaded_blas(), warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)        # an order at max_order is reported in identify.json
        model = ident.subspace_id(y[:k], u[:k], order=order or None, fs=fs, max_order=DATA_MAX_ORDER,
                                  enforce_stability=True, input_names=rec.input_names,
                                  output_names=rec.output_names)
        x0 = ident.estimate_x0(model, y[k:], u[k:])
        yhat = ident.simulate(model, u[k:], x0)
    fit = np.atleast_1d(ident.fit_percent(y[k:], yhat))
    if progress:
        progress(f"identified order {model.order}; validation fit {', '.join(f'{v:.1f} %' for v in fit)}")
    sysd = model.to_statespace()
    sysc = ident.d2c(sysd, method="tustin")
    modes = ident.modes_from_model(model.A, model.dt_s)
    units = "the record's input units -> the record's output units"
    write_npz(out / A.MODEL_NPZ, A=sysc.A, B=sysc.B, C=sysc.C, D=sysc.D, Ad=sysd.A, Bd=sysd.B, Cd=sysd.C,
              Dd=sysd.D, dt=np.float64(rec.dt_s), input_names=np.array(rec.input_names),
              output_names=np.array(rec.output_names), input_units=np.array("the record's units"),
              output_units=np.array("the record's units"), order_per_column=np.array([model.order]))
    save_model_mat(out / A.MODEL_MAT, sysd, sysc, rec.input_names, rec.output_names, units)
    doc = {
        "source": {"file": str(data_path), "n_samples": rec.n_samples, "n_inputs": rec.n_inputs,
                   "n_outputs": rec.n_outputs, "Ts_s": rec.dt_s, "input_names": list(rec.input_names),
                   "output_names": list(rec.output_names),
                   "input_mean": u_mean.tolist(), "output_mean": y_mean.tolist()},
        "fit_percent": fit.round(3).tolist(), "fit_rows": list(rec.output_names),
        "order": int(model.order), "order_chosen": "given" if order else "singular values",
        "modes_hz": [{"freq_hz": float(f), "damping_ratio": float(z)} for f, z in zip(modes.freq_hz, modes.damping)],
        "dc_gain": np.real(model.dc_gain()).round(6).tolist(),
        "settings": {"method": "PO-MOESP subspace identification of one MIMO model from all inputs at once, "
                               "enforce_stability, D estimated",
                     "estimation": f"first {100 * (1 - DATA_VALIDATION_FRACTION):g} % of the record",
                     "validation": f"last {100 * DATA_VALIDATION_FRACTION:g} % of the record",
                     "centring": "each channel's mean over the record removed (input_mean, output_mean)",
                     "continuous": "inverse Tustin transform of the discrete model",
                     "max_order": DATA_MAX_ORDER},
        "units": {"fit_percent": "%", "modes_hz": "Hz (freq_hz), damping_ratio dimensionless", "Ts_s": "s",
                  "dc_gain": "the record's output units per input unit", "input_mean": "the record's input units",
                  "output_mean": "the record's output units"},
    }
    write_json(out / A.IDENTIFY_JSON, doc)
    save_figure(figure_record_time_fit(u[k:], y[k:], yhat, rec.dt_s, fit, rec.output_names, rec.input_names),
                out / A.FIG04_TIME_DOMAIN_FIT)
    save_figure(figure_record_bode(model, u[:k], y[:k], rec.dt_s, rec.output_names, rec.input_names),
                out / A.FIG05_IDENTIFIED_FREQUENCY_RESPONSE)
    save_figure(figure_record_singular_values(model), out / A.FIG_SINGULAR_VALUES)
    return doc


def model_npz_from_mat(mat_path, out_npz, dt: float = C.CONTROL_PERIOD_S) -> Path:
    """A ``model.npz`` (continuous and discrete arrays) from a MATLAB state space ``A, B, C, D, Ts``.

    ``Ts > 0``: the discrete model as it is, its continuous twin by the inverse Tustin transform (as
    ``nanosim identify`` does); ``Ts = 0``: the continuous model, discretized by Tustin at ``dt``.
    """
    import control as ct

    Am, Bm, Cm, Dm, ts = ident.load_state_space(mat_path)
    if ts > 0:
        sysd = ct.ss(Am, Bm, Cm, Dm, ts)
        sysc = ident.d2c(sysd, method="tustin")
    else:
        sysc = ct.ss(Am, Bm, Cm, Dm)
        sysd = ct.c2d(sysc, dt, "tustin")
    return write_npz(out_npz, A=sysc.A, B=sysc.B, C=sysc.C, D=sysc.D, Ad=sysd.A, Bd=sysd.B, Cd=sysd.C, Dd=sysd.D,
                     dt=np.float64(sysd.dt), source=np.array(str(mat_path)))
