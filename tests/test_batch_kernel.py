"""The compiled batch loop (numba) gives the numbers of the numpy batch path and of the single stage.

The compiled loop makes the numpy path's element-wise operations in the same order (numpy's pairwise
sum for the hysteresis, the creep sum left to right) and the same BLAS products (``gemm`` for shared
matrices with ``exact=False``, one ``gemv`` per member otherwise), so the records are equal bit for bit;
B = 1 equals :class:`~nanosim.plant.twin.TwinStage` with :class:`DiscreteController` bit for bit.
"""
import numpy as np
import pytest

from nanosim.design.controller import DiscreteController
from nanosim.experiments.batch_loop import BatchController, run_closed_loop_batch
from nanosim.experiments.loop import LoopProtocol, run_closed_loop
from nanosim.plant import batch_kernel
from nanosim.plant.batch import BatchTwinStage, member_products
from nanosim.plant.filters import FlickerShaper
from nanosim.plant.floor import floor_model
from nanosim.plant.linearize import linearize
from nanosim.plant.modes import modal_analysis
from nanosim.plant.stage import Stage, StageConfig
from nanosim.plant.tolerances import default_tolerances, sample_model
from nanosim.plant.twin import TwinStage
from integrator_loop import integrator_controller

SHORT = LoopProtocol(0.03, 0.02)        # a short approach and hold: the loops' start, not their settling

pytestmark = pytest.mark.skipif(not batch_kernel.AVAILABLE, reason="numba is not installed")

FIELDS = ("y_um", "table_um", "u_V", "saturated")


@pytest.fixture(scope="module")
def plants():
    tm = default_tolerances()
    out = []
    for i in (0, 1):
        m = sample_model(tm.sample(3, i), tm)
        out.append(dict(twin=linearize(Stage(config=StageConfig.ideal(), model=m)), home=Stage(model=m).table_um,
                        G0=modal_analysis(m).static_gain_um_per_V, floor=floor_model(m)))
    return out


def _ref(n=700):
    ref = np.zeros((n, 3))
    ref[80:, 0] = 2.0
    ref[300:, 1] = -1.0
    ref[500:, 2] = 20.0                # Z: into the amplifier limit under the 20 Hz loop
    return ref


def test_pairwise_sum_is_numpys():
    rng = np.random.default_rng(0)
    for n in range(0, 129):
        v = rng.standard_normal(n) * np.exp(4 * rng.standard_normal(n))
        assert batch_kernel.pairwise_sum(v) == np.add.reduce(v[None, :], axis=-1)[0], n


def test_flicker_cascade_is_flicker_shaper():
    e = np.random.default_rng(1).standard_normal((3000, 6))
    ref = FlickerShaper(2e-5, 0.01, 4000.0, 6)
    sec = ref._sec
    z = np.zeros((len(sec), 6))
    got = np.vstack([batch_kernel.flicker_cascade(part, ref._gain, np.array([b for b, _ in sec]),
                                                  np.array([a for _, a in sec]), z) for part in (e[:1700], e[1700:])])
    assert np.array_equal(got, ref.run(e))


def test_member_products_are_the_numpy_paths():
    # every remainder of the kernel's four-term passes (k = 1 ... 9), on values whose sums round differently
    # when regrouped: equal bits, and within one rounding per term of the exact sums
    rng = np.random.default_rng(2)
    for k in range(1, 10):
        PS = rng.standard_normal((5, k, 37)) * np.exp(6 * rng.standard_normal((5, k, 37)))
        xv = rng.standard_normal((37, k))
        out = np.empty((5, 37))
        batch_kernel.member_products(PS, np.ascontiguousarray(xv.T), out)
        assert np.array_equal(out.T, member_products(PS, xv)), k
        exact = np.einsum("ikb,bk->bi", PS.astype(np.longdouble), xv.astype(np.longdouble))
        bound = 2 * k * np.finfo(float).eps * np.einsum("ikb,bk->bi", np.abs(PS), np.abs(xv))
        assert np.all(np.abs(out.T - exact) <= bound), k


@pytest.mark.parametrize("exact", [True, False])
@pytest.mark.parametrize("two_dof", [False, True])
def test_compiled_closed_loop_equals_numpy_path(plants, exact, two_dof):
    """Per-member twins with floor vibration, per-member controllers (20 Hz: rings and saturates)."""
    ctrls = [integrator_controller(p["G0"], two_dof, 20.0) for p in plants]

    def run(compiled):
        st = BatchTwinStage([p["twin"] for p in plants], [4, 11], home_um=np.array([p["home"] for p in plants]),
                            floor_models=[p["floor"] for p in plants], exact=exact, compiled=compiled)
        tr = run_closed_loop_batch(st, BatchController(ctrls, exact=exact), _ref(), protocol=SHORT)
        return tr, st

    (fast, st_f), (slow, st_s) = run(True), run(False)
    assert batch_kernel.supported(st_f) and not batch_kernel.supported(st_s)
    for a, b in zip(fast, slow):
        for k in FIELDS:
            assert np.array_equal(getattr(a, k), getattr(b, k)), k
    # the states left behind are the same too: a second run continues identically
    assert np.array_equal(st_f.table_um, st_s.table_um) and st_f.time_s == st_s.time_s
    assert np.array_equal(st_f.electronics.hysteresis_state, st_s.electronics.hysteresis_state)


def test_compiled_shared_twin_and_controller_fast_products(plants):
    """The benchmark's configuration: one twin and one controller for all members, ``exact=False`` (gemm)."""
    p = plants[0]
    c = integrator_controller(p["G0"], True, 5.0)

    def run(compiled):
        st = BatchTwinStage(p["twin"], [1, 2, 3], home_um=p["home"], exact=False, compiled=compiled)
        return run_closed_loop_batch(st, BatchController(c, n=3, exact=False), _ref(), protocol=SHORT)

    for a, b in zip(run(True), run(False)):
        for k in FIELDS:
            assert np.array_equal(getattr(a, k), getattr(b, k)), k


@pytest.mark.parametrize("two_dof", [False, True])
def test_compiled_batch_of_one_equals_single_stage(plants, two_dof):
    p = plants[1]
    c = integrator_controller(p["G0"], two_dof, 30.0)
    st = BatchTwinStage([p["twin"]], [9], home_um=p["home"], floor_models=[p["floor"]])
    (got,) = run_closed_loop_batch(st, BatchController([c]), _ref(), protocol=SHORT)
    assert batch_kernel.supported(st)
    ref = run_closed_loop(TwinStage(p["twin"], seed=9, home_um=p["home"], floor_model=p["floor"]),
                          DiscreteController(c), _ref(), protocol=SHORT)
    for k in FIELDS:
        assert np.array_equal(getattr(got, k), getattr(ref, k)), k
    assert got.saturated.any()          # the comparison covers saturation


def test_compiled_loop_across_noise_chunks_equals_numpy_path_and_single_stage(plants):
    # 1234 open-loop periods first, so the 4096-row noise chunks end inside the closed loop's calls
    p = plants[0]
    c = integrator_controller(p["G0"], True, 20.0)
    ref = np.tile(_ref(), (13, 1))[:9000]
    got = {}
    for compiled in (True, False):
        st = BatchTwinStage([p["twin"]] * 2, [4, 5], home_um=p["home"], floor_models=[p["floor"]] * 2)
        st.run(np.full((2, 1234, 3), 0.3))
        got[compiled] = run_closed_loop_batch(st, BatchController([c, c]), ref, protocol=SHORT, compiled=compiled)
    single = TwinStage(p["twin"], seed=5, home_um=p["home"], floor_model=p["floor"])
    single.run(np.full((1234, 3), 0.3))
    one = run_closed_loop(single, DiscreteController(c), ref, protocol=SHORT)
    for k in FIELDS:
        for b in range(2):
            assert np.array_equal(getattr(got[True][b], k), getattr(got[False][b], k)), (b, k)
        assert np.array_equal(getattr(got[True][1], k), getattr(one, k)), k


@pytest.mark.parametrize("config", [StageConfig(), StageConfig.v1()], ids=["v2", "v1"])
def test_compiled_open_loop_equals_single_stage(plants, config):
    p = plants[0]
    u = 1.5 + np.cumsum(np.random.default_rng(5).standard_normal((2, 900, 3)) * 0.05, axis=1)
    traces = BatchTwinStage([p["twin"]] * 2, [0, 6], config=config, home_um=p["home"],
                            floor_models=p["floor"]).run(u)
    for b, s in enumerate([0, 6]):
        ref = TwinStage(p["twin"], seed=s, config=config, home_um=p["home"], floor_model=p["floor"]).run(u[b])
        for k in ref.__dataclass_fields__:
            assert np.array_equal(getattr(ref, k), getattr(traces[b], k)), (b, k)


@pytest.mark.parametrize("config", [StageConfig(), StageConfig.v1()], ids=["v2", "v1"])
def test_compiled_steps_equal_numpy_electronics(config):
    """BatchElectronics.actuate/read one period per compiled call (the MuJoCo batch), mixed with numpy calls."""
    from nanosim.plant.batch_electronics import BatchElectronics

    seeds = [3, 8]
    a = BatchElectronics(config.electronics, config.piezo, seeds)
    b = BatchElectronics(config.electronics, config.piezo, seeds)
    b.use_compiled_steps()
    rng = np.random.default_rng(2)
    u = 2.0 + np.cumsum(rng.standard_normal((1500, 2, 3)) * 0.2, axis=0)     # into both command limits
    d = 40.0 * np.sin(np.linspace(0, 30, 1500))[:, None, None] + rng.standard_normal((1500, 2, 3))
    for k in range(1500):
        if k == 700:                   # a stretch of numpy calls on the compiled object: same state, same streams
            b._steps, steps = None, b._steps
        if k == 800:
            b._steps = steps
        ra, rb = a.actuate(u[k]), b.actuate(u[k])
        for x, y in zip(ra[1:], rb[1:]):
            assert np.array_equal(x, y), k
        sa, sb = a.read(d[k]), b.read(d[k])
        for f in ("reading_V", "reading_um", "clipped"):
            assert np.array_equal(getattr(sa, f), getattr(sb, f)), (k, f)
    assert np.array_equal(a.hysteresis_state, b.hysteresis_state)


def test_mujoco_batch_open_loop_equals_stage_run(plants):
    """BatchMujocoStage.run rolls each member out as Stage.run does: the same numbers."""
    from nanosim.plant.batch import BatchMujocoStage

    tm = default_tolerances()
    models = [sample_model(tm.sample(3, i), tm) for i in (0, 1)]
    u = 1.0 + np.cumsum(np.random.default_rng(7).standard_normal((2, 1300, 3)) * 0.05, axis=1)   # two chunks
    with BatchMujocoStage(models, [2, 5], nthread=2) as st:
        st.step(np.full((2, 3), 0.3))                       # not from home: the run continues a history
        traces = st.run(u)
        after = st.step(np.full((2, 3), 0.4))
    for b, s in enumerate([2, 5]):
        single = Stage(seed=s, model=models[b])
        single.step(np.full(3, 0.3))
        ref = single.run(u[b])
        for k in ("piezo_V", "saturated", "table_um", "sensor_V", "sensor_um", "clipped"):
            assert np.array_equal(getattr(ref, k), getattr(traces[b], k)), (b, k)
        assert np.array_equal(single.step(np.full(3, 0.4)), after[b])
