"""The tuning rules of the lqg bench designs as values: :class:`LqgRule` and its named presets.

A rule says which LQG members (:func:`~nanosim.design.architectures.lqg_synthesis.lqg_controller`) are
designed and which checks pick one of them; :func:`~nanosim.design.architectures.lqg.design_lqg` runs it.
The presets are the bench's four LQG designs:

* :meth:`LqgRule.robust` (``lqg``, the default rule of ``design_lqg``): robust over the uncertainty set;
* :meth:`LqgRule.nominal` (``lqg-nominal``): the identified modes and gain, the disk margin only;
* :meth:`LqgRule.gain_range` (``lqg-gain-range``): the robust rule with its disk margin at both ends of the
  set's piezo-gain range, designed at its top;
* :meth:`LqgRule.bandwidth` (``lqg-bandwidth``): the robust rule at the smallest control weight that meets
  every check, without the reference prefilter.

A variant is a value too: ``dataclasses.replace(LqgRule.robust(), control_weight=0.01)``. The rule's
sentence (:attr:`LqgRule.text`, the design's ``tuning_rule``) is built from its fields.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

from nanosim.design.loopargs import check_scale
from nanosim.design.architectures.lqg_synthesis import (
    CONTROL_WEIGHT,
    DISTURBANCE_CORNER_HZ,
    DISTURBANCE_NOISE_V,
    INTEGRAL_WEIGHT,
    MEASUREMENT_INFLATION,
    ROBUST_GAIN_FRACTIONS,
    SHIFT_ABOVE_HZ,
)

__all__ = ["LqgRule", "MIN_DISK_MARGIN", "DEFAULT_LADDER", "ROBUST_FREQ_SCALES", "ROBUST_INFLATIONS",
           "ROBUST_LADDER", "GAIN_RANGE_FRACTIONS", "ROBUST_MIN_DISK_MARGIN", "ROBUST_MU_MAX",
           "ROBUST_MAX_MU_CHECKS", "BANDWIDTH_CONTROL_WEIGHTS", "PREFILTER_RULE", "TUNING_RULE",
           "ROBUST_TUNING_RULE", "GAIN_RANGE_TUNING_RULE", "BANDWIDTH_TUNING_RULE"]

# the nominal rule: the inflation ladder at R_u = CONTROL_WEIGHT, tried in order until the disk margin holds
MIN_DISK_MARGIN = 0.45
DEFAULT_LADDER = tuple((i, CONTROL_WEIGHT) for i in MEASUREMENT_INFLATION)
# the robust rule's members (design frequency scale of the modes above SHIFT_ABOVE_HZ, measurement inflation, R_u)
ROBUST_FREQ_SCALES = (1.03, 1.035, 1.04, 1.045, 1.05)
ROBUST_INFLATIONS = (2.5, 3.0, 4.0, 5.0)
ROBUST_LADDER = tuple((s, i, CONTROL_WEIGHT) for s in ROBUST_FREQ_SCALES for i in ROBUST_INFLATIONS)
# the gain-range rule: from the set's top upwards, inside the piezo's tangent slope after a long monotone move
# (lqg_synthesis.SMALL_SIGNAL_GAIN)
GAIN_RANGE_FRACTIONS = (1.0, 1.25, 1.5)
ROBUST_MIN_DISK_MARGIN = 0.42
ROBUST_MU_MAX = 1.0
# at most this many mixed-mu analyses (the slow part of a design) per design
ROBUST_MAX_MU_CHECKS = 4
# the bandwidth rule: the robust rule at each of these LQR control weights R_u, smallest (the fastest loops) first,
# until one meets every check; from 1/300 of the robust rule's weight up to it
BANDWIDTH_CONTROL_WEIGHTS = (1e-4, 3e-4, 0.001, 0.003, 0.01, 0.03)
PREFILTER_RULE = ("a reference prefilter notches the closed loop's ringing pairs (two degrees of freedom, the "
                  "feedback unchanged)")
# names of the fractions of the set's log gain range (0: its low end, 1: its top)
_FRACTION_NAMES = {0.0: "low end", 0.5: "centre", 0.75: "upper quarter", 1.0: "top"}


def _positive_tuple(name: str, value) -> tuple:
    """``value`` as a non-empty tuple of finite numbers > 0 (``name`` in the error)."""
    try:
        out = tuple(float(v) for v in value)
    except TypeError:
        raise ValueError(f"{name}: expected a sequence of numbers > 0, got {value!r}") from None
    if not out or not all(math.isfinite(v) and v > 0 for v in out):
        raise ValueError(f"{name}: expected a non-empty sequence of finite numbers > 0, got {value!r}")
    return out


def _one_of(items: list) -> str:
    """``a``, ``a or b``, ``a, b or c``."""
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " or " + items[-1]


@dataclass(frozen=True)
class LqgRule:
    """How :func:`~nanosim.design.architectures.lqg.design_lqg` designs and picks its loop.

    Every member of ``freq_scales`` x ``inflations`` (at ``control_weight``) is designed at each design
    gain; a member is taken if it passes the rule's checks.

    Attributes
    ----------
    name : str
        The preset's name (``robust``, ``nominal``, ``gain-range``, ``bandwidth``) or a variant's.
    over_uncertainty : bool
        True: the members are ranked by their predicted noise sigma, the disturbance-observer intensity scales
        with the inflation, and a member must also be stable at every vertex of the uncertainty set and have a
        mixed-mu upper bound below ``mu_max`` over it. False: the members in order, the first with the disk
        margin (checked over the set but not required to pass).
    freq_scales : tuple of float
        Design frequency scales of the structural modes above
        :data:`~nanosim.design.architectures.lqg_synthesis.SHIFT_ABOVE_HZ` (1: the identified modes).
    inflations : tuple of float
        Measurement-noise inflations of the estimator.
    control_weight : float
        LQR control weight ``R_u`` [1/V^2 relative to the output weight].
    gain_fractions : tuple of float or None
        Design piezo gains as fractions of the uncertainty set's log gain range on the identified model
        (:func:`~nanosim.design.architectures.lqg_synthesis.design_input_gains`; 0: its low end, 1: its top);
        None: the identified gain.
    design_input_gain : float or None
        A fixed design piezo gain (factor on the identified model's); overrides ``gain_fractions``.
    min_disk_margin : float
        Smallest accepted multiloop disk margin on the identified model.
    margin_at_gain_top : bool
        Also require ``min_disk_margin`` at the top of the set's gain range (``over_uncertainty`` only).
    mu_max : float
        Mixed-mu upper bound a member must stay below (``over_uncertainty`` only).
    max_mu_checks : int
        At most this many mu analyses per design.
    control_weights : tuple of float or None
        The bandwidth scan: the rule at each of these control weights, smallest first, until its pick
        meets every check (``over_uncertainty`` only); None: ``control_weight`` alone.
    reference_prefilter : bool
        Add the reference notch of :mod:`~nanosim.design.architectures.prefilter` at the loop's ringing pairs.

    Raises
    ------
    ValueError
        A field out of range, naming it.
    """

    name: str = "robust"
    over_uncertainty: bool = True
    freq_scales: tuple = ROBUST_FREQ_SCALES
    inflations: tuple = ROBUST_INFLATIONS
    control_weight: float = CONTROL_WEIGHT
    gain_fractions: tuple | None = ROBUST_GAIN_FRACTIONS
    design_input_gain: float | None = None
    min_disk_margin: float = ROBUST_MIN_DISK_MARGIN
    margin_at_gain_top: bool = False
    mu_max: float = ROBUST_MU_MAX
    max_mu_checks: int = ROBUST_MAX_MU_CHECKS
    control_weights: tuple | None = None
    reference_prefilter: bool = True

    def __post_init__(self):
        if not (isinstance(self.name, str) and self.name):
            raise ValueError(f"name: expected a non-empty string, got {self.name!r}")
        for flag in ("over_uncertainty", "margin_at_gain_top", "reference_prefilter"):
            if not isinstance(getattr(self, flag), bool):
                raise ValueError(f"{flag}: expected True or False, got {getattr(self, flag)!r}")
        set_ = lambda k, v: object.__setattr__(self, k, v)          # noqa: E731 (frozen: normalise in place)
        set_("freq_scales", _positive_tuple("freq_scales", self.freq_scales))
        set_("inflations", _positive_tuple("inflations", self.inflations))
        set_("control_weight", check_scale("control_weight", self.control_weight))
        if self.gain_fractions is not None:
            fr = tuple(self.gain_fractions) if not isinstance(self.gain_fractions, (str, bytes)) else ()
            if not fr or not all(isinstance(q, (int, float)) and math.isfinite(q) for q in fr):
                raise ValueError(f"gain_fractions: expected None or a non-empty sequence of finite numbers, "
                                 f"got {self.gain_fractions!r}")
            set_("gain_fractions", tuple(float(q) for q in fr))
        if self.design_input_gain is not None:
            set_("design_input_gain", check_scale("design_input_gain", self.design_input_gain))
        set_("min_disk_margin", check_scale("min_disk_margin", self.min_disk_margin))
        set_("mu_max", check_scale("mu_max", self.mu_max))
        if not (isinstance(self.max_mu_checks, int) and not isinstance(self.max_mu_checks, bool)
                and self.max_mu_checks >= 1):
            raise ValueError(f"max_mu_checks: expected an integer >= 1, got {self.max_mu_checks!r}")
        if self.control_weights is not None:
            set_("control_weights", _positive_tuple("control_weights", self.control_weights))
        if not self.over_uncertainty:
            for k, bad in (("margin_at_gain_top", self.margin_at_gain_top),
                           ("control_weights", self.control_weights is not None)):
                if bad:
                    raise ValueError(f"{k}: expected over_uncertainty=True (it qualifies the robust rule), "
                                     f"got {k}={getattr(self, k)!r} with over_uncertainty=False")

    # ---------------------------------------------------------------- the bench's presets
    @classmethod
    def robust(cls) -> "LqgRule":
        """The robust rule (``lqg``, the default rule of ``design_lqg``): the ladder over design-model mode scales,
        inflations and piezo gains inside the set, the least-noise member with the disk margin, stable at
        every vertex and mixed mu < 1 over the set.
        """
        return cls()

    @classmethod
    def nominal(cls) -> "LqgRule":
        """The nominal rule (``lqg-nominal``): the identified modes and gain, the inflations
        ``MEASUREMENT_INFLATION`` in order until the disk margin reaches :data:`MIN_DISK_MARGIN`.
        """
        return cls(name="nominal", over_uncertainty=False, freq_scales=(1.0,), inflations=MEASUREMENT_INFLATION,
                   gain_fractions=None, min_disk_margin=MIN_DISK_MARGIN)

    @classmethod
    def gain_range(cls) -> "LqgRule":
        """The gain-range rule (``lqg-gain-range``): the robust rule designed at :data:`GAIN_RANGE_FRACTIONS`
        of the set's gain range, its disk margin required at both ends of the range.
        """
        return cls(name="gain-range", gain_fractions=GAIN_RANGE_FRACTIONS, margin_at_gain_top=True)

    @classmethod
    def bandwidth(cls) -> "LqgRule":
        """The bandwidth rule (``lqg-bandwidth``): the robust rule at each weight of
        :data:`BANDWIDTH_CONTROL_WEIGHTS`, smallest first, until its pick meets every check; no reference
        prefilter (the fastest reference path too).
        """
        return cls(name="bandwidth", control_weights=BANDWIDTH_CONTROL_WEIGHTS, reference_prefilter=False)

    # ---------------------------------------------------------------- the rule in words
    def at_control_weight(self, control_weight: float) -> "LqgRule":
        """This rule at one control weight (no bandwidth scan)."""
        return replace(self, control_weight=control_weight, control_weights=None)

    @property
    def scan_clause(self) -> str:
        """The bandwidth scan in words, the start of :attr:`text` (empty without a scan)."""
        if self.control_weights is None:
            return ""
        return ("the robust rule below at the smallest LQR control weight R_u of "
                + ", ".join(f"{w:g}" for w in self.control_weights)
                + " (the fastest loops first) at which one of its members meets every check: ")

    @property
    def text(self) -> str:
        """The rule in one sentence (a design's ``tuning_rule``, without the prefilter clause)."""
        if self.control_weights is not None:
            return self.scan_clause + replace(self, control_weights=None).text
        if not self.over_uncertainty:
            return ("LQG on the identified model (the loop as run): Kalman filter from the stage's DAC (input) "
                    f"and gauge (reading, inflated x{self.inflations[0]:g}, more if the multiloop disk margin "
                    f"falls below {self.min_disk_margin:g}) noise levels plus an input-disturbance observer "
                    f"(hysteresis, {DISTURBANCE_CORNER_HZ:g} Hz process, {DISTURBANCE_NOISE_V:g} V per sample), "
                    f"LQR on the reading and its leaky integral (R_u = {self.control_weight:g}, "
                    f"Q_i = {INTEGRAL_WEIGHT:g})")
        s, i = self.freq_scales, self.inflations
        top = " at both ends of the set's gain range" if self.margin_at_gain_top else ""
        return ("LQG on the identified model (the loop as run), robust over the stage's uncertainty set: the "
                f"design model's piezo gain {self._gain_phrase()} (the identified model holds its low end, the slope "
                f"after a reversal), its structural modes above {SHIFT_ABOVE_HZ:g} Hz designed at "
                f"x{_range(s)}, measurement inflation {_range(i)} (disturbance-observer intensity x inflation / "
                f"{MEASUREMENT_INFLATION[0]:g}), R_u = {self.control_weight:g}, Q_i = {INTEGRAL_WEIGHT:g}; of "
                "these, the member with the least predicted noise sigma that has a multiloop disk margin >= "
                f"{self.min_disk_margin:g}{top}, is stable at every vertex of the set and has a mixed-mu upper "
                f"bound < {self.mu_max:g} over it")

    def _gain_phrase(self) -> str:
        if self.design_input_gain is not None:
            return f"at {self.design_input_gain:.3g} x the identified model's"
        fr = self.gain_fractions
        if fr is None:
            return "at the identified model's"
        if all(q in _FRACTION_NAMES for q in fr):
            return f"at the {_one_of([_FRACTION_NAMES[q] for q in fr])} of the set's gain range"
        if all(q >= 1.0 for q in fr):
            from nanosim.design.architectures.lqg_synthesis import design_input_gains
            ratio = [g / design_input_gains((1.0,))[0] for g in design_input_gains(fr)]
            return f"at {_one_of([f'{r:.3g}' for r in ratio])} x the top of the set's gain range"
        return (f"at the fractions {_one_of([f'{q:g}' for q in fr])} of the set's log gain range (0: its low end, "
                "1: its top)")


def _range(v: tuple) -> str:
    """``a-b`` of a ladder's first and last values (``a`` for one value)."""
    return f"{v[0]:g}" if len(v) == 1 else f"{v[0]:g}-{v[-1]:g}"


# the presets' sentences
TUNING_RULE = LqgRule.nominal().text
ROBUST_TUNING_RULE = LqgRule.robust().text
GAIN_RANGE_TUNING_RULE = LqgRule.gain_range().text
# the bandwidth rule's sentence before the robust rule's
BANDWIDTH_TUNING_RULE = LqgRule.bandwidth().scan_clause
