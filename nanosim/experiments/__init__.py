"""Closed-loop experiments of the paper's Section 5, one module each, and the loop that runs them.

Every module of this package is imported on first use, so an experiment
module that calls :func:`~nanosim.experiments.registry.register` is picked up
by ``nanosim characterize`` without editing any other file.
"""
from __future__ import annotations

import importlib
import pkgutil

from nanosim.experiments.loop import (
    LoopTrace,
    interpolate,
    run_closed_loop,
    step_metrics,
)
from nanosim.experiments.registry import (
    Experiment,
    ExperimentContext,
    get,
    register,
    registered,
    unregister,
)

__all__ = ["Experiment", "ExperimentContext", "register", "unregister", "registered", "get", "LoopTrace",
           "run_closed_loop", "step_metrics", "interpolate", "load_builtin"]

_NOT_EXPERIMENTS = {"loop", "registry"}


def load_builtin() -> tuple[str, ...]:
    """Import every module of this package (each registers its experiment); returns the registered names."""
    for info in pkgutil.iter_modules(__path__):
        if info.name not in _NOT_EXPERIMENTS and not info.name.startswith("_"):
            importlib.import_module(f"{__name__}.{info.name}")
    return registered()
