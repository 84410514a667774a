"""(a) paper: the paper's design exactly -- 10-state model, one loop, the paper's weights.

Tuning rule (paper Sec. 4, DOI 10.1115/1.2936861): DC-matched balanced truncation of the
identified model to 10 states; mixed-sensitivity H-infinity synthesis
``min || [Wp S; Wu KS; Wt T] ||_inf`` with the paper's weights (optimal ``gamma``, the
central controller of ``hinfsyn``); discretized at 4 kHz by Tustin. The design model is the
Tustin d2c of the identified discrete model (:func:`~nanosim.design.architectures.common.as_continuous`),
so Tustin is its exact inverse: a controller zero that cancels a pole of the design model lands
on the identified discrete pole (the notches sit on the plant's resonances, not on their warped
images). The design model has no delay: the paper's did not.
"""
from __future__ import annotations

from nanosim.design.architectures.common import DT_S, IDENTIFIED_DELAY_SAMPLES, BenchDesign, as_continuous
from nanosim.design.discretize import discretize_controller
from nanosim.design.hinf import design_hinf
from nanosim.design.lti import single_threaded_blas
from nanosim.design.reduction import reduce_model
from nanosim.design.weights import Weights
from nanosim.paper import PAPER_REDUCED_ORDER

__all__ = ["design_paper", "TUNING_RULE"]

TUNING_RULE = ("the paper's: 10-state balanced truncation, optimal S/KS/T H-infinity with the paper's weights, "
               "4 kHz Tustin discretization (the exact inverse of the design model's d2c); "
               "no delay in the design model")


@single_threaded_blas
def design_paper(G, *, dt: float = DT_S, delay_samples: int = IDENTIFIED_DELAY_SAMPLES,
                 reduced_order: int = PAPER_REDUCED_ORDER, weights=None) -> BenchDesign:
    """The paper's single-loop H-infinity design.

    Parameters
    ----------
    G : control.StateSpace
        Identified plant (continuous, or discrete: mapped by inverse Tustin), 3 x 3.
    dt : float
        Control period [s].
    delay_samples : int
        Recorded only: the paper's design model has no delay.
    reduced_order : int
        States of the design model (paper: 10).
    weights : Weights, mapping, path or None
        None: the paper's weights.

    Returns
    -------
    BenchDesign
        Error-only controller.
    """
    Gc = as_continuous(G)
    red = reduce_model(Gc, reduced_order)
    d = design_hinf(red.G_reduced, Weights.coerce(weights))
    disc = discretize_controller(d.K, dt, "tustin_round_trip")
    params = {"reduced_order": red.order, "gamma": d.gamma, "controller_order": d.controller_order,
              "design_bandwidth_S_hz": d.bandwidth_S_hz, "design_bandwidth_T_hz": d.bandwidth_T_hz,
              "discretization": disc.method, "design_model_delay_samples": 0, "loop_delay_samples": delay_samples}
    return BenchDesign("paper", disc.Kd, Gc.noutputs, TUNING_RULE, params)
