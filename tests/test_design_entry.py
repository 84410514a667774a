"""The design layer's front door: ``design(name, G)`` over the bench registry, and the LQG rules as values.

Model: ``tests/data/identified_seed0.npz`` (``nanosim identify --seed 0``), as in ``tests/test_lqg.py``.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

ct = pytest.importorskip("control")

from nanosim.design.architectures import BENCH, DESIGN_RULES, REGISTRY, BenchMember, design  # noqa: E402
from nanosim.design.architectures.common import (  # noqa: E402
    DT_S,
    analysis_grid_hz,
    closed_loop_spectral_radius,
    disk_margin_summary,
    freqresp_z,
    loop_response,
    split_2dof,
)
from nanosim.design.architectures.lqg import (  # noqa: E402
    CONTROL_WEIGHT,
    DISTURBANCE_NOISE_V,
    MEASUREMENT_INFLATION,
    MIN_DISK_MARGIN,
    LqgRule,
    design_lqg,
    lqg_controller,
)
from nanosim.design.lti import load_state_space_npz  # noqa: E402

MODEL = Path(__file__).parent / "data" / "identified_seed0.npz"


@pytest.fixture(scope="module")
def model():
    return load_state_space_npz(MODEL)[1]


def _same(a, b) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(a.matrices, b.matrices))


# ----------------------------------------------------------------------------------------
# the registry
# ----------------------------------------------------------------------------------------
def test_registry_holds_every_named_design_and_the_bench_in_scorecard_order():
    assert list(DESIGN_RULES) == list(REGISTRY)
    assert list(BENCH) == ["hinf", "paper", "hinf-damped", "pi-notch", "damping-tracking", "robust", "feedforward",
                           "lqg", "lqg-nominal", "lqg-gain-range", "irc"]
    assert [n for n, m in REGISTRY.items() if not m.scored] == ["lqg-bandwidth"]
    rules = {n: m.rule for n, m in REGISTRY.items() if m.rule is not None}
    assert rules == {"lqg": LqgRule.robust(), "lqg-nominal": LqgRule.nominal(), "lqg-gain-range": LqgRule.gain_range(),
                     "lqg-bandwidth": LqgRule.bandwidth()}
    assert all(isinstance(m, BenchMember) and m.name == n for n, m in REGISTRY.items())


def test_design_names_the_argument_of_an_unknown_name(model):
    with pytest.raises(ValueError, match=r"name: expected one of \['hinf', .*'lqg-bandwidth'\], got 'pid'"):
        design("pid", model)


def test_the_package_front_door_is_the_bench_entry():
    import nanosim.design as nd
    from nanosim.design import architectures
    assert nd.design is architectures.design and nd.REGISTRY is architectures.REGISTRY
    assert nd.LqgRule is LqgRule


def test_a_registered_rule_gives_the_same_controller_as_the_rule_passed_by_hand(model):
    """design("lqg-nominal") is design_lqg with the nominal rule, named after the member; a rule passed to
    design() replaces the member's."""
    d = design("lqg-nominal", model)
    assert d.name == "lqg-nominal" and d.parameters["rule"] == "nominal"
    by_hand = design_lqg(model, LqgRule.nominal())
    assert by_hand.name == "lqg" and _same(d, by_hand) and d.tuning_rule == by_hand.tuning_rule
    d2 = design("lqg", model, rule=LqgRule.nominal())
    assert d2.name == "lqg" and _same(d2, by_hand)


# ----------------------------------------------------------------------------------------
# the LQG rules
# ----------------------------------------------------------------------------------------
def test_nominal_rule_is_the_first_inflation_with_the_disk_margin_built_by_hand(model):
    """The nominal rule on the identified model: the ladder MEASUREMENT_INFLATION at R_u = CONTROL_WEIGHT in
    order, the first loop stable with a multiloop disk margin >= 0.45 -- the controller built here by hand from
    lqg_controller, to the bit."""
    rule = dataclasses.replace(LqgRule.nominal(), reference_prefilter=False)
    d = design_lqg(model, rule)
    f = analysis_grid_hz(DT_S, n=400)
    Gf = freqresp_z(model, f)
    for infl in MEASUREMENT_INFLATION:
        K = lqg_controller(model, measurement_inflation=infl, control_weight=CONTROL_WEIGHT,
                           disturbance_noise_V=DISTURBANCE_NOISE_V)
        Ke, Ky = split_2dof(K, 3)
        if closed_loop_spectral_radius(model, Ke, Ky, 0) >= 1.0:
            continue
        if disk_margin_summary(loop_response(Gf, f, Ke, Ky, delay_samples=0))["multiloop"] >= MIN_DISK_MARGIN:
            break
    assert infl == 3.0 and d.parameters["measurement_inflation"] == infl
    assert all(np.array_equal(a, np.asarray(b, float)) for a, b in zip(d.matrices[:4], (K.A, K.B, K.C, K.D)))
    p = d.parameters
    assert p["controller_order"] == 43 and p["design_input_gain"] == 1.0 and p["design_freq_scale"] == 1.0
    assert p["predicted_disk_margin"]["multiloop"] == pytest.approx(0.694, abs=0.001)
    assert p["predicted_bandwidth_S_hz"] == pytest.approx(54.1, abs=0.1)


def test_presets_are_the_documented_rules():
    r, n, g, b = LqgRule.robust(), LqgRule.nominal(), LqgRule.gain_range(), LqgRule.bandwidth()
    assert (r.over_uncertainty, r.min_disk_margin, r.mu_max, r.max_mu_checks) == (True, 0.42, 1.0, 4)
    assert len(r.freq_scales) * len(r.inflations) == 20 and r.gain_fractions == (0.5, 0.75, 1.0)
    assert (n.over_uncertainty, n.freq_scales, n.inflations, n.gain_fractions, n.min_disk_margin) == \
        (False, (1.0,), MEASUREMENT_INFLATION, None, 0.45)
    assert g.margin_at_gain_top and g.gain_fractions == (1.0, 1.25, 1.5)
    assert b.control_weights == (1e-4, 3e-4, 1e-3, 3e-3, 0.01, 0.03) and b.reference_prefilter is False
    assert dataclasses.replace(r, name="gain-range", gain_fractions=(1.0, 1.25, 1.5), margin_at_gain_top=True) == g


def test_rule_text_follows_the_rule_values():
    r = LqgRule.robust()
    assert "piezo gain at the centre, upper quarter or top of the set's gain range" in r.text
    assert "modes above 300 Hz designed at x1.03-1.05, measurement inflation 2.5-5" in r.text
    assert "R_u = 0.03, Q_i = 0.03" in r.text and "disk margin >= 0.42, is stable" in r.text
    g = LqgRule.gain_range().text
    assert "piezo gain at 1, 1.07 or 1.15 x the top of the set's gain range" in g
    assert "disk margin >= 0.42 at both ends of the set's gain range, is stable" in g
    assert "R_u = 0.01, Q_i" in dataclasses.replace(r, control_weight=0.01).text
    assert "mixed-mu upper bound < 0.5 over it" in dataclasses.replace(r, mu_max=0.5).text
    b = LqgRule.bandwidth()
    assert b.text == b.scan_clause + dataclasses.replace(b, control_weights=None).text
    assert b.scan_clause.startswith("the robust rule below at the smallest LQR control weight R_u of "
                                    "0.0001, 0.0003, 0.001, 0.003, 0.01, 0.03 (the fastest loops first)")
    assert LqgRule.robust().scan_clause == ""
    assert "inflated x3, more if the multiloop disk margin falls below 0.45" in LqgRule.nominal().text
    assert b.at_control_weight(0.003) == dataclasses.replace(b, control_weight=0.003, control_weights=None)


@pytest.mark.parametrize("kwargs, argument", [
    ({"inflations": ()}, "inflations"),
    ({"freq_scales": (1.0, -1.0)}, "freq_scales"),
    ({"control_weight": 0.0}, "control_weight"),
    ({"min_disk_margin": float("nan")}, "min_disk_margin"),
    ({"mu_max": -1.0}, "mu_max"),
    ({"max_mu_checks": 0}, "max_mu_checks"),
    ({"max_mu_checks": 2.0}, "max_mu_checks"),
    ({"gain_fractions": ("top",)}, "gain_fractions"),
    ({"design_input_gain": 0}, "design_input_gain"),
    ({"control_weights": ()}, "control_weights"),
    ({"over_uncertainty": "yes"}, "over_uncertainty"),
    ({"name": ""}, "name"),
    ({"over_uncertainty": False, "margin_at_gain_top": True}, "margin_at_gain_top"),
    ({"over_uncertainty": False, "control_weights": (0.01,)}, "control_weights"),
])
def test_bad_rule_arguments_raise_naming_the_argument(kwargs, argument):
    with pytest.raises(ValueError, match=rf"^{argument}: expected"):
        LqgRule(**kwargs)


def test_design_lqg_refuses_a_rule_that_is_not_an_lqg_rule(model):
    with pytest.raises(ValueError, match="rule: expected an LqgRule"):
        design_lqg(model, "nominal")
