"""The stage loop as it is run: the plant a controller sees and the controller's systems.

:class:`LoopPlant` is a sampled plant as the loop runs it (plant and delay), from an identified model
(:meth:`LoopPlant.identified`, :data:`IDENTIFIED_DELAY_SAMPLES`) or the linear twin with the bench
electronics (:meth:`LoopPlant.twin`, :func:`electronics_ss`, :data:`RECORD_ROW_DELAY_SAMPLES` plus the
computation delay); :func:`controller_systems` turns a controller file or object into ``(K, Ky)``.
The conventions are those of :mod:`~nanosim.design.robustness` (which re-exports these names).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import control as ct
import numpy as np

from nanosim import fileio
from nanosim.plant.electronics import ElectronicsConfig
from nanosim.plant.filters import PREWARP_HZ, butterworth_lowpass
from nanosim.design.controller import ControllerConfig, DiscreteController
from nanosim.design.loopargs import check_delay, check_scale

__all__ = ["RECORD_ROW_DELAY_SAMPLES", "IDENTIFIED_DELAY_SAMPLES", "IDENTIFIED_INPUT_GAIN_OF_NOMINAL", "LoopPlant",
           "controller_systems", "electronics_ss"]

# Samples between u_k computed from the reading y_k and its first effect on a reading,
# counted from a model identified from (u_k, reading after step(u_k)) record rows.
RECORD_ROW_DELAY_SAMPLES = 1
# The same for a model identified by nanosim.experiments.sysid, which pairs each command with the
# reading the controller had when it computed it (the bench's data gathering): that model is the
# loop as run, computation delay, amplifier and gauge included.
IDENTIFIED_DELAY_SAMPLES = 0
# The piezo gain an identified model holds, as a factor on the nominal (Fig. 14 loop secant) slope of the
# uncertainty set: the identification's PRBS drives small minor loops, whose slope is that after a reversal
# (w0 in nanosim.plant.piezo), raised by the thermally activated operators that follow within the PRBS's
# periods. Measured open loop, not fitted: the piezo model under the identification's own excitation gives
# 0.762 over 20-100 Hz on seeds 0-4 (tests/test_lqg.py); the linear twin (piezo at nominal, twin.npz) is
# 1.310-1.316 x the model identified on seed 0 over 20-100 Hz on every channel (phase within 8 degrees).
IDENTIFIED_INPUT_GAIN_OF_NOMINAL = 0.762


def _discrete_ss(name, x) -> ct.StateSpace:
    if not isinstance(x, ct.StateSpace) or not ct.isdtime(x, strict=True) or x.dt is True:
        raise ValueError(f"{name}: expected a discrete control.StateSpace with a numeric dt [s], got "
                         f"{type(x).__name__}" + (f" with dt={x.dt!r}" if isinstance(x, ct.StateSpace) else ""))
    return x


def _load_plant_npz(path, name):
    z = fileio.load_npz(path, required=("Ad", "Bd", "Cd", "Dd", "dt"))
    Gd = ct.ss(*(np.atleast_2d(np.asarray(z[k], float)) for k in ("Ad", "Bd", "Cd", "Dd")), float(z["dt"]))
    Gc = None
    if all(k in z for k in "ABCD"):
        Gc = ct.ss(*(np.atleast_2d(np.asarray(z[k], float)) for k in "ABCD"))
    return Gd, Gc


def electronics_ss(config: ElectronicsConfig, dt: float, n: int = 3):
    """The bench electronics' small-signal dynamics, per channel, as the loop sees them.

    Mirrors :mod:`nanosim.plant.filters` (pinned by ``tests/test_loop_analysis.py``
    against :class:`~nanosim.plant.twin.TwinStage`): the amplifier's first-order lag as
    the period mean the mechanics holds (``x+ = a x + (1 - a) u``, ``y = m x + (1 - m) u``,
    ``a = exp(-T / tau)``, ``m = tau / T (1 - a)``), the gauge's Butterworth output filter
    by Tustin prewarped at :data:`nanosim.plant.filters.PREWARP_HZ`, and the computation delay.
    Noise, quantization, saturation, hysteresis and creep are not in it (the piezo gain
    belongs to the uncertainty set).

    Parameters
    ----------
    config : ElectronicsConfig
    dt : float
        Control period [s].
    n : int
        Channels.

    Returns
    -------
    actuator, gauge : control.StateSpace or None
        ``n x n`` discrete, diagonal (None when that element is off).
    delay_samples : int
        ``config.computation_delay_samples``.
    """
    import scipy.signal

    if not isinstance(config, ElectronicsConfig):
        raise TypeError(f"config: expected an ElectronicsConfig, got {type(config).__name__}")

    def diag(one):
        return ct.ss(*(np.kron(np.eye(n), np.atleast_2d(np.asarray(getattr(one, m), float))) for m in "ABCD"), dt)

    act = gauge = None
    if config.amplifier_bandwidth_Hz is not None:
        tau = 1.0 / (2.0 * math.pi * float(config.amplifier_bandwidth_Hz))
        a = math.exp(-dt / tau)
        m = (tau / dt) * (1.0 - a)
        act = diag(ct.ss([[a]], [[1.0 - a]], [[m]], [[1.0 - m]], dt))
    if config.gauge_bandwidth_Hz is not None:
        w = 2.0 * math.pi * PREWARP_HZ
        num, den = butterworth_lowpass(config.gauge_bandwidth_Hz, config.gauge_filter_order)
        b, a_ = scipy.signal.bilinear(num, den, fs=w / (2.0 * math.tan(w * dt / 2.0)))
        gauge = diag(ct.ss(ct.tf(np.atleast_1d(np.squeeze(b)), a_, dt)))
    return act, gauge, int(config.computation_delay_samples)


@dataclass(frozen=True, eq=False)
class LoopPlant:
    """A sampled plant as the loop runs it: ``G`` followed by ``delay_samples`` samples.

    Attributes
    ----------
    G : control.StateSpace
        Discrete, controller V -> sensor V, in the convention of a record row: ``G``
        maps ``u_k`` to the reading returned by ``Stage.step(u_k)`` (it may have a
        direct feedthrough).
    delay_samples : int
        Samples between a reading and the command computed from it, as run
        (:data:`RECORD_ROW_DELAY_SAMPLES`).
    label : str
    G_continuous : control.StateSpace or None
        Continuous counterpart (only to place the analysis grid).
    input_gain_of_nominal : float
        The piezo gain ``G`` holds, as a factor on the uncertainty set's nominal slope (the set's
        gain range is mapped onto ``G`` by it; :meth:`UncertaintySet.input_gain_range_about`).
    """

    G: ct.StateSpace
    delay_samples: int = RECORD_ROW_DELAY_SAMPLES
    label: str = "plant"
    G_continuous: ct.StateSpace | None = None
    input_gain_of_nominal: float = 1.0

    def __post_init__(self):
        _discrete_ss("G", self.G)
        object.__setattr__(self, "delay_samples", check_delay(self.delay_samples))
        object.__setattr__(self, "input_gain_of_nominal", check_scale("input_gain_of_nominal",
                                                                      self.input_gain_of_nominal))

    @property
    def dt(self) -> float:
        """Sample period [s]."""
        return float(self.G.dt)

    @classmethod
    def identified(cls, model, delay_samples: int = IDENTIFIED_DELAY_SAMPLES, label: str = "identified model"):
        """An identified model (``model.npz`` path or discrete StateSpace).

        ``delay_samples``: :data:`IDENTIFIED_DELAY_SAMPLES` for a model of
        :mod:`nanosim.experiments.sysid`; :data:`RECORD_ROW_DELAY_SAMPLES` (+ the computation
        delay) for a model identified from record rows. Its piezo gain is
        :data:`IDENTIFIED_INPUT_GAIN_OF_NOMINAL`.
        """
        Gc = None
        if isinstance(model, (str, os.PathLike)):
            model, Gc = _load_plant_npz(model, "model")
        return cls(_discrete_ss("model", model), delay_samples, label, Gc, IDENTIFIED_INPUT_GAIN_OF_NOMINAL)

    @classmethod
    def twin(cls, twin, electronics: ElectronicsConfig | None = None, label: str = "linear twin"):
        """A zero-order-hold model ``y_k = C x_k + D u_k`` (``twin.npz`` path or discrete
        StateSpace) moved to the record-row convention ``(A, B, C A, C B + D)``, with the
        bench electronics (:func:`electronics_ss`; None: none, the ideal stage) around it.

        The loop's delay is :data:`RECORD_ROW_DELAY_SAMPLES` plus the computation delay.
        """
        Gc = None
        if isinstance(twin, (str, os.PathLike)):
            twin, Gc = _load_plant_npz(twin, "twin")
        t = _discrete_ss("twin", twin)
        A, B, C, D = (np.asarray(m, float) for m in (t.A, t.B, t.C, t.D))
        G = ct.ss(A, B, C @ A, C @ B + D, t.dt)
        delay = RECORD_ROW_DELAY_SAMPLES
        if electronics is not None:
            act, gauge, comp = electronics_ss(electronics, float(t.dt), G.ninputs)
            G = G if act is None else ct.series(act, G)
            G = G if gauge is None else ct.series(G, gauge)
            G = ct.ss(G.A, G.B, G.C, G.D, t.dt)
            delay += comp
        return cls(G, delay, label, Gc)


def controller_systems(controller, n_error: int | None = None):
    """``(K, Ky)`` discrete StateSpaces of a controller ``u = K e + Ky y`` (``Ky`` None
    for an error-only controller).

    Parameters
    ----------
    controller : path, ControllerConfig, DiscreteController or control.StateSpace
        ``controller.npz`` (``Akd..Dkd, dt``, optional ``n_error``) or the same in memory;
        a StateSpace must be discrete.
    n_error : int or None
        Error inputs of a StateSpace (default: all inputs are errors); taken from the
        file/config otherwise.
    """
    if isinstance(controller, (str, os.PathLike)):
        controller = DiscreteController.from_npz(controller)
    if isinstance(controller, DiscreteController):
        controller = controller.config
    if isinstance(controller, ControllerConfig):
        c = controller
        sys2, ne = ct.ss(c.Akd, c.Bkd, c.Ckd, c.Dkd, c.dt), c.n_error
    elif isinstance(controller, ct.StateSpace):
        sys2 = _discrete_ss("controller", controller)
        ne = ControllerConfig(sys2.A, sys2.B, sys2.C, sys2.D, sys2.dt, n_error).n_error
    else:
        raise TypeError(f"controller: expected a controller.npz path, ControllerConfig, DiscreteController or "
                        f"discrete StateSpace, got {type(controller).__name__}")
    A, B, C, D = (np.asarray(m, float) for m in (sys2.A, sys2.B, sys2.C, sys2.D))
    K = ct.ss(A, B[:, :ne], C, D[:, :ne], sys2.dt)
    Ky = None if B.shape[1] == ne else ct.ss(A, B[:, ne:], C, D[:, ne:], sys2.dt)
    return K, Ky
