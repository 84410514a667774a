"""Inverse Prandtl-Ishlinskii feedforward: closed-form inverse (Krejci & Kuhnen 2001)."""
import numpy as np
import pytest

from nanosim import constants as C
from nanosim.design.feedforward import InversePIFeedforward, inverse_prandtl_ishlinskii
from nanosim.plant.piezo import PiezoConfig, PlayOperators, PrandtlIshlinskii, loop_hysteresis_percent


def _reversing_input(n=4000):
    """Monotone pieces with reversals at decreasing and increasing amplitudes (piezo V, 0..66)."""
    knots = np.array([0, 60, 10, 45, 25, 66, 0, 30, 5, 50, 0])
    return np.concatenate([np.linspace(a, b, n // 10, endpoint=False) for a, b in zip(knots[:-1], knots[1:])])


def test_inverse_of_two_play_pi_by_hand():
    r, w, w0 = inverse_prandtl_ishlinskii([1.0, 2.0], [0.5, 0.5], 1.0)
    np.testing.assert_allclose(r, [1.0, 2.5], rtol=0, atol=1e-15)
    np.testing.assert_allclose(w, [-1 / 3, -1 / 6], rtol=1e-15)
    assert w0 == 1.0


def test_inverse_composed_with_athermal_pi_is_identity():
    cfg = PiezoConfig.athermal()
    w0, w = cfg.hysteresis_weights()
    v = _reversing_input()[:, None]
    inv = PrandtlIshlinskii(*inverse_prandtl_ishlinskii(cfg.pi_thresholds_V, w, w0), n_channels=1)
    fwd = PrandtlIshlinskii(cfg.pi_thresholds_V, w, w0, n_channels=1)
    np.testing.assert_allclose(fwd.run(inv.run(v)), v, rtol=0, atol=1e-9 * 66)
    inv.reset()
    fwd.reset()
    np.testing.assert_allclose(inv.run(fwd.run(v)), v, rtol=0, atol=1e-9 * 66)


def test_inverse_of_inverse_is_the_operator():
    cfg = PiezoConfig.athermal()
    w0, w = cfg.hysteresis_weights()
    r1, w1, w01 = inverse_prandtl_ishlinskii(cfg.pi_thresholds_V, w, w0)
    # The inverse's weights are negative; its inverse formula holds with W_j > 0 (Krejci & Kuhnen 2001).
    rr = np.concatenate([[0.0], r1])
    ww = np.concatenate([[w01], w1])
    cum = np.cumsum(ww)
    assert np.all(cum > 0)
    r2 = np.array([ww[:j + 1] @ (rr[j] - rr[:j + 1]) for j in range(1, rr.size)])
    w2 = -w1 / (cum[1:] * cum[:-1])
    np.testing.assert_allclose(r2, cfg.pi_thresholds_V, rtol=1e-12)
    np.testing.assert_allclose(w2, w, rtol=1e-12)
    np.testing.assert_allclose(1 / w01, w0, rtol=1e-15)


def test_feedforward_removes_athermal_loop_in_controller_volts():
    cfg = PiezoConfig.athermal()
    n = 4000
    tri = np.concatenate([np.linspace(0, 1, n // 2), np.linspace(1, 0, n - n // 2)])
    u = np.zeros((n, 3))
    u[:, 0] = 1.65 * tri
    w0, w = cfg.hysteresis_weights()
    fwd = PrandtlIshlinskii(cfg.pi_thresholds_V, w, w0, n_channels=3)
    h_plain = fwd.run(C.AMPLIFIER_GAIN * u)[:, 0]
    fwd.reset()
    ff = InversePIFeedforward(cfg)
    h_ff = fwd.run(C.AMPLIFIER_GAIN * ff.run(u))[:, 0]
    pct_plain, _ = loop_hysteresis_percent(u[:, 0], h_plain)
    pct_ff, _ = loop_hysteresis_percent(u[:, 0], h_ff)
    assert pct_plain > 5.0
    assert pct_ff < 1e-6


def _thermal_residual(period_s):
    """Fig. 14 loop width (%) of the thermal operators, without and with the inverse, for a triangle of period_s."""
    cfg = PiezoConfig()
    assert cfg.thermal
    w0, w = cfg.hysteresis_weights()
    va, nu = cfg.activation()
    n = int(period_s * C.CONTROL_RATE_HZ)
    tri = np.concatenate([np.linspace(0, 1, n // 2), np.linspace(1, 0, n - n // 2)])
    v = (33.0 * tri)[:, None]
    plant = PlayOperators(cfg.pi_thresholds_V, w, w0, n_channels=1, activation_V=va, attempt_rate_V_per_s=nu)
    pct_plain, _ = loop_hysteresis_percent(v[:, 0], plant.run(v)[:, 0])
    plant.reset()
    ff = InversePIFeedforward(cfg, n_channels=1, amplifier_gain=1.0)
    pct_ff, _ = loop_hysteresis_percent(v[:, 0], plant.run(ff.run(v))[:, 0])
    return pct_plain, pct_ff


def test_thermal_operators_leave_a_creep_residual_smaller_than_the_loop():
    pct_plain, pct_ff = _thermal_residual(2.0)
    assert pct_ff < pct_plain / 3


def test_residual_grows_with_the_time_the_operators_have_to_relax():
    """The inverse is rate independent; the thermal relaxation (creep) acts over the loop's duration."""
    residual = [_thermal_residual(T)[1] for T in (0.2, 2.0, 20.0)]
    assert residual[0] < residual[1] < residual[2]


@pytest.mark.parametrize("args, name", [
    (([1.0, 1.0], [0.1, 0.1], 1.0), "thresholds_V"),
    (([0.0, 1.0], [0.1, 0.1], 1.0), "thresholds_V"),
    (([1.0, 2.0], [0.1, -0.1], 1.0), "weights"),
    (([1.0, 2.0], [0.1], 1.0), "weights"),
    (([1.0, 2.0], [0.1, 0.1], 0.0), "linear_weight"),
    (([1.0, np.nan], [0.1, 0.1], 1.0), "thresholds_V"),
])
def test_errors_name_the_argument(args, name):
    with pytest.raises(ValueError, match=name):
        inverse_prandtl_ishlinskii(*args)


def test_feedforward_rejects_a_linear_piezo():
    with pytest.raises(ValueError, match="piezo"):
        InversePIFeedforward(PiezoConfig.linear())


@pytest.fixture(scope="module")
def hinf_controller(twin):
    """The paper's mixed-sensitivity design on the reduced linear twin (no identification needed)."""
    from nanosim.design import design_hinf, discretize_controller, reduce_model
    from nanosim.design.controller import DiscreteController

    red = reduce_model(twin.sys_V, order=10)
    kd = discretize_controller(design_hinf(red.G_reduced, G_full=twin.sys_V).K, dt=C.CONTROL_PERIOD_S).Kd
    return lambda: DiscreteController.from_matrices(kd.A, kd.B, kd.C, kd.D, C.CONTROL_PERIOD_S)


def test_fig14_loop_width_and_closed_loop_error_drop_with_the_inverse_on_the_twin(twin, hinf_controller):
    """Thermal operators: the rate-independent inverse leaves the creep and the rate dependence."""
    from nanosim.experiments.hysteresis import hysteresis
    from nanosim.plant.twin import TwinStage

    factory = lambda s: TwinStage(twin, seed=s)
    plain = hysteresis(factory, hinf_controller(), seed=0)
    comp = hysteresis(factory, hinf_controller(), seed=0, feedforward="inverse-pi")
    assert comp.feedforward == "inverse-pi"
    assert plain.open_loop_percent > 10.0                       # the Fig. 14 loop, ~15 %
    assert comp.open_loop_percent < plain.open_loop_percent / 4
    assert comp.open_loop_percent <= 3.0                        # fitted operator, inverted
    rms = lambda r: float(np.sqrt(np.mean(r.closed.error_um[:, 0] ** 2)))
    assert rms(comp) < 0.95 * rms(plain)                        # feedback on a linearised actuator


def test_feedforward_option_is_checked_before_any_work():
    from nanosim.experiments.hysteresis import hysteresis
    from nanosim.pipeline.config import CharacterizeConfig

    def factory(seed):
        raise AssertionError("no stage may be built for a bad option")

    with pytest.raises(ValueError, match="feedforward"):
        hysteresis(factory, None, feedforward="inverse-preisach")
    with pytest.raises(ValueError, match="feedforward"):
        CharacterizeConfig(feedforward="charge")
    assert CharacterizeConfig(feedforward="inverse-pi").feedforward == "inverse-pi"


def test_fit_recovers_the_weights_of_a_pi_operator_on_its_thresholds():
    """On its own thresholds the PI operator is linear in its weights: least squares returns them exactly."""
    from nanosim.design.feedforward import fit_prandtl_ishlinskii
    cfg = PiezoConfig.athermal()
    w0, w = cfg.hysteresis_weights()
    v = _reversing_input()
    h = PrandtlIshlinskii(cfg.pi_thresholds_V, w, w0, n_channels=1).run(v[:, None])[:, 0]
    m = fit_prandtl_ishlinskii(v, h, cfg.pi_thresholds_V)
    np.testing.assert_allclose(m.weights, w, rtol=1e-8, atol=1e-10)
    assert m.linear_weight == pytest.approx(w0, rel=1e-10)
    assert m.residual_rms <= 1e-9 * m.output_rms


def test_inverse_of_a_fitted_operator_is_its_slope_after_a_reversal():
    """InversePI = (PI / k)^-1, k the record's mean slope: the fitted operator behind it maps u to k u."""
    from nanosim.design.feedforward import InversePI, fit_prandtl_ishlinskii, fit_thresholds_V, play_outputs
    v = _reversing_input() / 30.0                                   # controller volts, 0 .. 2.2
    r = fit_thresholds_V(2.2, 6)
    h = 0.7 * v + play_outputs(v, r) @ np.array([0.3, 0.2, 0.1, 0.05, 0.05, 0.02])
    m = fit_prandtl_ishlinskii(v, h, r)
    u_ff = InversePI(m, n_channels=1).run(v[:, None])[:, 0]
    back = m.linear_weight * u_ff + play_outputs(u_ff, m.thresholds_V) @ m.weights
    assert m.mean_slope == pytest.approx(float(h @ v / (v @ v)), rel=1e-12)
    assert m.linear_weight < m.mean_slope < m.linear_weight + m.weights.sum()
    np.testing.assert_allclose(back, m.mean_slope * v, rtol=0, atol=1e-9)


@pytest.mark.parametrize("v, h, r, name", [
    (np.zeros(40), np.zeros(41), [0.1], "h"),
    (np.zeros(40), np.zeros(40), [0.2, 0.1], "thresholds_V"),
    (np.zeros(3), np.zeros(3), [0.1, 0.2], "v"),
    (np.full(40, np.nan), np.zeros(40), [0.1], "v"),
])
def test_fit_errors_name_the_argument(v, h, r, name):
    from nanosim.design.feedforward import fit_prandtl_ishlinskii
    with pytest.raises(ValueError, match=name):
        fit_prandtl_ishlinskii(v, h, r)
