"""10 nm staircase (paper Fig. 17)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nanosim.artifact_names import FIG17_SMALL_STEPS
from nanosim.experiments.loop import (
    FS,
    LoopTrace,
    StageFactory,
    plateaus,
    run_closed_loop,
)
from nanosim.experiments.registry import Experiment, register
from nanosim.plant.noise import stream_seed
from nanosim.plots.experiments import fig_small_steps

__all__ = ["SmallStepsResult", "small_steps"]


@dataclass(frozen=True)
class SmallStepsResult:
    """The 10 nm staircase: trace, targets and the settled plateau means and sigmas (nm)."""

    trace: LoopTrace
    targets_nm: np.ndarray
    plateau_mean_nm: np.ndarray
    plateau_sigma_nm: np.ndarray


def small_steps(factory: StageFactory, controller, seed=0, step_nm=10.0, n_steps=5, dwell_s=0.15,
                axis=0) -> SmallStepsResult:
    """Closed-loop staircase of ``n_steps`` steps of ``step_nm`` on ``axis``, ``dwell_s`` each."""
    nd = int(dwell_s * FS)
    targets = step_nm * np.arange(n_steps + 1)
    ref = np.zeros(((n_steps + 1) * nd, 3))
    ref[:, axis] = np.repeat(targets, nd) * 1e-3
    cl = run_closed_loop(factory(stream_seed(seed, "small_steps")), controller, ref)
    means, sig = plateaus(cl.y_um[:, axis] * 1e3, nd, n_steps + 1)
    means = means - means[0]
    return SmallStepsResult(trace=cl, targets_nm=targets, plateau_mean_nm=means, plateau_sigma_nm=sig)


def _metrics(r: SmallStepsResult) -> dict:
    return {"small_steps": {"targets_nm": r.targets_nm.tolist(), "plateau_means_nm": r.plateau_mean_nm.tolist(),
                            "plateau_sigma_nm": r.plateau_sigma_nm.tolist()}}


register(Experiment("small_steps", run=lambda ctx: small_steps(ctx.factory, ctx.controller, seed=ctx.seed),
                    metrics=_metrics, figure=lambda r, ctx: fig_small_steps(r),
                    figure_name=FIG17_SMALL_STEPS, order=40, cost=1))
