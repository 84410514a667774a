"""Every closed-loop experiment starts from the state LoopProtocol states, whatever the controller object holds."""
import json

import numpy as np
import pytest

from nanosim import experiments
from nanosim.design.controller import ControllerConfig, DiscreteController
from nanosim.experiments import bandwidth as bw_mod
from nanosim.experiments import registry
from nanosim.experiments.batch_loop import BatchController, run_closed_loop_batch
from nanosim.experiments.loop import FS, LOOP_PROTOCOL, LoopProtocol, run_closed_loop
from nanosim.experiments.registry import ExperimentContext
from nanosim.plant.batch import BatchTwinStage
from nanosim.plant.modes import modal_analysis
from nanosim.plant.stage import StageConfig
from nanosim.plant.twin import TwinStage
from integrator_loop import integrator_controller


@pytest.fixture(scope="module")
def setup(ideal, twin):
    G0 = modal_analysis(ideal.model).static_gain_um_per_V
    home = ideal.table_um.copy()

    def factory(seed, config=StageConfig()):
        return TwinStage(twin, seed=seed, config=config, home_um=home)
    return dict(G0=G0, home=home, factory=factory, twin=twin)


def _dirty(ctrl: DiscreteController) -> None:
    """A state far from any start: what a controller object holds after some other run."""
    ctrl.reset(np.linspace(-0.4, 0.6, ctrl.config.n_states))


# --- the protocol itself ---------------------------------------------------------------------------
def test_protocol_weights_approach_monotonically_then_hold():
    p = LoopProtocol(approach_s=0.1, hold_s=0.05)
    w = p.weights()
    assert p.n_approach == 400 and p.n_hold == 200 and len(w) == p.n_before_record == 600
    assert w[0] == 0.0 and np.all(np.diff(w[:400]) > 0) and np.all(w[400:] == 1.0)
    # raised cosine: the slope vanishes at both ends and is largest (pi/2 per approach) in the middle
    assert np.abs(np.diff(w[:400])).max() == pytest.approx(np.pi / 2 / 400, rel=1e-4)
    assert LoopProtocol(0.0, 0.0).weights().shape == (0,)
    assert p.with_hold(3.0) == LoopProtocol(0.1, 3.0)
    d = LOOP_PROTOCOL.describe()
    assert d["approach_s"] == LOOP_PROTOCOL.approach_s and d["hold_s"] == LOOP_PROTOCOL.hold_s
    assert "reset_at" in d["controller_start"]


@pytest.mark.parametrize("kw", [dict(approach_s=-0.1), dict(hold_s=float("nan")), dict(hold_s="x")])
def test_protocol_rejects_bad_durations_naming_them(kw):
    with pytest.raises(ValueError, match=next(iter(kw))):
        LoopProtocol(**kw)


def test_run_closed_loop_rejects_a_protocol_of_another_type(setup):
    ctrl = DiscreteController(integrator_controller(setup["G0"], f_hz=15.0))
    with pytest.raises(ValueError, match="protocol"):
        run_closed_loop(setup["factory"](0), ctrl, np.zeros((10, 3)), protocol=0.6)


@pytest.mark.parametrize("two_dof", [False, True])
def test_a_dirty_controller_gives_the_fresh_controllers_bits(setup, two_dof):
    # rule 1: one start for one- and two-degree-of-freedom controllers alike
    cfg = integrator_controller(setup["G0"], two_dof, f_hz=15.0)
    ref = np.zeros((400, 3))
    ref[100:, 0] = 1.0
    fresh = run_closed_loop(setup["factory"](4), DiscreteController(cfg), ref)
    used = DiscreteController(cfg)
    _dirty(used)
    again = run_closed_loop(setup["factory"](4), used, ref)
    for k in ("y_um", "table_um", "u_V"):
        assert np.array_equal(getattr(fresh, k), getattr(again, k)), k


def test_the_record_starts_on_the_first_reference(setup):
    # noise-free linear twin, a 2 Hz pure integrator (time constant 80 ms): after the 25 um approach and a
    # 0.6 s hold (7.5 time constants, e^-7.5 = 5.5e-4) the reading sits on ref[0] to 0.05 % of the move
    g = 2 * np.pi * 2.0 / FS * np.linalg.inv(setup["G0"] / 5.0)
    ctrl = DiscreteController(ControllerConfig(np.eye(3), np.eye(3), g, g, 1 / FS))
    ref = np.tile([1.0, -0.5, 0.3], (50, 1))
    tr = run_closed_loop(setup["factory"](0, StageConfig.ideal()), ctrl, ref, protocol=LoopProtocol(0.2, 0.6))
    move = np.abs(ref[0] - setup["home"]).max()
    assert move > 20.0
    assert np.abs(tr.y_um[0] - ref[0]).max() < 5e-4 * move


def test_batch_members_start_like_the_single_loop(setup):
    cfg = integrator_controller(setup["G0"], two_dof=True, f_hz=15.0)
    bank = BatchController([cfg, cfg])
    bank.feedback(np.full((2, 3), 0.3), np.zeros((2, 3)))            # a state left by another run
    ref = np.zeros((300, 3))
    ref[50:, 1] = -1.0
    p = LoopProtocol(0.05, 0.02)
    st = BatchTwinStage([setup["twin"]] * 2, [2, 3], home_um=setup["home"])
    traces = run_closed_loop_batch(st, bank, ref, protocol=p)
    for b, s in enumerate((2, 3)):
        single = run_closed_loop(setup["factory"](s), DiscreteController(cfg), ref, protocol=p)
        assert np.array_equal(single.y_um, traces[b].y_um)


# --- every registered experiment ------------------------------------------------------------------
@pytest.mark.parametrize("name", experiments.load_builtin())
def test_every_registered_experiment_run_twice_with_one_controller_object_gives_the_same_bits(setup, name):
    """The same controller object, run twice (its state dirtied in between): the same metrics, bit for bit.

    Fails for an experiment that runs a second closed loop with the state its first one left.
    """
    exp = experiments.get(name)
    ctrl = DiscreteController(integrator_controller(setup["G0"], f_hz=15.0))
    ctx = ExperimentContext(factory=setup["factory"], controller=ctrl, seed=1, static_gain_um_per_V=setup["G0"])
    first = json.dumps(exp.metrics(exp.run(ctx)), sort_keys=True)
    _dirty(ctrl)
    second = json.dumps(exp.metrics(exp.run(ctx)), sort_keys=True)
    assert first == second


def test_the_step_after_the_prbs_record_equals_a_step_with_a_fresh_controller(setup):
    # bandwidth() runs the PRBS record and then the steps with one controller object: each step must be
    # the step a brand-new controller gives
    cfg = integrator_controller(setup["G0"], f_hz=15.0)
    r = bw_mod.bandwidth(setup["factory"], DiscreteController(cfg), seed=2, duration_s=1.1, holds_s=(0.1,),
                         axes=(0,))
    assert [(c.axis, c.sign, c.hold_s) for c in r.steps] == [(0, 1, 0.1), (0, -1, 0.1)]
    for i, c in enumerate(r.steps):
        alone = bw_mod.step_case(setup["factory"], DiscreteController(cfg), 2, c.axis, c.sign, c.hold_s, index=i)
        assert np.array_equal(alone.trace.y_um, c.trace.y_um)
        assert alone.settling_ms == c.settling_ms
    # the headline is the first case when +X after 1 s is not measured
    assert r.settling_ms == r.steps[0].settling_ms


def test_bandwidth_reports_each_step_case_and_the_worst(setup):
    cfg = integrator_controller(setup["G0"], f_hz=5.0, leak=1.0)
    r = bw_mod.bandwidth(setup["factory"], DiscreteController(cfg), seed=0, duration_s=1.1, holds_s=(0.05, 0.1))
    m = registry.get("bandwidth").metrics(r)                      # what metrics.json holds
    assert len(m["step_2um_cases"]) == 8
    assert {(c["axis"], c["sign"], c["hold_s"]) for c in m["step_2um_cases"]} == \
        {(a, s, h) for a in "XY" for s in (1, -1) for h in (0.05, 0.1)}
    worst = m["step_2um_worst"]
    assert worst["settling_ms"] == max(c["settling_ms"] for c in m["step_2um_cases"])
    assert worst["overshoot_percent"] == max(c["overshoot_percent"] for c in m["step_2um_cases"])
    assert m["loop_protocol"] == LOOP_PROTOCOL.describe()
    # every case steps by 2 um on its own axis after STEP_LEAD_S at the origin
    k0 = int(round(bw_mod.STEP_LEAD_S * FS))
    for c in r.steps:
        want = np.zeros(3)
        want[c.axis] = 2.0 * c.sign
        assert np.array_equal(c.trace.ref_um[k0:], np.tile(want, (len(c.trace.ref_um) - k0, 1))), c.name
        assert not c.trace.ref_um[:k0].any()
