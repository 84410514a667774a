"""Resolution: sensor reading at rest, open and closed loop, with its PSD (paper Fig. 16)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from nanosim.experiments.loop import FS, StageFactory, run_closed_loop
from nanosim.experiments.registry import Experiment, register
from nanosim.plots.experiments import fig_resolution

__all__ = ["ResolutionResult", "resolution"]


@dataclass(frozen=True)
class ResolutionResult:
    """Readings at rest (nm), their sigma and 95.45 / 99.73 % bands, and Welch PSDs (nm^2/Hz)."""

    open_y_nm: np.ndarray
    closed_y_nm: np.ndarray
    sigma_nm: dict
    band2_nm: dict
    band3_nm: dict
    psd_freq_hz: np.ndarray
    psd_open: np.ndarray
    psd_closed: np.ndarray


def _bands(x_nm):
    dev = np.abs(x_nm - x_nm.mean())
    return float(x_nm.std()), float(np.percentile(dev, 95.45)), float(np.percentile(dev, 99.73))


def resolution(factory: StageFactory, controller, seed=0, duration_s=4.0, axis=0) -> ResolutionResult:
    """Sensor reading at rest in open and closed loop on ``axis`` for ``duration_s`` seconds."""
    n = int(duration_s * FS)
    st = factory(seed)
    st.run(np.zeros((int(0.3 * FS), 3)))
    y_open = st.run(np.zeros((n, 3))).sensor_um[:, axis] * 1e3
    cl = run_closed_loop(factory(seed + 1), controller, np.zeros((n, 3)))
    y_closed = cl.y_um[:, axis] * 1e3
    so, so2, so3 = _bands(y_open)
    sc, sc2, sc3 = _bands(y_closed)
    f, po = signal.welch(y_open - y_open.mean(), fs=FS, nperseg=2048)
    _, pc = signal.welch(y_closed - y_closed.mean(), fs=FS, nperseg=2048)
    return ResolutionResult(open_y_nm=y_open, closed_y_nm=y_closed,
                            sigma_nm={"open_loop": so, "closed_loop": sc},
                            band2_nm={"open_loop": so2, "closed_loop": sc2},
                            band3_nm={"open_loop": so3, "closed_loop": sc3},
                            psd_freq_hz=f, psd_open=po, psd_closed=pc)


def _metrics(r: ResolutionResult) -> dict:
    return {"resolution_sigma_nm": r.sigma_nm, "resolution_2sigma_nm": r.band2_nm,
            "resolution_3sigma_nm": r.band3_nm}


register(Experiment("resolution", run=lambda ctx: resolution(ctx.factory, ctx.controller, seed=ctx.seed),
                    metrics=_metrics, figure=lambda r, ctx: fig_resolution(r), figure_name="fig16_resolution.png",
                    order=30, cost=5))
