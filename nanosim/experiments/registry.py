"""The experiment registry: one :class:`Experiment` entry per experiment (run, metrics, figure).

Adding an experiment touches one file: a module in :mod:`nanosim.experiments`
(found automatically) or any imported module that calls :func:`register`.
``nanosim characterize`` runs every registered experiment, writes the dict
returned by ``metrics`` into ``metrics.json`` and the Figure returned by
``figure`` as ``figure_name``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

__all__ = ["ExperimentContext", "Experiment", "register", "unregister", "registered", "get"]


@dataclass(frozen=True)
class ExperimentContext:
    """What an experiment may use.

    Attributes
    ----------
    factory : callable
        ``factory(seed) -> stage`` with ``step``/``run``/``reset`` (a fresh MuJoCo
        :class:`~nanosim.plant.stage.Stage` or :class:`~nanosim.plant.twin.TwinStage`).
    controller : DiscreteController
        A fresh controller, owned by this experiment.
    seed : int
    static_gain_um_per_V : (3, 3) array
        Static gain of the stage's mechanics (um per controller V), for open-loop moves.
    base_stage : Stage
        The nominal stage (for predictions that need its linearization).
    feedforward : str or None
        Hysteresis compensation for the experiments that take it (``"inverse-pi"``:
        :mod:`nanosim.design.feedforward`); None: none.
    """

    factory: Callable[[int], Any]
    controller: Any
    seed: int
    static_gain_um_per_V: np.ndarray | None = None
    base_stage: Any = None
    feedforward: str | None = None


@dataclass(frozen=True)
class Experiment:
    """One experiment.

    Attributes
    ----------
    name : str
        Identifier used by ``--only`` and in ``experiment_seconds``.
    run : callable
        ``run(ctx) -> result``.
    metrics : callable
        ``metrics(result) -> dict`` merged into ``metrics.json`` (JSON types, units in key names).
    figure : callable or None
        ``figure(result, ctx) -> matplotlib.figure.Figure``; never writes a file.
    figure_name : str or None
        File name of the figure in the run folder (registered in :mod:`nanosim.pipeline.artifacts`
        for the built-in experiments).
    order : int
        Position in ``metrics.json`` and in listings.
    cost : float
        Relative run time; the longest run first so two workers finish together.
    """

    name: str
    run: Callable[[ExperimentContext], Any]
    metrics: Callable[[Any], dict]
    figure: Callable[[Any, ExperimentContext], Any] | None = None
    figure_name: str | None = None
    order: int = 1000
    cost: float = 1.0

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.isidentifier():
            raise ValueError(f"name: expected a Python identifier, got {self.name!r}")
        for attr in ("run", "metrics"):
            if not callable(getattr(self, attr)):
                raise ValueError(f"{attr}: expected a callable, got {type(getattr(self, attr)).__name__}")


_REGISTRY: dict[str, Experiment] = {}


def register(experiment: Experiment) -> Experiment:
    """Add ``experiment`` (replacing one of the same name); returns it."""
    if not isinstance(experiment, Experiment):
        raise ValueError(f"experiment: expected an Experiment, got {type(experiment).__name__}")
    _REGISTRY[experiment.name] = experiment
    return experiment


def unregister(name: str) -> None:
    """Remove the experiment called ``name`` (no error if absent)."""
    _REGISTRY.pop(name, None)


def registered() -> tuple[str, ...]:
    """Names of the registered experiments, in ``order``."""
    return tuple(sorted(_REGISTRY, key=lambda n: (_REGISTRY[n].order, n)))


def get(name: str) -> Experiment:
    """The experiment called ``name``; ``ValueError`` naming the known ones otherwise."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ValueError(f"experiment: unknown name {name!r}; expected one of {list(registered())}") from None
