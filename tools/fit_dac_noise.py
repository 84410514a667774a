"""Fit the one noise level of the bench model: the DAC's white noise.

The paper's open-loop probe sigma at rest is 11.4 nm (Sec. 5, Fig. 16). With every other source at
its sourced level, the variance at the probes is ``sigma^2 = L^2 s1^2 + s0^2`` in the DAC level ``L``
(the DAC noise enters linearly). For the X and Y probes of 20 stages (4 s after 0.5 s at rest; the
streams ``stream_seed(s, "fit_dac_noise")``, s = 0-19, which no experiment uses), this measures ``s0^2``
(DAC noise off) and ``s1^2`` (at the current level) and solves for the ``L`` whose mean variance is
11.4 nm squared. One record's sigma scatters by ~1.55 nm (the lightly damped first XY pair holds most of
the variance), so 40 records fix the level to ~2 %.

Usage: ``OPENBLAS_NUM_THREADS=1 python tools/fit_dac_noise.py`` (about 2 min on 2 cores); put the printed
level into ``nanosim/constants.py`` (``DAC_WHITE_NOISE_V``). tests/test_stage.py checks it on held-out
streams (s = 20-34).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from nanosim import constants as C
from nanosim.paper import PAPER
from nanosim.plant.noise import stream_seed
from nanosim.plant.stage import StageConfig, run_open_loop_batch

SEEDS = range(20)
N_SETTLE, N_RECORD = 2000, 16000          # 0.5 s, then 4 s at 4 kHz


def open_loop_variance_nm2(dac_noise: bool) -> np.ndarray:
    """Mean variance (nm^2) of the X and Y probe readings at rest over the fit's stages."""
    cfg = StageConfig()
    cfg = replace(cfg, electronics=replace(cfg.electronics, dac_noise=dac_noise))
    traces = run_open_loop_batch(np.zeros((len(SEEDS), N_SETTLE + N_RECORD, 3)),
                                 seeds=[stream_seed(s, "fit_dac_noise") for s in SEEDS], config=cfg)
    return float(np.mean([(tr.sensor_um[N_SETTLE:, :2] * 1e3).var(axis=0) for tr in traces]))


def main() -> int:
    """Measure, solve and print."""
    target = float(PAPER["sig_o"])
    v1 = open_loop_variance_nm2(True)
    v0 = open_loop_variance_nm2(False)
    level = C.DAC_WHITE_NOISE_V * np.sqrt((target ** 2 - v0) / (v1 - v0))
    print(f"current level {C.DAC_WHITE_NOISE_V:.4g} V: open-loop sigma {np.sqrt(v1):.3f} nm (rms over streams 0-19, "
          f"X and Y); without DAC noise {np.sqrt(v0):.3f} nm; level for {target} nm: {level:.4g} V")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
