"""Bandwidth from S and T measured with PRBS references, and the 2 um step (paper Fig. 18)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import identification as ident
from nanosim.artifact_names import FIG18_BANDWIDTH_STEP
from nanosim.design.controller import DiscreteController
from nanosim.design.lti import crossing_hz
from nanosim.experiments.loop import (
    FS,
    LoopTrace,
    StageFactory,
    run_closed_loop,
    step_metrics,
)
from nanosim.experiments.registry import Experiment, register
from nanosim.paper import PAPER_STEP_UM
from nanosim.plant.linearize import linearize
from nanosim.plant.noise import stream_seed
from nanosim.plots.experiments import fig_bandwidth

__all__ = ["BandwidthResult", "bandwidth", "predicted_loop", "PRBS_DURATION_S", "PRBS_AMPLITUDE_UM"]

# The PRBS references (also the reading disturbance of nanosim.pipeline.compare.feedback_sensitivity)
PRBS_DURATION_S = 4.0
PRBS_AMPLITUDE_UM = 2.0


@dataclass(frozen=True)
class BandwidthResult:
    """sigma(S), sigma(T) measured with PRBS references (Hz grid), their -3 dB bandwidths and the 2 um step."""

    freq_hz: np.ndarray
    sigma_S: np.ndarray
    sigma_T: np.ndarray
    bandwidth_S_hz: float
    bandwidth_T_hz: float
    step: LoopTrace
    rise_ms: float
    peak_ms: float
    settling_ms: float
    overshoot_percent: float


def bandwidth(factory: StageFactory, controller, seed=0, duration_s=PRBS_DURATION_S, amplitude_um=PRBS_AMPLITUDE_UM,
              step_um=PAPER_STEP_UM) -> BandwidthResult:
    """sigma(S), sigma(T) from three uncorrelated PRBS references (MIMO H1), and a 2 um step.

    The PRBS amplitude (2 um) drives the piezos with about the same swing as the
    identification experiment: the hysteretic actuator's gain depends on amplitude.
    """
    n = int(duration_s * FS)
    ref = ident.prbs_channels(n, 800.0, fs=FS, n_channels=3, amplitude=amplitude_um,
                              seed=stream_seed(seed, "bandwidth.reference"))
    cl = run_closed_loop(factory(stream_seed(seed, "bandwidth", 0)), controller, ref)
    est_T = ident.h1_estimate(ref, cl.y_um, fs=FS, nperseg=2048)
    f = est_T.freq_hz
    band = (f >= 1.0) & (f <= 1000.0)
    T = est_T.H[band]
    S = np.eye(3)[None] - T
    sT = np.linalg.svd(T, compute_uv=False)[:, 0]
    sS = np.linalg.svd(S, compute_uv=False)[:, 0]
    fb = f[band]
    lvl = 1 / np.sqrt(2)
    bS = crossing_hz(fb, sS, lvl, rising=True)
    bT = crossing_hz(fb, sT, lvl, rising=False)
    ns = int(0.3 * FS)
    sref = np.zeros((ns + int(0.01 * FS), 3))
    sref[int(0.01 * FS):, 0] = step_um
    stp = run_closed_loop(factory(stream_seed(seed, "bandwidth", 1)), controller, sref)
    k0 = int(0.01 * FS)
    t = stp.t_s[k0:] - stp.t_s[k0]
    y = stp.y_um[k0:, 0] - stp.y_um[:k0, 0].mean()
    rise, peak, settle, over = step_metrics(t, y, step_um)
    return BandwidthResult(freq_hz=fb, sigma_S=sS, sigma_T=sT, bandwidth_S_hz=bS, bandwidth_T_hz=bT, step=stp,
                           rise_ms=rise, peak_ms=peak, settling_ms=settle, overshoot_percent=over)


def predicted_loop(controller: DiscreteController, base, f_hz=None):
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


def _metrics(r: BandwidthResult) -> dict:
    return {"bandwidth_S_hz": r.bandwidth_S_hz, "bandwidth_T_hz": r.bandwidth_T_hz,
            "step_2um": {"rise_ms": r.rise_ms, "peak_ms": r.peak_ms, "settling_ms": r.settling_ms,
                         "overshoot_percent": r.overshoot_percent}}


register(Experiment("bandwidth", run=lambda ctx: bandwidth(ctx.factory, ctx.controller, seed=ctx.seed),
                    metrics=_metrics,
                    figure=lambda r, ctx: fig_bandwidth(r, predicted=predicted_loop(ctx.controller,
                                                                                    ctx.base_stage)),
                    figure_name=FIG18_BANDWIDTH_STEP, order=50, cost=2))
