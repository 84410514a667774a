"""The controller bench: ten designs, each a pure function of the identified model.

``design_X(G, *, dt=250e-6, delay_samples=0, ...) -> BenchDesign`` (a discrete
``Akd, Bkd, Ckd, Dkd, dt, n_error`` controller with its tuning rule), for

* ``hinf`` (:mod:`.hinf_fourblock`) -- four-block H-infinity (S, SG, KS, T): the paper's weights plus an
  input-disturbance channel, so the optimum damps the first pair (the exported default);
* ``paper`` (:mod:`.paper`) -- the paper's 10-state single-loop H-infinity design;
* ``hinf-damped`` (:mod:`.hinf_damped`) -- H-infinity around an inner damping loop, delay-aware;
* ``pi-notch`` (:mod:`.pi_notch`) -- decoupled PI with notches (the industry baseline);
* ``damping-tracking`` (:mod:`.damping_tracking`) -- positive position feedback plus integral tracking;
* ``robust`` (:mod:`.robust`) -- Glover-McFarlane H-infinity loop shaping against the stage's uncertainty set;
* ``feedforward`` (:mod:`.feedforward`) -- model-inversion feedforward on top of a feedback design;
* ``lqg`` (:mod:`.lqg`) -- H2-optimal output feedback with integral action from the stage's noise levels,
  robust over the uncertainty set; ``lqg-nominal`` -- the same designed on the identified modes (not robust
  to one extra sample of delay with the modes 3 % higher); ``lqg-gain-range`` -- the robust lqg with its disk
  margin required at both ends of the set's piezo-gain range (the identified slope after a reversal and the
  nominal slope of a monotone move), designed at the range's top;
* ``irc`` (:mod:`.irc`) -- integral resonant control per decoupled axis plus integral tracking.

Outside the scored bench (:data:`DESIGN_RULES`, which :func:`design` accepts too): ``lqg-bandwidth`` -- the robust
lqg at the smallest control weight (from 1/300 of its own up) at which its pick meets every check, without the
reference prefilter: the fastest loops its robustness checks accept (``nanosim sweep --architecture lqg-bandwidth``).

:mod:`.protocol` turns a name, a file or ``module:function`` into a controller.
"""
from __future__ import annotations

from typing import Callable

from nanosim.design.architectures.common import DT_S, LOOP_DELAY_SAMPLES, BenchDesign

__all__ = ["BENCH", "DESIGN_RULES", "BenchDesign", "design", "design_bench", "DT_S", "LOOP_DELAY_SAMPLES"]


def _paper(G, **kw):
    from nanosim.design.architectures.paper import design_paper
    return design_paper(G, **kw)


def _hinf(G, **kw):
    from nanosim.design.architectures.hinf_fourblock import design_hinf_fourblock
    return design_hinf_fourblock(G, **kw)


def _hinf_damped(G, **kw):
    from nanosim.design.architectures.hinf_damped import design_hinf_damped
    return design_hinf_damped(G, **kw)


def _pi_notch(G, **kw):
    from nanosim.design.architectures.pi_notch import design_pi_notch
    return design_pi_notch(G, **kw)


def _damping_tracking(G, **kw):
    from nanosim.design.architectures.damping_tracking import design_damping_tracking
    return design_damping_tracking(G, **kw)


def _robust(G, **kw):
    from nanosim.design.architectures.robust import design_robust
    return design_robust(G, **kw)


def _lqg(G, **kw):
    from nanosim.design.architectures.lqg import design_lqg
    return design_lqg(G, **kw)


def _lqg_nominal(G, **kw):
    import dataclasses

    from nanosim.design.architectures.lqg import design_lqg
    return dataclasses.replace(design_lqg(G, robust=False, **kw), name="lqg-nominal")


def _lqg_gain_range(G, **kw):
    import dataclasses

    from nanosim.design.architectures.lqg import design_lqg
    return dataclasses.replace(design_lqg(G, gain_range_margin=True, **kw), name="lqg-gain-range")


def _irc(G, **kw):
    from nanosim.design.architectures.irc import design_irc
    return design_irc(G, **kw)


def _feedforward(G, **kw):
    from nanosim.design.architectures.feedforward import design_feedforward
    return design_feedforward(G, **kw)


# name -> design function, in scorecard order
BENCH: dict[str, Callable[..., BenchDesign]] = {
    "hinf": _hinf,
    "paper": _paper,
    "hinf-damped": _hinf_damped,
    "pi-notch": _pi_notch,
    "damping-tracking": _damping_tracking,
    "robust": _robust,
    "feedforward": _feedforward,
    "lqg": _lqg,
    "lqg-nominal": _lqg_nominal,
    "lqg-gain-range": _lqg_gain_range,
    "irc": _irc,
}


def _lqg_bandwidth(G, **kw):
    import dataclasses

    from nanosim.design.architectures.lqg import design_lqg
    kw.setdefault("reference_prefilter", False)      # the fastest reference path too (the notch costs ~12 Hz)
    return dataclasses.replace(design_lqg(G, seek_bandwidth=True, **kw), name="lqg-bandwidth")


# every named design: the scored bench, then the rules outside it
DESIGN_RULES: dict[str, Callable[..., BenchDesign]] = {**BENCH, "lqg-bandwidth": _lqg_bandwidth}


def design(name: str, G, **kwargs) -> BenchDesign:
    """Design the named architecture (:data:`DESIGN_RULES`: the bench's and ``lqg-bandwidth``) from ``G``."""
    if name not in DESIGN_RULES:
        raise ValueError(f"name: expected one of {list(DESIGN_RULES)}, got {name!r}")
    return DESIGN_RULES[name](G, **kwargs)


def design_bench(G, names=None, **kwargs) -> dict[str, BenchDesign]:
    """Every (or the named) bench design from ``G``, in :data:`BENCH` order."""
    names = list(BENCH) if names is None else list(names)
    return {n: design(n, G, **kwargs) for n in names}
