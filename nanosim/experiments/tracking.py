"""Tracking of triangles and sines at 5-40 Hz (paper Fig. 19)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from nanosim.artifact_names import FIG19_TRACKING
from nanosim.experiments.loop import (
    FS,
    LoopTrace,
    StageFactory,
    compensate,
    resolve_feedforward,
    interpolate,
    run_closed_loop,
)
from nanosim.experiments.registry import Experiment, register
from nanosim.plant.noise import stream_seed
from nanosim.plots.experiments import fig_tracking

__all__ = ["TrackingCase", "tracking"]


@dataclass(frozen=True)
class TrackingCase:
    """One tracking case: waveform, frequency (Hz), trace, rms and max error (nm), phase lag (deg)."""

    waveform: str
    freq_hz: float
    trace: LoopTrace
    rms_error_nm: float
    max_error_nm: float
    phase_lag_deg: float


def _wave(kind, f, t, amp):
    ph = 2 * np.pi * f * t
    if kind == "sine":
        return amp * 0.5 * (1 - np.cos(ph))
    return amp * np.abs(signal.sawtooth(ph, 0.5) + 1) / 2


def tracking(factory: StageFactory, controller, seed=0, freqs_hz=(5, 10, 20, 40), amplitude_um=10.0,
             periods=3, axis=0, feedforward: str | None = None) -> list:
    """Triangles and sines of ``amplitude_um`` at each frequency, through the command interpolation.

    ``feedforward="inverse-pi"``: the controller's command passes the inverse of a
    Prandtl-Ishlinskii operator fitted to the stage's piezo
    (:func:`~nanosim.experiments.loop.fit_feedforward`, :func:`~nanosim.experiments.loop.compensate`).
    """
    ffm = resolve_feedforward(factory, seed, feedforward)
    cases = []
    for kind in ("triangle", "sine"):
        for f in freqs_hz:
            n = int((periods + 1) / f * FS)
            t = np.arange(n) / FS
            ref = np.zeros((n, 3))
            ref[:, axis] = _wave(kind, f, t, amplitude_um)
            stage = factory(stream_seed(seed, "tracking"))
            cl = run_closed_loop(stage, compensate(stage, controller, ffm)[1], interpolate(ref))
            keep = slice(int(1 / f * FS), n)
            e = cl.error_um[keep, axis] * 1e3
            tt = t[keep]
            basis = np.exp(-2j * np.pi * f * tt)
            lag = np.angle(np.sum(cl.ref_um[keep, axis] * basis) / np.sum(cl.y_um[keep, axis] * basis))
            cases.append(TrackingCase(kind, float(f), cl, float(np.sqrt(np.mean(e ** 2))), float(np.abs(e).max()),
                                      float(np.degrees(lag))))
    return cases


def _metrics(cases) -> dict:
    return {"tracking": [{"waveform": c.waveform, "freq_hz": c.freq_hz, "rms_error_nm": c.rms_error_nm,
                          "max_error_nm": c.max_error_nm, "phase_lag_deg": c.phase_lag_deg} for c in cases]}


register(Experiment("tracking", run=lambda ctx: tracking(ctx.factory, ctx.controller, seed=ctx.seed,
                                                             feedforward=ctx.feedforward),
                    metrics=_metrics, figure=lambda r, ctx: fig_tracking(r), figure_name=FIG19_TRACKING,
                    order=60, cost=4))
