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

Identified from a measured loop (:func:`fit_prandtl_ishlinskii`): on fixed thresholds the PI
operator is linear in its weights, so a recorded command ``v`` and the actuator-referred output
``h`` give the weights by non-negative least squares over the play outputs
(Fleming & Leang 2014, Sec. 11.3). :class:`InversePI` inverts such a fitted operator, normalised
to the record's least-squares slope ``k = <h, v> / <v, v>``: the compensated actuator is linear with
the actuator's average gain over the record, between its slope right after a reversal (``w_0``) and
that of a long monotone move, the range the design's uncertainty set spans.

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
           "FEEDFORWARD_CHOICES", "PIModel", "play_outputs", "fit_prandtl_ishlinskii", "fit_thresholds_V", "InversePI",
           "FIT_OPERATORS"]

# plays of a fitted operator (besides the linear term): thresholds spread evenly over half the fitted span
FIT_OPERATORS = 9

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


def play_outputs(v, thresholds_V) -> np.ndarray:
    """Outputs of play operators with ``thresholds_V`` driven by ``v`` from the virgin state (all 0).

    Parameters
    ----------
    v : array_like, shape (N,)
        Input.
    thresholds_V : array_like, shape (n,)
        Thresholds ``r_i >= 0`` (input units).

    Returns
    -------
    ndarray, shape (N, n)
        ``z_i[k] = clamp(z_i[k-1], v[k] - r_i, v[k] + r_i)``, ``z_i[-1] = 0``.
    """
    v = as_finite_array("v", v, ndim=1)
    r = as_finite_array("thresholds_V", thresholds_V, ndim=1)
    if np.any(r < 0):
        raise ValueError(f"thresholds_V: expected values >= 0, got {r.tolist()}")
    z = np.zeros(r.size)
    out = np.empty((v.size, r.size))
    for k, vk in enumerate(v):
        z = np.minimum(np.maximum(z, vk - r), vk + r)
        out[k] = z
    return out


def fit_thresholds_V(span_V: float, n: int = FIT_OPERATORS) -> np.ndarray:
    """``n`` thresholds ``r_i = i span / (2 (n + 1))``: a play engages after a reversal of ``2 r_i``, so
    these cover reversals up to the span.
    """
    a = float(span_V)
    if not np.isfinite(a) or a <= 0:
        raise ValueError(f"span_V: expected a finite value > 0, got {span_V!r}")
    if isinstance(n, bool) or int(n) != n or n < 1:
        raise ValueError(f"n: expected an integer >= 1, got {n!r}")
    return a * np.arange(1, int(n) + 1) / (2 * (int(n) + 1))


@dataclass(frozen=True, eq=False)
class PIModel:
    """A Prandtl-Ishlinskii operator ``h = w_0 v + sum_i w_i P_{r_i}[v]`` fitted to a record.

    Attributes
    ----------
    thresholds_V : ndarray, shape (n,)
        ``r_i`` [controller V].
    weights : ndarray, shape (n,)
        ``w_i >= 0`` [output units per controller V].
    linear_weight : float
        ``w_0 > 0``: the slope right after a reversal.
    residual_rms : float
        RMS of ``h - PI[v]`` over the record [output units].
    output_rms : float
        RMS of ``h - mean(h)`` [output units].
    mean_slope : float
        ``<h, v> / <v, v>`` over the record [output units per controller V].
    """

    thresholds_V: np.ndarray
    weights: np.ndarray
    linear_weight: float
    residual_rms: float
    output_rms: float
    mean_slope: float

    def to_dict(self) -> dict:
        """JSON-ready parameters."""
        return {"thresholds_controller_V": self.thresholds_V.tolist(), "weights": self.weights.tolist(),
                "linear_weight": self.linear_weight, "mean_slope": self.mean_slope,
                "fit_residual_percent": 100 * self.residual_rms / self.output_rms,
                "form": "h = w0 v + sum_i w_i play_{r_i}[v], weights by non-negative least squares"}


def fit_prandtl_ishlinskii(v, h, thresholds_V) -> PIModel:
    """Weights of the PI operator on ``thresholds_V`` that best map ``v`` to ``h`` (non-negative least squares).

    Parameters
    ----------
    v : array_like, shape (N,) or (N, m)
        Commands [controller V], from rest at 0 (several columns: records of the same operator, stacked).
    h : array_like, same shape as ``v``
        Actuator-referred outputs, from 0 at the start of each record.
    thresholds_V : array_like, shape (n,)
        ``r_i > 0``, strictly increasing.

    Returns
    -------
    PIModel

    Examples
    --------
    >>> v = np.concatenate([np.linspace(0, 2, 50), np.linspace(2, 0, 50)])
    >>> h = v + 0.5 * play_outputs(v, [0.5])[:, 0]
    >>> m = fit_prandtl_ishlinskii(v, h, [0.5])
    >>> round(m.linear_weight, 6), np.round(m.weights, 6).tolist()
    (1.0, [0.5])
    """
    from scipy.optimize import nnls
    v = np.asarray(v, dtype=float)
    h = np.asarray(h, dtype=float)
    if v.ndim == 1:
        v, h = v[:, None], h[:, None] if h.ndim == 1 else h
    as_finite_array("v", v, ndim=2)
    as_finite_array("h", h, shape=v.shape)
    r = as_finite_array("thresholds_V", thresholds_V, ndim=1)
    if r.size == 0 or np.any(r <= 0) or np.any(np.diff(r) <= 0):
        raise ValueError(f"thresholds_V: expected strictly increasing values > 0, got {r.tolist()}")
    if v.shape[0] < 2 * (r.size + 1):
        raise ValueError(f"v: expected at least {2 * (r.size + 1)} samples for {r.size} plays, got {v.shape[0]}")
    A = np.vstack([np.column_stack([v[:, j], play_outputs(v[:, j], r)]) for j in range(v.shape[1])])
    b = h.T.reshape(-1)
    x, res = nnls(A, b)
    if x[0] <= 0:
        raise ValueError("h: the fit has no linear term (w0 = 0): the record does not reverse the command")
    vv = v.T.reshape(-1)
    return PIModel(thresholds_V=r.copy(), weights=x[1:], linear_weight=float(x[0]),
                   residual_rms=float(res / np.sqrt(b.size)), output_rms=float(np.std(b)),
                   mean_slope=float(b @ vv / (vv @ vv)))


class InversePI:
    """The inverse of a fitted :class:`PIModel`, normalised to the record's mean slope.

    ``u_ff = H^-1[u]`` with ``H = PI / k``, ``k`` = :attr:`PIModel.mean_slope`: in front of the
    actuator the cascade maps ``u`` to ``k u``, the actuator's average gain over the fitted record.
    Stateful as :class:`InversePIFeedforward`.

    Parameters
    ----------
    model : PIModel
    n_channels : int
        Actuator channels (the same operator on each).
    """

    def __init__(self, model: PIModel, n_channels: int = 3):
        if not isinstance(model, PIModel):
            raise TypeError(f"model: expected a PIModel, got {type(model).__name__}")
        k = model.mean_slope
        r_inv, w_inv, w0_inv = inverse_prandtl_ishlinskii(model.thresholds_V, model.weights / k,
                                                          model.linear_weight / k)
        self.model = model
        self._op = PrandtlIshlinskii(r_inv, w_inv, w0_inv, n_channels=int(n_channels))

    def reset(self) -> None:
        """Virgin state."""
        self._op.reset()

    def step(self, u_V) -> np.ndarray:
        """Pre-distort one sample ``u_V`` shape ``(n_channels,)`` [controller V]."""
        return self._op.step(np.asarray(u_V, dtype=float))

    def run(self, u_V) -> np.ndarray:
        """Pre-distort a sequence ``u_V`` shape ``(N, n_channels)``."""
        return self._op.run(np.asarray(u_V, dtype=float))


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
        if not isinstance(feedforward, (InversePIFeedforward, InversePI)):
            raise TypeError(f"feedforward: expected an InversePIFeedforward or InversePI, "
                            f"got {type(feedforward).__name__}")
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
