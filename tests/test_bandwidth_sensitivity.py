"""The bandwidth experiment's S: its method as a value (formula + explanation), Fig. 18's legend from the formula,
and the direct measurement of nanosim compare (a PRBS at the reading) against it on a linear loop."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from nanosim.design.architectures import design
from nanosim.design.architectures.protocol import ObjectController
from nanosim.design.controller import ControllerConfig, DiscreteController
from nanosim.design.lti import load_state_space_npz
from nanosim.experiments import bandwidth as bw_mod
from nanosim.experiments import registry
from nanosim.pipeline.characterize import make_factory
from nanosim.pipeline.compare import reading_disturbance_sensitivity
from nanosim.plant.stage import StageConfig
from nanosim.plots.experiments import fig_bandwidth

MODEL = Path(__file__).parent / "data" / "identified_seed0.npz"
DURATION_S = bw_mod.PRBS_DURATION_S


@pytest.fixture(scope="module")
def loops():
    """The paper's design (one degree of freedom) and the same feedback with a static reference gain 0.5,
    ``u = K (0.5 r - y)`` as ``u = 0.5 K e - 0.5 K y`` (two degrees of freedom, the same ``K_fb = K``), on the
    linear twin with every electromechanical effect off (a linear loop)."""
    c = design("paper", load_state_space_npz(MODEL)[1]).config
    f = 0.5
    two = ControllerConfig(c.Akd, np.hstack([f * c.Bkd, (f - 1) * c.Bkd]), c.Ckd,
                           np.hstack([f * c.Dkd, (f - 1) * c.Dkd]), c.dt, n_error=3)
    factory, base = make_factory(True, config=StageConfig.ideal())
    return dict(one=c, two=two, factory=factory, base=base)


class _Object:
    """A user's controller object (``step``/``reset`` only, no matrices), as ``module:function`` gives."""

    def __init__(self, config):
        self._k = DiscreteController(config)

    def step(self, error_V, measurement_V):
        return self._k.step(error_V)

    def reset(self, measurement_V=None):
        if measurement_V is None:
            self._k.reset()
        else:
            self._k.reset_at(measurement_V)


def _run(loops, ctrl):
    return bw_mod.bandwidth(loops["factory"], ctrl, seed=0, duration_s=DURATION_S, holds_s=(0.1,), axes=(0,))


def _s_legend(r) -> str:
    fig = fig_bandwidth(r)
    try:
        return fig.axes[0].get_legend().get_texts()[0].get_text()
    finally:
        import matplotlib.pyplot as plt
        plt.close(fig)


@pytest.mark.parametrize("kind, method", [("one", bw_mod.SENSITIVITY_ONE_DOF), ("two", bw_mod.SENSITIVITY_INDIRECT),
                                          ("object", bw_mod.SENSITIVITY_OBJECT)])
def test_the_method_is_a_value_and_the_legend_reads_its_formula(loops, kind, method):
    ctrl = ObjectController(_Object(loops["one"])) if kind == "object" else DiscreteController(loops[kind])
    r = _run(loops, ctrl)
    assert r.sensitivity_method is method
    assert _s_legend(r) == f"measured on the stage: {method.formula}"
    m = json.loads(json.dumps(registry.get("bandwidth").metrics(r)))          # what metrics.json holds
    assert m["sensitivity_formula"] == method.formula
    assert m["sensitivity_method"] == method.describe()
    assert m["sensitivity_method"].startswith(method.formula + ", ") and method.explanation in m["sensitivity_method"]


def test_the_legend_reads_the_formula_field_not_the_text(loops):
    """A formula holding commas and brackets is shown whole: nothing is parsed out of the explanation."""
    import dataclasses
    r = dataclasses.replace(_run(loops, DiscreteController(loops["one"])),
                            sensitivity_method=bw_mod.SensitivityMethod("S(1, 2) (test)", "an explanation, (commas)"))
    assert _s_legend(r) == "measured on the stage: S(1, 2) (test)"


def test_formulas_name_the_two_maps():
    assert bw_mod.SENSITIVITY_ONE_DOF.formula == bw_mod.SENSITIVITY_OBJECT.formula == "I - T"
    assert bw_mod.SENSITIVITY_INDIRECT.formula == "(I + G K_fb)^-1"


def test_direct_and_indirect_sensitivity_agree_on_a_linear_loop(loops):
    """The reading-disturbance measurement (nanosim compare's ``bandwidth_S_feedback_hz``) and the bandwidth
    experiment's indirect one are one quantity: on the linear loop their S bandwidths agree (about 1 % apart, the
    curves about 0.15 dB rms over 5-100 Hz) and are the one-degree-of-freedom loop's (about 34 Hz); the
    reference-to-error map of the two-degree-of-freedom loop is not S."""
    two = _run(loops, DiscreteController(loops["two"]))
    one = _run(loops, DiscreteController(loops["one"]))
    direct = reading_disturbance_sensitivity(loops["factory"], DiscreteController(loops["two"]), seed=0,
                                             duration_s=DURATION_S)
    assert np.array_equal(direct.freq_hz, two.freq_hz)
    assert direct.bandwidth_S_hz == pytest.approx(two.bandwidth_S_hz, rel=0.03)
    assert two.bandwidth_S_hz == pytest.approx(one.bandwidth_S_hz, rel=0.03)
    band = (two.freq_hz > 5.0) & (two.freq_hz < 100.0)
    assert np.sqrt(np.mean(np.log10(two.sigma_S[band] / direct.sigma_S[band]) ** 2)) * 20 < 0.5     # dB rms
    assert abs(two.bandwidth_reference_error_hz / two.bandwidth_S_hz - 1) > 0.1, two.bandwidth_reference_error_hz
