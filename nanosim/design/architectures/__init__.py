"""The controller bench: every design a pure function of the identified model, behind one entry.

Front door: ``design(name, G, **kwargs) -> BenchDesign`` designs the named member of :data:`REGISTRY` from the
identified plant ``G`` (a discrete ``Akd, Bkd, Ckd, Dkd, dt, n_error`` controller with its tuning rule, the
layout of ``controller.npz``). A member (:class:`BenchMember`) names its design function and, where the
function takes one, its tuning rule as a value (the LQG members: an
:class:`~nanosim.design.architectures.lqg_rules.LqgRule` preset)::

    from nanosim.design.architectures import design
    from nanosim.design.architectures.lqg_rules import LqgRule
    d = design("lqg-nominal", G)                       # = design_lqg(G, LqgRule.nominal()), named lqg-nominal
    d = design("lqg", G, rule=dataclasses.replace(LqgRule.robust(), control_weight=0.01))

The scored bench (:data:`BENCH`, in scorecard order):

* ``hinf`` (:mod:`.hinf_fourblock`) -- four-block H-infinity (S, SG, KS, T): the paper's weights plus an
  input-disturbance channel, so the optimum damps the first pair (the exported default);
* ``paper`` (:mod:`.paper`) -- the paper's 10-state single-loop H-infinity design;
* ``hinf-damped`` (:mod:`.hinf_damped`) -- H-infinity around an inner damping loop, delay-aware;
* ``pi-notch`` (:mod:`.pi_notch`) -- decoupled PI with notches (the industry baseline);
* ``damping-tracking`` (:mod:`.damping_tracking`) -- positive position feedback plus integral tracking;
* ``robust`` (:mod:`.robust`) -- Glover-McFarlane H-infinity loop shaping against the stage's uncertainty set;
* ``feedforward`` (:mod:`.feedforward`) -- model-inversion feedforward on top of a feedback design;
* ``lqg`` (:mod:`.lqg`, :meth:`~.lqg_rules.LqgRule.robust`) -- H2-optimal output feedback with integral
  action from the stage's noise levels, robust over the uncertainty set; ``lqg-nominal``
  (:meth:`~.lqg_rules.LqgRule.nominal`) -- the same designed on the identified modes (not robust to one extra
  sample of delay with the modes 3 % higher); ``lqg-gain-range`` (:meth:`~.lqg_rules.LqgRule.gain_range`) --
  the robust lqg with its disk margin required at both ends of the set's piezo-gain range (the identified slope
  after a reversal and the nominal slope of a monotone move), designed at the range's top;
* ``irc`` (:mod:`.irc`) -- integral resonant control per decoupled axis plus integral tracking.

Outside the scored bench (in :data:`DESIGN_RULES`, which :func:`design` accepts too): ``lqg-bandwidth``
(:meth:`~.lqg_rules.LqgRule.bandwidth`) -- the robust lqg at the smallest control weight (from 1/300 of its
own up) at which its pick meets every check, without the reference prefilter: the fastest loops its
robustness checks accept (``nanosim sweep --architecture lqg-bandwidth``).

Below the bench: the shared pieces (:mod:`.common`: the result type, filters, decoupling, the fast loop
checks), the building blocks of :mod:`nanosim.design` (H-infinity synthesis, reduction, weights, damping,
discretization) and its analysis (loop maps, margins, mu, uncertainty, :mod:`nanosim.design.robustness`).
:mod:`.protocol` turns a name, a file or ``module:function`` into a controller.
"""
from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass
from typing import Any, Callable

from nanosim.design.architectures.common import DT_S, BenchDesign
from nanosim.design.architectures.lqg_rules import LqgRule

__all__ = ["REGISTRY", "BENCH", "DESIGN_RULES", "BenchMember", "BenchDesign", "LqgRule", "design", "design_bench",
           "DT_S"]


@dataclass(frozen=True)
class BenchMember:
    """One named design of the bench: the function that designs it and the rule it is given.

    Attributes
    ----------
    name : str
        Bench name (``lqg-nominal``); the design's ``name``.
    module : str
        Module of the design function (imported on first use).
    function : str
        Its name: ``function(G, **kwargs) -> BenchDesign``.
    rule : object or None
        The tuning rule passed as ``rule=`` (None: the function's own, fixed rule).
    scored : bool
        In the scored bench (:data:`BENCH`) or outside it (only :data:`DESIGN_RULES`).
    """

    name: str
    module: str
    function: str
    rule: Any = None
    scored: bool = True

    def design(self, G, **kwargs) -> BenchDesign:
        """The design from ``G``: ``function(G, rule=self.rule, **kwargs)``, named :attr:`name`.

        ``kwargs`` go to the design function; a ``rule`` among them replaces the member's.
        """
        fn = getattr(importlib.import_module(self.module), self.function)
        if self.rule is not None:
            kwargs.setdefault("rule", self.rule)
        d = fn(G, **kwargs)
        return d if d.name == self.name else dataclasses.replace(d, name=self.name)


_A = "nanosim.design.architectures."
# every named design, the scored bench (in scorecard order) first
REGISTRY: dict[str, BenchMember] = {m.name: m for m in (
    BenchMember("hinf", _A + "hinf_fourblock", "design_hinf_fourblock"),
    BenchMember("paper", _A + "paper", "design_paper"),
    BenchMember("hinf-damped", _A + "hinf_damped", "design_hinf_damped"),
    BenchMember("pi-notch", _A + "pi_notch", "design_pi_notch"),
    BenchMember("damping-tracking", _A + "damping_tracking", "design_damping_tracking"),
    BenchMember("robust", _A + "robust", "design_robust"),
    BenchMember("feedforward", _A + "feedforward", "design_feedforward"),
    BenchMember("lqg", _A + "lqg", "design_lqg", LqgRule.robust()),
    BenchMember("lqg-nominal", _A + "lqg", "design_lqg", LqgRule.nominal()),
    BenchMember("lqg-gain-range", _A + "lqg", "design_lqg", LqgRule.gain_range()),
    BenchMember("irc", _A + "irc", "design_irc"),
    BenchMember("lqg-bandwidth", _A + "lqg", "design_lqg", LqgRule.bandwidth(), scored=False),
)}

# name -> design function (G, **kwargs) -> BenchDesign: the scored bench, in scorecard order
BENCH: dict[str, Callable[..., BenchDesign]] = {n: m.design for n, m in REGISTRY.items() if m.scored}
# every named design: the scored bench, then the rules outside it
DESIGN_RULES: dict[str, Callable[..., BenchDesign]] = {n: m.design for n, m in REGISTRY.items()}


def design(name: str, G, **kwargs) -> BenchDesign:
    """Design the named member of :data:`REGISTRY` (:data:`DESIGN_RULES`: the bench's and ``lqg-bandwidth``)
    from the identified plant ``G``.

    Parameters
    ----------
    name : str
        A key of :data:`REGISTRY`.
    G : control.StateSpace
        Identified plant (controller V -> sensor V), discrete at the control period or continuous.
    **kwargs
        Passed to the design function (``dt``, ``delay_samples``, a ``rule`` value, ...).

    Returns
    -------
    BenchDesign

    Raises
    ------
    ValueError
        ``name`` is not a registered design.
    """
    if name not in REGISTRY:
        raise ValueError(f"name: expected one of {list(REGISTRY)}, got {name!r}")
    return REGISTRY[name].design(G, **kwargs)


def design_bench(G, names=None, **kwargs) -> dict[str, BenchDesign]:
    """Every (or the named) bench design from ``G``, in :data:`BENCH` order."""
    names = list(BENCH) if names is None else list(names)
    return {n: design(n, G, **kwargs) for n in names}
