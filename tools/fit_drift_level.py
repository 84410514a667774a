"""Calibrate the one noise level of the bench model: the legs' thermal drift (rms temperature, K).

The paper's open-loop probe sigma at rest is 11.4 nm (Sec. 5, Fig. 16). Every broadband source (DAC
electronics and quantisation, amplifier, gauge, ADC, floor) is at its datasheet level, and the piezo
makes its own creep; the drift level ``sigma_T`` is the one parameter left. The drift enters additively
ahead of the piezo, so the probes' variance is ``v(sigma_T) = g sigma_T^2 + v0`` to first order
(the hysteresis' small-signal gain is nearly constant over nanometre excursions). This tool measures
``v0`` (drift off) and ``v`` at the current level, solves for the level whose mean variance over the
X and Y probes of 20 stages is 11.4 nm squared, and checks it by a run at that level (one more linear
step if it misses by more than 1 %). The records are the resolution experiment's open-loop record
(0.3 s at rest from home, then 4 s), on the streams ``stream_seed(s, "fit_drift_level")``,
s = 0-19, which no experiment uses; then 20 held-out stages (s = 20-39) give the stability figure:
their rms sigma and the spread of single stages.

The level must lie inside ``nanosim.constants.THERMAL_DRIFT_K_BOUNDS`` (the tool says whether it
does and how far from either bound). Re-run it after any change of the piezo model or of a broadband
source, and put the printed level into ``nanosim/constants.py`` (``THERMAL_DRIFT_K_RMS``).

Usage: ``OPENBLAS_NUM_THREADS=1 python tools/fit_drift_level.py [--twin] [--out DIR]`` (MuJoCo by
default; ``--twin``: the linear twin of the nominal stage with its floor model, faster). ``--out DIR``
writes ``drift_fit.json`` there.
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from nanosim import constants as C
from nanosim.paper import PAPER
from nanosim.plant.noise import stream_seed
from nanosim.plant.stage import StageConfig, run_open_loop_batch

FIT_SEEDS = range(20)
CHECK_SEEDS = range(20, 40)
N_REST, N_RECORD = 1200, 16000          # 0.3 s at rest, then 4 s at 4 kHz (the resolution experiment's)


def _config(level_K: float) -> StageConfig:
    cfg = StageConfig()
    return replace(cfg, electronics=replace(cfg.electronics, thermal_drift=level_K > 0,
                                            thermal_drift_K=max(level_K, 0.0)))


def probe_sigmas_nm(level_K: float, seeds, twin=None) -> np.ndarray:
    """``(len(seeds), 2)`` sigma (nm) of the X and Y probe readings over the record, drift at ``level_K``."""
    cfg = _config(level_K)
    s = [stream_seed(k, "fit_drift_level") for k in seeds]
    u = np.zeros((len(s), N_REST + N_RECORD, 3))
    if twin is None:
        traces = run_open_loop_batch(u, seeds=s, config=cfg)
    else:
        from nanosim.plant.twin import TwinStage
        lin, home, fm = twin
        traces = [TwinStage(lin, seed=k, config=cfg, home_um=home, floor_model=fm).run(u[0]) for k in s]
    return np.array([(tr.sensor_um[N_REST:, :2] * 1e3).std(axis=0) for tr in traces])


def _mean_var(sig: np.ndarray) -> float:
    return float(np.mean(sig ** 2))


def fit(twin=None, progress=True) -> dict:
    """Measure, solve, check; returns the fit as JSON types."""
    target = float(PAPER["sig_o"])
    bar = tqdm(total=4, desc="fit_drift_level", unit="run", file=sys.stderr, disable=not progress)
    bar.set_postfix_str("drift off")
    v0 = _mean_var(probe_sigmas_nm(0.0, FIT_SEEDS, twin))
    bar.update(1)
    level = C.THERMAL_DRIFT_K_RMS
    bar.set_postfix_str(f"drift {level:.4g} K")
    v_now = _mean_var(probe_sigmas_nm(level, FIT_SEEDS, twin))
    bar.update(1)
    if target ** 2 <= v0:
        raise SystemExit(f"the broadband sources alone give {np.sqrt(v0):.2f} nm >= {target} nm: no drift level fits")
    new = level * np.sqrt((target ** 2 - v0) / (v_now - v0))
    bar.set_postfix_str(f"check {new:.4g} K")
    v_new = _mean_var(probe_sigmas_nm(new, FIT_SEEDS, twin))
    bar.update(1)
    if abs(np.sqrt(v_new) / target - 1) > 0.01:        # one more linear step through (new, v_new)
        new = new * np.sqrt((target ** 2 - v0) / (v_new - v0))
    bar.set_postfix_str("held-out stages")
    held = probe_sigmas_nm(new, CHECK_SEEDS, twin)
    bar.update(1)
    bar.close()
    lo, hi = C.THERMAL_DRIFT_K_BOUNDS
    rms = float(np.sqrt(_mean_var(held)))
    return {"target_open_loop_sigma_nm": target, "level_K": float(new), "bounds_K": [lo, hi],
            "inside_bounds": bool(lo < new < hi), "distance_to_bounds": [float(new / lo), float(hi / new)],
            "broadband_only_sigma_nm": float(np.sqrt(v0)), "sigma_at_current_level_nm": float(np.sqrt(v_now)),
            "current_level_K": float(level),
            "held_out": {"rms_sigma_nm": rms, "rms_over_target": rms / target,
                         "per_stage_sigma_nm": {"min": float(held.min()), "max": float(held.max()),
                                                "std": float(held.std()), "median": float(np.median(held))},
                         "stages": len(CHECK_SEEDS), "probes": ["X", "Y"]},
            "record_s": N_RECORD / C.CONTROL_RATE_HZ, "rest_before_record_s": N_REST / C.CONTROL_RATE_HZ,
            "engine": "twin" if twin is not None else "mujoco"}


def main(argv=None) -> int:
    """Fit, print one line, write drift_fit.json with --out."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--twin", action="store_true", help="the linear twin of the nominal stage (faster)")
    ap.add_argument("--out", type=Path, default=None, help="folder for drift_fit.json")
    a = ap.parse_args(argv)
    twin = None
    if a.twin:
        from nanosim.plant.floor import floor_model
        from nanosim.plant.linearize import linearize
        from nanosim.plant.stage import Stage
        base = Stage(config=StageConfig.ideal())
        twin = (linearize(base), base.table_um.copy(), floor_model(base.model, base.dt_s))
    r = fit(twin)
    h = r["held_out"]
    print(f"drift level {r['level_K']:.4g} K (bounds {r['bounds_K'][0]:g}-{r['bounds_K'][1]:g} K, "
          f"{'inside' if r['inside_bounds'] else 'OUTSIDE'}; x{r['distance_to_bounds'][0]:.3g} above the lower, "
          f"x{r['distance_to_bounds'][1]:.3g} below the upper); broadband sources alone "
          f"{r['broadband_only_sigma_nm']:.2f} nm; held-out {h['stages']} stages: rms sigma {h['rms_sigma_nm']:.2f} nm "
          f"({100 * (h['rms_over_target'] - 1):+.1f} % of {r['target_open_loop_sigma_nm']} nm), single probes "
          f"{h['per_stage_sigma_nm']['min']:.2f}-{h['per_stage_sigma_nm']['max']:.2f} nm ({r['engine']})")
    if a.out is not None:
        a.out.mkdir(parents=True, exist_ok=True)
        (a.out / "drift_fit.json").write_text(json.dumps(r, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
