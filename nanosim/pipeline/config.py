"""Configuration dataclasses: the single home of every default (CLI and Python API alike).

``nanosim design`` builds a :class:`DesignConfig` from its arguments; the Python
API uses ``DesignConfig()`` as its default, so both give the same controller.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace

from nanosim.constants import (CONTROL_RATE_HZ, DEFAULT_DAMPING_LOWPASS_HZ, DEFAULT_DAMPING_ZETA,
                               DEFAULT_PRBS_BANDS_HZ, DEFAULT_REDUCED_ORDER)
from nanosim.paper import PAPER_IDENTIFIED_ORDER_PER_COLUMN, PAPER_REDUCED_ORDER

__all__ = ["IdentifyConfig", "DesignConfig", "CharacterizeConfig", "PipelineConfig", "MonteCarloConfig",
           "SweepConfig", "CompareConfig", "DEFAULT_REDUCED_ORDER", "DEFAULT_DAMPING_ZETA",
           "DEFAULT_DAMPING_LOWPASS_HZ", "DEFAULT_ARCHITECTURE", "DESIGN_ARCHITECTURES"]

# DEFAULT_REDUCED_ORDER, DEFAULT_DAMPING_ZETA, DEFAULT_DAMPING_LOWPASS_HZ: defined in nanosim.constants (the
# design layer uses them too), re-exported here
# the exported controller of `nanosim design`: every named design of nanosim.design.architectures.DESIGN_RULES
# (tests/test_hinf_fourblock.py checks the list against it), "hinf" the four-block H-infinity design by default;
# "mixsyn" the mixed-sensitivity design these settings describe (the paper's with --paper-design)
DESIGN_ARCHITECTURES = ("hinf", "paper", "hinf-damped", "pi-notch", "damping-tracking", "robust", "feedforward", "irc",
                        "lqg", "lqg-nominal", "lqg-gain-range", "lqg-bandwidth", "mixsyn")
DEFAULT_ARCHITECTURE = "hinf"


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed: expected a non-negative integer, got {seed!r}")
    return seed


@dataclass(frozen=True)
class IdentifyConfig:
    """Settings of ``nanosim identify``.

    Attributes
    ----------
    seed : int
        Seed of the stage's noise and of the excitation.
    order : int or None
        States per 3x1 column (paper: 13); 0 or None chooses from the singular values.
    ideal : bool
        Every electromechanical effect off.
    operating_points_piezo_V : tuple of float
        Piezo-volt offsets at which a model is identified (paper Fig. 7: 0 V and 80 V).
    shared_poles : bool
        Re-estimate the resonances the columns share jointly, one pole per mode (default);
        False keeps each column's own estimate, as the paper.
    bands_hz : tuple of float
        PRBS band edges [Hz], one 1 s segment each, every edge in (0, 2000]: the paper's 50, 100 and
        200 Hz and a 1 kHz band for the stage's sixth mode, the twist (paper: 740 Hz) (default);
        ``PAPER_PRBS_BANDS_HZ`` is the paper's.
    """

    seed: int = 0
    order: int | None = PAPER_IDENTIFIED_ORDER_PER_COLUMN
    ideal: bool = False
    operating_points_piezo_V: tuple = (0.0, 80.0)
    shared_poles: bool = True
    bands_hz: tuple = DEFAULT_PRBS_BANDS_HZ

    def __post_init__(self):
        _check_seed(self.seed)
        if self.order is not None and (isinstance(self.order, bool) or not isinstance(self.order, int)
                                       or not 0 <= self.order <= 60):
            raise ValueError(f"order: expected an integer in [0, 60] (0: choose from singular values), "
                             f"got {self.order!r}")
        bands, nyquist_hz = self.bands_hz, CONTROL_RATE_HZ / 2
        if (not isinstance(bands, tuple) or not bands
                or not all(isinstance(b, (int, float)) and not isinstance(b, bool) and 0 < b <= nyquist_hz
                           for b in bands)):
            raise ValueError(f"bands_hz: expected a non-empty tuple of band edges in (0, {nyquist_hz:g}] Hz (half "
                             f"the {CONTROL_RATE_HZ:g} Hz sampling rate), got {bands!r}")


@dataclass(frozen=True)
class DesignConfig:
    """Settings of ``nanosim design``.

    Attributes
    ----------
    reduced_order : int
        States of the balanced-truncation design model (paper: 10).
    damping_zeta : float
        Damping ratio the inner damping loop adds to the first mode; 0 = no damping loop (the paper).
    damping_lowpass_hz : float
        Low-pass corner of the damping loop [Hz].
    weights : path or None
        JSON/TOML weights file; None = the paper's weights.
    discretization : str
        See :func:`nanosim.design.discretize.discretize_controller`.
    gamma_relax : float
        0 = optimal central controller.
    delay_samples : int or None
        Computation delay of the loop as run, put into the design model (Pade
        approximant at the plant input) [samples]; None = the loop's actual delay relative
        to the identified model (:func:`nanosim.pipeline.design.model_loop_delay_samples`);
        0 = none (the paper).
    architecture : str
        The exported controller: ``"hinf"`` (default, the four-block H-infinity design,
        :mod:`nanosim.design.architectures.hinf_fourblock`), any other member of
        :data:`nanosim.design.architectures.DESIGN_RULES` (``"lqg"``, ``"paper"``, ...), or ``"mixsyn"``: the
        mixed-sensitivity design of these settings (``reduced_order``, ``damping_zeta``, ``weights``), which is
        always made and described in ``design.json`` as the reference (``--paper-design``: the paper's set-up).
    """

    reduced_order: int = DEFAULT_REDUCED_ORDER
    damping_zeta: float = DEFAULT_DAMPING_ZETA
    damping_lowpass_hz: float = DEFAULT_DAMPING_LOWPASS_HZ
    weights: str | os.PathLike | None = None
    discretization: str = "auto"
    gamma_relax: float = 0.0
    delay_samples: int | None = None
    architecture: str = DEFAULT_ARCHITECTURE

    def __post_init__(self):
        if self.architecture not in DESIGN_ARCHITECTURES:
            raise ValueError(f"architecture: expected one of {DESIGN_ARCHITECTURES}, got {self.architecture!r}")
        d = self.delay_samples
        if d is not None and (isinstance(d, bool) or not isinstance(d, int) or not 0 <= d <= 4):
            raise ValueError(f"delay_samples: expected None (the loop's delay) or an integer in 0..4, got {d!r}")
        if isinstance(self.reduced_order, bool) or not isinstance(self.reduced_order, int) or self.reduced_order < 1:
            raise ValueError(f"reduced_order: expected a positive integer, got {self.reduced_order!r}")
        z = self.damping_zeta
        if not isinstance(z, (int, float)) or not math.isfinite(z) or not 0.0 <= z <= 1.0:
            raise ValueError(f"damping_zeta: expected a number in [0, 1] (0 = no damping loop), got {z!r}")
        lp = self.damping_lowpass_hz
        if not isinstance(lp, (int, float)) or not math.isfinite(lp) or lp <= 0:
            raise ValueError(f"damping_lowpass_hz: expected a positive number of Hz, got {lp!r}")
        if not isinstance(self.gamma_relax, (int, float)) or not 0.0 <= self.gamma_relax < 10.0:
            raise ValueError(f"gamma_relax: expected a number in [0, 10), got {self.gamma_relax!r}")

    @classmethod
    def paper(cls, **overrides) -> "DesignConfig":
        """The paper's set-up: 10-state design model, single H-infinity loop, no damping loop, no delay,
        discretized by Tustin (the exact inverse of the design model's Tustin d2c).
        """
        return replace(cls(reduced_order=PAPER_REDUCED_ORDER, damping_zeta=0.0, delay_samples=0, architecture="mixsyn",
                           discretization="tustin_round_trip"), **overrides)

    @property
    def has_damping_loop(self) -> bool:
        """True if the design adds an inner damping loop (``damping_zeta > 0``)."""
        return self.damping_zeta > 0.0


@dataclass(frozen=True)
class CharacterizeConfig:
    """Settings of ``nanosim characterize``.

    Attributes
    ----------
    seed : int
    only : str or None
        Run one registered experiment.
    twin : bool
        Run on the linear twin (same electromechanics) instead of MuJoCo.
    workers : int or None
        Threads for the independent experiments (default: up to 2).
    feedforward : str or None
        Hysteresis compensation (``"inverse-pi"``: the inverse of a Prandtl-Ishlinskii operator fitted
        to the stage's piezo, open loop in the hysteresis experiment and behind the controller in the
        hysteresis, tracking and contouring loops); None: none.
    drive : {"voltage", "charge"}
        The piezo amplifier of every experiment: the bench's voltage amplifier, or a charge amplifier
        (:mod:`nanosim.plant.charge_drive`, its crossover and residual at their
        :class:`~nanosim.plant.electronics.ElectronicsConfig` defaults).
    """

    seed: int = 0
    only: str | None = None
    twin: bool = False
    workers: int | None = None
    feedforward: str | None = None
    drive: str = "voltage"

    def __post_init__(self):
        _check_seed(self.seed)
        from nanosim.design.feedforward import FEEDFORWARD_CHOICES      # numba-compiled piezo: import on use

        if self.feedforward is not None and self.feedforward not in FEEDFORWARD_CHOICES:
            raise ValueError(f"feedforward: expected None or one of {', '.join(FEEDFORWARD_CHOICES)}, "
                             f"got {self.feedforward!r}")
        from nanosim.plant.charge_drive import DRIVES

        if self.drive not in DRIVES:
            raise ValueError(f"drive: expected one of {', '.join(DRIVES)}, got {self.drive!r}")
        if self.workers is not None and (not isinstance(self.workers, int) or self.workers < 1):
            raise ValueError(f"workers: expected a positive integer, got {self.workers!r}")


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of ``nanosim pipeline``: one seed for every step, and each step's config."""

    seed: int = 0
    mjcf: str | os.PathLike | None = None
    identify: IdentifyConfig = field(default_factory=IdentifyConfig)
    design: DesignConfig = field(default_factory=DesignConfig)
    characterize_twin_too: bool = True

    def __post_init__(self):
        _check_seed(self.seed)

    @property
    def mjcf_arg(self) -> str | None:
        """``mjcf`` as the worker tasks take it: a string path, or None for the bundled stage."""
        return None if self.mjcf is None else str(self.mjcf)


def _check_count(name: str, v, lo: int, allow_none: bool = False) -> None:
    if v is None and allow_none:
        return
    if isinstance(v, bool) or not isinstance(v, int) or v < lo:
        raise ValueError(f"{name}: expected an integer >= {lo}, got {v!r}")


@dataclass(frozen=True)
class MonteCarloConfig:
    """Settings of ``nanosim montecarlo`` (fabrication-tolerance Monte Carlo).

    Attributes
    ----------
    n : int
        Number of fabricated stages (samples 0 ... n-1 of ``seed``).
    seed : int
        Seed of the tolerance samples and of every experiment's noise (common to all samples).
    crosscheck : int
        Samples 0 ... crosscheck-1 are rerun on MuJoCo and compared (0: none).
    spec : path or None
        Spec JSON (limits with units); None = the paper's closed-loop bands.
    scheduler : str or None
        None: local process pool; ``"local"``: a Dask LocalCluster; ``tcp://HOST:8786``: a Dask cluster.
    workers : int or None
        Local worker processes (default: CPUs).
    chunk : int or None
        Samples per task (default: about two tasks per worker, at most 64).
    experiments : tuple of str or None
        Registered experiments to run (default: all).
    mjcf : path or None
        Stage MJCF (default: the bundled one).
    """

    n: int = 200
    seed: int = 0
    crosscheck: int = 10
    spec: str | os.PathLike | None = None
    scheduler: str | None = None
    workers: int | None = None
    chunk: int | None = None
    experiments: tuple | None = None
    mjcf: str | os.PathLike | None = None

    def __post_init__(self):
        _check_count("n", self.n, 1)
        _check_seed(self.seed)
        _check_count("crosscheck", self.crosscheck, 0)
        _check_count("workers", self.workers, 1, allow_none=True)
        _check_count("chunk", self.chunk, 1, allow_none=True)


@dataclass(frozen=True)
class SweepConfig:
    """Settings of ``nanosim sweep`` (flexure design sweep).

    Attributes
    ----------
    params : tuple of (name, start, stop, count)
        Swept parameters; the grid is their Cartesian product.
    seed : int
        Noise seed of the experiments.
    design : DesignConfig
        Controller redesigned at every point with these settings.
    scheduler, workers, mjcf
        As in :class:`MonteCarloConfig`.
    """

    params: tuple = ()
    seed: int = 0
    design: DesignConfig = field(default_factory=DesignConfig)
    scheduler: str | None = None
    workers: int | None = None
    mjcf: str | os.PathLike | None = None

    def __post_init__(self):
        _check_seed(self.seed)
        _check_count("workers", self.workers, 1, allow_none=True)


@dataclass(frozen=True)
class CompareConfig:
    """Settings of ``nanosim compare`` (:mod:`nanosim.pipeline.compare`).

    Attributes
    ----------
    controllers : tuple of str
        Bench names (``nanosim.design.architectures.BENCH``), ``.npz``/``.mat`` state spaces or
        ``module:function`` controller objects.
    seeds : tuple of int
        Every controller runs the suite on each seed.
    twin : bool
        The linear twin (same electromechanics) instead of MuJoCo.
    only : tuple of str or None
        Registered experiments to run (default: all).
    model : path or None
        Identified ``model.npz`` (or a run folder holding one) for the bench designs and the analysis;
        None identifies the stage on the first seed.
    robustness : bool
        Write each linear controller's ``robustness.json`` (mu included).
    workers : int or None
        Threads for one controller's experiments (default: up to 2).
    """

    controllers: tuple = ()
    seeds: tuple = (0,)
    twin: bool = False
    only: tuple | None = None
    model: str | os.PathLike | None = None
    robustness: bool = True
    workers: int | None = None

    def __post_init__(self):
        if not self.controllers or not all(isinstance(c, str) and c for c in self.controllers):
            raise ValueError(f"controllers: expected one or more names, files or module:function, "
                             f"got {self.controllers!r}")
        if not self.seeds:
            raise ValueError("seeds: expected at least one seed")
        for s in self.seeds:
            _check_seed(s)
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds: expected distinct seeds, got {self.seeds!r}")
        if self.workers is not None and (not isinstance(self.workers, int) or self.workers < 1):
            raise ValueError(f"workers: expected a positive integer, got {self.workers!r}")
