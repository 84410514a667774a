r"""Hysteresis feedforward: the inverse Prandtl-Ishlinskii operator.

A Prandtl-Ishlinskii (PI) operator is a weighted sum of play operators,
``h = w_0 v + sum_{i=1}^{n} w_i P_{r_i}[v]``, with thresholds
``0 < r_1 < ... < r_n`` and the play ``P_r[v](t) = clamp(z, v - r, v + r)``.
With ``r_0 = 0`` (``P_0[v] = v``) and ``w_0 > 0``, ``W_j = sum_{i<=j} w_i > 0``,
its inverse is again a PI operator (Krejci & Kuhnen 2001):

.. math::

    r'_j = \sum_{i=0}^{j} w_i (r_j - r_i), \qquad
    w'_0 = \frac{1}{w_0}, \qquad
    w'_j = -\frac{w_j}{W_j W_{j-1}}, \quad j = 1, \dots, n,

so ``v = w'_0 h + sum_j w'_j P_{r'_j}[h]`` when both operators start in the
virgin state (all play outputs 0). Placed in front of the piezo, the inverse
pre-distorts the command so that the rate-independent part of the
hysteresis cancels; the thermally activated operators of
:mod:`nanosim.plant.piezo` relax between samples (creep, rate dependence),
which the rate-independent inverse does not model and leaves as a residual.

References
----------
P. Krejci and K. Kuhnen, "Inverse control of systems with hysteresis and
creep", IEE Proc. Control Theory Appl. 148(3), 2001.
A. J. Fleming and K. K. Leang, *Design, Modeling and Control of
Nanopositioning Systems*, Springer 2014, Ch. 11.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nanosim import constants as C
from nanosim.plant.piezo import PiezoConfig, PrandtlIshlinskii
from nanosim.validation import as_finite_array

__all__ = ["inverse_prandtl_ishlinskii", "InversePIFeedforward", "HysteresisCompensatedController",
           "FEEDFORWARD_CHOICES"]

# names accepted by the experiments' ``feedforward`` option (None: no compensation)
FEEDFORWARD_CHOICES = ("inverse-pi",)


def inverse_prandtl_ishlinskii(thresholds_V, weights, linear_weight: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Thresholds and weights of the inverse of a Prandtl-Ishlinskii operator.

    Parameters
    ----------
    thresholds_V : array_like, shape (n,)
        Play thresholds ``r_i`` (V), strictly increasing, > 0.
    weights : array_like, shape (n,)
        Play weights ``w_i`` (>= 0).
    linear_weight : float
        Weight ``w_0`` (> 0) of the zero-threshold (linear) term.

    Returns
    -------
    thresholds_inv : ndarray, shape (n,)
        ``r'_j = sum_{i=0}^{j} w_i (r_j - r_i)`` (in the units of the
        operator's output), strictly increasing.
    weights_inv : ndarray, shape (n,)
        ``w'_j = -w_j / (W_j W_{j-1})`` with ``W_j = sum_{i=0}^{j} w_i``.
    linear_weight_inv : float
        ``w'_0 = 1 / w_0``.

    Notes
    -----
    The inverse is exact for the rate-independent operator when both start in
    the virgin state: ``PI'[PI[v]] = v`` for any continuous input (Krejci &
    Kuhnen 2001, Thm. 1; Fleming & Leang 2014, Sec. 11.4).

    Examples
    --------
    >>> r, w, w0 = inverse_prandtl_ishlinskii([1.0, 2.0], [0.5, 0.5], 1.0)
    >>> r.tolist(), w.tolist(), w0
    ([1.0, 2.5], [-0.3333333333333333, -0.16666666666666666], 1.0)
    """
    r = as_finite_array("thresholds_V", thresholds_V, ndim=1)
    w = as_finite_array("weights", weights, shape=(r.size,))
    if r.size and (np.any(r <= 0) or np.any(np.diff(r) <= 0)):
        raise ValueError(f"thresholds_V: expected strictly increasing values > 0, got {r.tolist()}")
    if np.any(w < 0):
        raise ValueError(f"weights: expected values >= 0, got {w.tolist()}")
    w0 = float(linear_weight)
    if not np.isfinite(w0) or w0 <= 0:
        raise ValueError(f"linear_weight: expected a finite value > 0, got {linear_weight}")
    rr = np.concatenate([[0.0], r])
    ww = np.concatenate([[w0], w])
    cum = np.cumsum(ww)                                   # W_j, j = 0..n
    r_inv = np.array([float(ww[:j + 1] @ (rr[j] - rr[:j + 1])) for j in range(1, rr.size)])
    w_inv = -w / (cum[1:] * cum[:-1])
    return r_inv, w_inv, 1.0 / w0


@dataclass(frozen=True, eq=False)
class InversePIFeedforward:
    """Controller-side inverse-PI pre-distortion of a command in controller volts.

    The command ``u`` (controller V) asks for the piezo's hysteretic output
    ``h = G_a u`` (piezo V, ``G_a = AMPLIFIER_GAIN``); the feedforward returns
    ``u_ff = PI^-1[G_a u] / G_a`` so that ``PI[G_a u_ff] = G_a u``.

    Parameters
    ----------
    piezo : PiezoConfig
        The piezo whose (athermal) operators are inverted, with its loop-slope
        normalisation (:meth:`PiezoConfig.hysteresis_weights`).
    n_channels : int
        Number of independent actuator channels.
    amplifier_gain : float
        Piezo volts per controller volt.

    Notes
    -----
    Stateful: :meth:`reset` puts the inverse operators in the virgin state,
    matching a piezo reset at 0 V. Each call to :meth:`run` continues from the
    current state.
    """

    piezo: PiezoConfig
    n_channels: int = 3
    amplifier_gain: float = C.AMPLIFIER_GAIN

    def __post_init__(self):
        if not isinstance(self.piezo, PiezoConfig):
            raise TypeError(f"piezo: expected a PiezoConfig, got {type(self.piezo).__name__}")
        if not self.piezo.hysteresis:
            raise ValueError("piezo: expected a config with hysteresis=True (nothing to invert)")
        g = float(self.amplifier_gain)
        if not np.isfinite(g) or g <= 0:
            raise ValueError(f"amplifier_gain: expected a finite value > 0, got {self.amplifier_gain}")
        w0, w = self.piezo.hysteresis_weights()
        r_inv, w_inv, w0_inv = inverse_prandtl_ishlinskii(self.piezo.pi_thresholds_V, w, w0)
        object.__setattr__(self, "_op", PrandtlIshlinskii(r_inv, w_inv, w0_inv, n_channels=int(self.n_channels)))

    def reset(self) -> None:
        """Virgin state (all inverse play outputs 0)."""
        self._op.reset()

    def step(self, u_V) -> np.ndarray:
        """Pre-distort one sample ``u_V`` shape ``(n_channels,)``."""
        return self._op.step(np.asarray(u_V, dtype=float) * self.amplifier_gain) / self.amplifier_gain

    def run(self, u_V) -> np.ndarray:
        """Pre-distort a sequence ``u_V`` shape ``(N, n_channels)``."""
        return self._op.run(np.asarray(u_V, dtype=float) * self.amplifier_gain) / self.amplifier_gain


class HysteresisCompensatedController:
    """A feedback controller followed by the inverse-PI pre-distortion of its command.

    ``u_piezo = PI^-1[G_a K(r - y, y)] / G_a``: the feedback design ``K``
    (any :class:`~nanosim.design.controller.DiscreteController`) sees the
    cascade ``PI o PI^-1`` as an actuator that is linear up to creep and rate
    dependence, the inverse-hysteresis compensation in series with the actuator
    of Fleming & Leang (2014, Sec. 11.5); the feedback removes what the
    rate-independent inverse leaves.

    Parameters
    ----------
    controller : DiscreteController
        The feedback design (its ``feedback``, ``reset`` and ``reset_at`` are used).
    feedforward : InversePIFeedforward
        The inverse operator, one channel per actuator.

    Notes
    -----
    ``reset`` and ``reset_at`` also return the inverse operators to the virgin
    state, the state of a piezo that starts from rest at 0 V (the stated start
    of every closed-loop experiment, :mod:`nanosim.experiments.loop`).
    """

    def __init__(self, controller, feedforward: InversePIFeedforward):
        for name in ("feedback", "reset", "reset_at"):
            if not callable(getattr(controller, name, None)):
                raise TypeError(f"controller: expected a DiscreteController with {name}(), "
                                f"got {type(controller).__name__}")
        if not isinstance(feedforward, InversePIFeedforward):
            raise TypeError(f"feedforward: expected an InversePIFeedforward, got {type(feedforward).__name__}")
        self.controller = controller
        self.feedforward = feedforward

    def reset(self, *args, **kwargs) -> None:
        """Reset the controller (same arguments) and the inverse operators."""
        self.controller.reset(*args, **kwargs)
        self.feedforward.reset()

    def reset_at(self, measurement_V, command_V=None) -> None:
        """Bumpless start of the controller at a reading; inverse operators virgin."""
        self.controller.reset_at(measurement_V, command_V)
        self.feedforward.reset()

    def feedback(self, reference_V, measurement_V) -> np.ndarray:
        """One sample: the controller's command, pre-distorted (controller V)."""
        return self.feedforward.step(self.controller.feedback(reference_V, measurement_V))
