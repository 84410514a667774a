"""The calibrated parameters of the stage model, in one list.

Every other model parameter has a datasheet, the paper or a formula from the geometry as its source
(``nanosim/constants.py``, ``nanosim/mjcf/README.md``). The parameters below were set by fitting the model to
a named figure of the paper, each within a stated bound ``[a, b]`` (a fabrication tolerance, or a range the
sources give), or without a bound and then checked inside a sourced range. The validation page
(``tools/make_validation_page.py``) reads this list for its table of fitted against predicted quantities:
a paper figure a parameter was fitted to is not a prediction of the model.

A parameter whose value sits on its bound (``on_bound``) says the fit wanted more than the bound allows.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["CalibratedParameter", "CALIBRATED_PARAMETERS", "fitted_figures"]


@dataclass(frozen=True)
class CalibratedParameter:
    """One calibrated model parameter.

    Attributes
    ----------
    name : str
        The parameter, as the code names it (a dotted path or a constant).
    value : float
        Its calibrated value, in ``unit``.
    unit : str
    bound : tuple of float or None
        ``(a, b)`` in ``unit``: the fit's bound, or the sourced range an unbounded fit is checked
        against (``bounded`` tells which); None: no bound and no range.
    bounded : bool
        True if the fit was constrained to ``bound``; False if ``bound`` is only a check.
    source_figure : str
        The paper's figure or number the parameter was fitted to.
    method : str
        How it was set (the tool or function, the residual).
    """

    name: str
    value: float
    unit: str
    bound: tuple[float, float] | None
    bounded: bool
    source_figure: str
    method: str

    def __post_init__(self):
        if not math.isfinite(self.value):
            raise ValueError(f"{self.name}: value: expected a finite number, got {self.value!r}")
        if self.bound is not None:
            a, b = self.bound
            if not a <= b:
                raise ValueError(f"{self.name}: bound: expected (a, b) with a <= b, got {self.bound!r}")

    @property
    def on_bound(self) -> bool:
        """The value is at an end of its bound (within 1e-6 of the bound's width)."""
        if self.bound is None:
            return False
        a, b = self.bound
        tol = 1e-6 * max(b - a, abs(b), 1e-300)
        return abs(self.value - a) <= tol or abs(self.value - b) <= tol

    @property
    def inside(self) -> bool:
        """The value lies within its bound (True when there is none)."""
        return self.bound is None or self.bound[0] - 1e-12 <= self.value <= self.bound[1] + 1e-12

    def to_dict(self) -> dict:
        """JSON-ready, with ``on_bound`` and ``inside``."""
        return {"name": self.name, "value": self.value, "unit": self.unit,
                "bound": None if self.bound is None else list(self.bound), "bounded": self.bounded,
                "on_bound": self.on_bound, "inside": self.inside, "source_figure": self.source_figure,
                "method": self.method}


_GEOMETRY_FIT = ("the paper's six modes (Sec. 3, Appendix A) and the nine static-gain entries (3.0 um/V x J)",
                 "nanosim.plant.calibrate.fit over CALIBRATION_PARAMS, least squares, best of twelve starts "
                 "(tools/calibrate_stage.py); result in nanosim.plant.geometry.CALIBRATED_GEOMETRY")
_EDM_UM = 10.0            # standard wire-EDM tolerance on a notch web and a cut radius (mjcf/SOURCES.md item 8)
_DESIGN_WEB_UM = {"fb1": 300.0, "fb2": 80.0, "swing": 175.0, "apa": 400.0}
_WEB_UM = {"a_fb1": 296.1, "a_fb2": 77.5, "a_swing": 172.7, "a_apa": 399.0,
           "b_fb1": 293.8, "b_fb2": 83.3, "b_swing": 185.0, "b_apa": 398.3,
           "c_fb1": 302.8, "c_fb2": 78.5, "c_swing": 172.9, "c_apa": 400.7}
_TARGET_SIDE_DESIGN_MM = 14.7      # its mass within +/-10 %: the side within the cube roots of 0.9 and 1.1


def _webs() -> tuple[CalibratedParameter, ...]:
    out = []
    for key, t in _WEB_UM.items():
        d = _DESIGN_WEB_UM[key[2:]]
        out.append(CalibratedParameter(f"chain {key[0]} {key[2:]} notch web", t, "um", (d - _EDM_UM, d + _EDM_UM),
                                       True, *_GEOMETRY_FIT))
    return tuple(out)


CALIBRATED_PARAMETERS: tuple[CalibratedParameter, ...] = _webs() + (
    CalibratedParameter("notch cut radius", 1.071, "mm", (1.060, 1.080), True, *_GEOMETRY_FIT),
    CalibratedParameter("four-bar 1 rocker width", 11.596, "mm", (11.5, 11.7), True, *_GEOMETRY_FIT),
    CalibratedParameter("leg rocker width", 2.988, "mm", (2.9, 3.1), True, *_GEOMETRY_FIT),
    CalibratedParameter("target cube side", 14.834, "mm", (round(_TARGET_SIDE_DESIGN_MM * 0.9 ** (1 / 3), 3),
                                                            round(_TARGET_SIDE_DESIGN_MM * 1.1 ** (1 / 3), 3)),
                        True, *_GEOMETRY_FIT),
    CalibratedParameter("DampingSpec.hinge_loss_factor", 4.8e-3, "1", None, False,
                        "the paper's modal damping ratios (Appendix A)",
                        "nanosim.plant.calibrate.fit_damping, relative least squares over the six modes"),
    CalibratedParameter("DampingSpec.piezo_loss_factor", 0.0494, "1", None, False,
                        "the paper's modal damping ratios (Appendix A)",
                        "nanosim.plant.calibrate.fit_damping, relative least squares over the six modes"),
    CalibratedParameter("THERMAL_DRIFT_K_RMS", 0.0594, "K rms", (1e-3, 0.1), True,
                        "the open-loop sigma at rest, 11.4 nm (Sec. 5)",
                        "tools/fit_drift_level.py: mean variance over 20 stages' X and Y probes, every broadband "
                        "source at its datasheet level (constants.THERMAL_DRIFT_K_BOUNDS)"),
    CalibratedParameter("CREEP_PER_DECADE", 0.015, "1 per decade", (0.01, 0.02), True,
                        "the open-loop creep of Fig. 15 (PI: 1-2 % per decade)",
                        "the middle of the published range; sets the activation voltage of the thermally activated "
                        "play operators (nanosim.plant.piezo.activation_voltage_for_creep)"),
    CalibratedParameter("piezo hysteresis weight scale (play operators, linear weight w0)", 0.7524, "1",
                        (0.65, 0.85), False, "the open-loop hysteresis loop of Fig. 14 (15 % output, 14 % input)",
                        "least squares on the loop's width, no bound; w0 checked inside the Rayleigh-law band "
                        "(mjcf/SOURCES.md item 3)"),
)


def fitted_figures() -> set[str]:
    """The paper figures some parameter was fitted to (``source_figure`` of every entry)."""
    return {p.source_figure for p in CALIBRATED_PARAMETERS}
