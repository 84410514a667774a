"""Fit the one noise level of the bench model: the DAC's white noise (issue 12, item 7).

The paper's open-loop probe sigma at rest is 11.4 nm (Sec. 5, Fig. 16). With every other source at
its sourced level, the variance at the probes is ``sigma^2 = L^2 s1^2 + s0^2`` in the DAC level ``L``
(the DAC noise enters linearly). For seeds 0-4 and the X and Y probes (4 s after 0.5 s at rest), this
measures ``s0^2`` (DAC noise off) and ``s1^2`` (at the current level) and solves for the ``L`` whose
mean variance is 11.4 nm squared.

Usage: ``OPENBLAS_NUM_THREADS=1 python tools/fit_dac_noise.py`` (about 1 min); put the printed level
into ``nanosim/constants.py`` (``DAC_WHITE_NOISE_V``).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from nanosim import constants as C
from nanosim.paper import PAPER
from nanosim.plant.stage import Stage, StageConfig

SEEDS = range(5)
N_SETTLE, N_RECORD = 2000, 16000          # 0.5 s, then 4 s at 4 kHz


def open_loop_variance_nm2(seed: int, dac_noise: bool) -> np.ndarray:
    """Variance (nm^2) of the X and Y probe readings at rest."""
    cfg = StageConfig()
    cfg = replace(cfg, electronics=replace(cfg.electronics, dac_noise=dac_noise))
    tr = Stage(seed=seed, config=cfg).run(np.zeros((N_SETTLE + N_RECORD, 3)))
    return (tr.sensor_um[N_SETTLE:, :2] * 1e3).var(axis=0)


def main() -> int:
    """Measure, solve and print."""
    target = float(PAPER["sig_o"])
    v1 = np.mean([open_loop_variance_nm2(s, True) for s in SEEDS])
    v0 = np.mean([open_loop_variance_nm2(s, False) for s in SEEDS])
    level = C.DAC_WHITE_NOISE_V * np.sqrt((target ** 2 - v0) / (v1 - v0))
    print(f"current level {C.DAC_WHITE_NOISE_V:.4g} V: open-loop sigma {np.sqrt(v1):.3f} nm (rms over seeds 0-4, "
          f"X and Y); without DAC noise {np.sqrt(v0):.3f} nm; level for {target} nm: {level:.4g} V")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
