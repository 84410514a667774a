"""The batch engine gives every member the single-stage numbers (the contract with the single-stage path).

Bitwise: electronics (every effect on), the twin's and the controller's products (``exact=True``),
MuJoCo members, and the registered experiments' metrics run in lockstep. To 1e-9 relative: the
fast BLAS-3 products (``exact=False``).
"""
import json

import numpy as np
import pytest

from nanosim import experiments
from nanosim.design.controller import ControllerConfig, DiscreteController
from nanosim.experiments import bandwidth as bw_mod
from nanosim.experiments import creep as creep_mod
from nanosim.experiments import resolution as res_mod
from nanosim.experiments.batch_loop import BatchController, run_closed_loop_batch
from nanosim.experiments.batch_suite import MemberPlant, run_experiments_batch
from nanosim.experiments.loop import LoopProtocol, run_closed_loop
from nanosim.experiments.registry import Experiment, ExperimentContext, register, unregister
from nanosim.plant.batch import BatchMujocoStage, BatchTwinStage
from nanosim.plant.floor import floor_model
from nanosim.plant.linearize import linearize
from nanosim.plant.modes import modal_analysis
from nanosim.plant.stage import Stage, StageConfig
from nanosim.plant.tolerances import default_tolerances, sample_model
from nanosim.plant.twin import TwinStage
from integrator_loop import integrator_controller

FIELDS = ("y_um", "table_um", "u_V", "saturated")


@pytest.fixture(scope="module")
def plants():
    """Two fabricated stages (tolerance samples 0 and 1): model, twin, home reading, static gain."""
    tm = default_tolerances()
    out = []
    for i in (0, 1):
        m = sample_model(tm.sample(0, i), tm)
        out.append(dict(model=m, twin=linearize(Stage(config=StageConfig.ideal(), model=m)),
                        home=Stage(model=m).table_um.copy(), G0=modal_analysis(m).static_gain_um_per_V,
                        floor=floor_model(m)))
    return out


def _ref(n=900):
    ref = np.zeros((n, 3))
    ref[100:, 0] = 2.0
    ref[400:, 1] = -1.0
    ref[600:, 2] = 6.0            # Z: large enough to hit the amplifier limit under a fast loop
    return ref


def test_twin_open_loop_bitwise(plants):
    p = plants[0]
    u = 1.5 + np.cumsum(np.random.default_rng(3).standard_normal((3, 700, 3)) * 0.05, axis=1)
    seeds = [0, 4, 9]
    traces = BatchTwinStage([p["twin"]] * 3, seeds, home_um=p["home"], floor_models=p["floor"]).run(u)
    for b, s in enumerate(seeds):
        ref = TwinStage(p["twin"], seed=s, home_um=p["home"], floor_model=p["floor"]).run(u[b])
        for k in ref.__dataclass_fields__:
            assert np.array_equal(getattr(ref, k), getattr(traces[b], k)), (b, k)


@pytest.mark.parametrize("two_dof", [False, True])
def test_twin_closed_loop_bitwise_per_member_plants_and_seeds(plants, two_dof):
    ctrls = [integrator_controller(p["G0"], two_dof) for p in plants]
    seeds = [2, 7]
    stage = BatchTwinStage([p["twin"] for p in plants], seeds, home_um=np.array([p["home"] for p in plants]),
                           floor_models=[p["floor"] for p in plants])
    traces = run_closed_loop_batch(stage, BatchController(ctrls), _ref(), protocol=LoopProtocol(0.06, 0.04))
    for b, (p, s) in enumerate(zip(plants, seeds)):
        ref = run_closed_loop(TwinStage(p["twin"], seed=s, home_um=p["home"], floor_model=p["floor"]),
                              DiscreteController(ctrls[b]), _ref(), protocol=LoopProtocol(0.06, 0.04))
        for k in FIELDS:
            assert np.array_equal(getattr(ref, k), getattr(traces[b], k)), (b, k)


def test_fast_products_within_1e9(plants):
    p = plants[0]
    c = integrator_controller(p["G0"], True, f_hz=1.0)        # a stable loop: round-off is not amplified
    seeds = [1, 2, 3]
    exact = run_closed_loop_batch(BatchTwinStage(p["twin"], seeds, home_um=p["home"], floor_models=p["floor"]),
                                  BatchController(c, n=3), _ref(), protocol=LoopProtocol(0.06, 0.04))
    fast = run_closed_loop_batch(BatchTwinStage(p["twin"], seeds, home_um=p["home"], floor_models=p["floor"],
                                                exact=False),
                                 BatchController(c, n=3, exact=False), _ref(), protocol=LoopProtocol(0.06, 0.04))
    for e, f in zip(exact, fast):
        assert np.allclose(e.table_um, f.table_um, rtol=1e-9, atol=1e-9)
        assert np.allclose(e.u_V, f.u_V, rtol=1e-9, atol=1e-9)


def test_mujoco_closed_loop_bitwise_two_threads(plants):
    ctrls = [integrator_controller(p["G0"], True) for p in plants]
    seeds = [5, 6]
    ref = _ref(300)
    with BatchMujocoStage([p["model"] for p in plants], seeds, nthread=2) as stage:
        traces = run_closed_loop_batch(stage, BatchController(ctrls), ref, protocol=LoopProtocol(0.03, 0.02))
    for b, (p, s) in enumerate(zip(plants, seeds)):
        single = run_closed_loop(Stage(seed=s, model=p["model"]), DiscreteController(ctrls[b]), ref,
                                 protocol=LoopProtocol(0.03, 0.02))
        for k in FIELDS:
            assert np.array_equal(getattr(single, k), getattr(traces[b], k)), (b, k)


def test_controller_bank_pads_orders_and_checks_members(plants):
    c1, c2 = integrator_controller(plants[0]["G0"], True), integrator_controller(plants[1]["G0"], True)
    small = ControllerConfig(c1.Akd[:3, :3], c1.Bkd[:3], c1.Ckd[:, :3], c1.Dkd, c1.dt, n_error=3)
    bank = BatchController([small, c2])
    assert bank.n_states == 6
    y = np.array([[0.1, -0.2, 0.3], [0.0, 0.5, -5.0]])
    bank.reset_at(y)
    single = [DiscreteController(small), DiscreteController(c2)]
    for b, d in enumerate(single):
        d.reset_at(y[b])
    r = np.zeros((2, 3))
    for _ in range(5):
        u = bank.feedback(r, y)
        assert np.allclose(u[0], single[0].feedback(r[0], y[0]), rtol=1e-12, atol=1e-15)   # padded: sum order
        assert np.array_equal(u[1], single[1].feedback(r[1], y[1]))
    with pytest.raises(ValueError, match="n_in, n_out, n_error"):
        BatchController([c1, integrator_controller(plants[0]["G0"], False)])
    with pytest.raises(ValueError, match="controller: expected 3 members"):
        run_closed_loop_batch(BatchTwinStage(plants[0]["twin"], [0, 1, 2]), bank, _ref())


# --- the registered experiments, run in lockstep -----------------------------------------------------
SHORT = {
    "t_creep": lambda ctx: creep_mod.creep(ctx.factory, ctx.controller, ctx.static_gain_um_per_V, seed=ctx.seed,
                                           hold_s=0.6),
    "t_resolution": lambda ctx: res_mod.resolution(ctx.factory, ctx.controller, seed=ctx.seed, duration_s=0.6,
                                                   budget=False),
    "t_budget": lambda ctx: res_mod.noise_budget(ctx.factory(ctx.seed), ctx.controller, seed=ctx.seed + 1,
                                                 duration_s=0.1),          # Stage.variant in a batch
    "t_bandwidth": lambda ctx: bw_mod.bandwidth(ctx.factory, ctx.controller, seed=ctx.seed, duration_s=1.1,
                                                 holds_s=(0.05, 0.1), axes=(0,)),
}


@pytest.fixture()
def short_experiments():
    experiments.load_builtin()
    names = []
    for name, run in SHORT.items():
        metrics = (lambda r: {"noise_budget": r}) if name == "t_budget" else experiments.get(name[2:]).metrics
        register(Experiment(name, run=run, metrics=metrics))
        names.append(name)
    yield names
    for n in names:
        unregister(n)


def test_registered_experiments_in_lockstep_equal_single_runs(plants, short_experiments):
    ctrl = integrator_controller(plants[0]["G0"], True)
    members = [MemberPlant(twin=p["twin"], model=p["model"], home_um=p["home"], static_gain_um_per_V=p["G0"])
               for p in plants]
    metrics, _ = run_experiments_batch(short_experiments, members, ctrl, seed=3, exact=True)
    for b, p in enumerate(plants):
        single = {}
        for name in short_experiments:
            ctx = ExperimentContext(factory=lambda s, p=p: TwinStage(p["twin"], seed=s, home_um=p["home"],
                                                                     floor_model=p["floor"]),
                                    controller=DiscreteController(ctrl), seed=3, static_gain_um_per_V=p["G0"])
            exp = experiments.get(name)
            single.update(exp.metrics(exp.run(ctx)))
        assert "errors" not in metrics[b]
        # the budget's open-loop records of a source without the ADC quantizer carry the open-loop twin's
        # last-bit rounding (its sensor filter run as a whole record against the batch's sample by sample):
        # those to 1e-12 relative, everything else bit for bit
        got = json.loads(json.dumps(metrics[b]))
        want = json.loads(json.dumps(single))
        for name, row in want["noise_budget"].items():
            for key in ("open_loop_nm", "open_loop_share"):
                assert got["noise_budget"][name].pop(key) == pytest.approx(row.pop(key), rel=1e-12, abs=1e-300)
        assert json.dumps(want, sort_keys=True) == json.dumps(got, sort_keys=True)


def test_data_dependent_control_flow_falls_back_to_single_members(plants):
    def run(ctx):          # the record length depends on the member's plant: the members' requests differ
        st = ctx.factory(ctx.seed)
        n = 40 if ctx.static_gain_um_per_V[0, 0] > 0 else 20
        return st.run(np.full((n, 3), 0.5)).sensor_um[-1]

    register(Experiment("t_divergent", run=run, metrics=lambda r: {"last_um": r.tolist()}))
    try:
        G = [p["G0"] for p in plants]
        members = [MemberPlant(twin=plants[0]["twin"], home_um=plants[0]["home"], static_gain_um_per_V=g * s)
                   for g, s in zip(G, (1.0, -1.0))]
        metrics, _ = run_experiments_batch(["t_divergent"], members, integrator_controller(G[0], False), seed=1)
        for b, m in enumerate(members):
            n = 40 if m.static_gain_um_per_V[0, 0] > 0 else 20
            single = TwinStage(plants[0]["twin"], seed=1, home_um=plants[0]["home"]).run(np.full((n, 3), 0.5))
            assert metrics[b]["last_um"] == single.sensor_um[-1].tolist()
    finally:
        unregister("t_divergent")


def test_twin_matrices_of_a_twin_and_its_input_scaled_copy(plants):
    # TwinMatrices.of reads the twin's discrete sysd_V; input_scaled(f) scales its static gain C (I - A)^-1 B + D
    # by exactly f (B and D scaled, A and C shared), and leaves the free response alone
    from nanosim.plant.batch import TwinMatrices

    tw = plants[0]["twin"]
    m = TwinMatrices.of(tw)
    np.testing.assert_array_equal(m.A, np.asarray(tw.sysd_V.A))
    assert all(np.array_equal(a, b) for a, b in zip(TwinMatrices.of(m), m))

    def dc(t):
        return t.C @ np.linalg.solve(np.eye(t.A.shape[0]) - t.A, t.B) + t.D

    f = 1.0 + 3e-6
    s = m.input_scaled(f)
    assert s.A is m.A and s.C is m.C
    np.testing.assert_allclose(dc(s), f * dc(m), rtol=1e-12, atol=1e-12 * np.abs(dc(m)).max())
    with pytest.raises(ValueError, match="twins: expected a LinearTwin or TwinMatrices, got list"):
        TwinMatrices.of([1, 2])
