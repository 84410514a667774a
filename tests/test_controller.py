"""Tests for nanosim.controller.DiscreteController (the 4 kHz real-time controller)."""
from __future__ import annotations

import time

import numpy as np
import pytest

from nanosim import fileio
from nanosim.design.controller import ControllerConfig, DiscreteController

DT = 1 / 4000


def random_controller(n=5, nin=3, nout=3, seed=0):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    A *= 0.9 / np.max(np.abs(np.linalg.eigvals(A)))          # spectral radius 0.9
    return A, rng.normal(size=(n, nin)), rng.normal(size=(nout, n)), rng.normal(size=(nout, nin))


def reference_response(A, B, C, D, E):
    """Plain textbook recursion x[k+1] = A x + B e, u = C x + D e."""
    x = np.zeros(A.shape[0])
    U = []
    for e in E:
        U.append(C @ x + D @ e)
        x = A @ x + B @ e
    return np.array(U), x


@pytest.fixture()
def npz_path(tmp_path):
    A, B, C, D = random_controller()
    return fileio.write_npz(tmp_path / "controller.npz", Akd=A, Bkd=B, Ckd=C, Dkd=D, dt=DT,
                         Ak=np.zeros((5, 5)), units=np.array(["sensor V in", "controller V out"])), (A, B, C, D)


def test_step_and_run_match_recursion(npz_path):
    path, (A, B, C, D) = npz_path
    ctrl = DiscreteController.from_npz(path)
    assert ctrl.config.dt == DT and ctrl.config.n_states == 5
    E = np.random.default_rng(1).normal(size=(200, 3))
    U_ref, x_end = reference_response(A, B, C, D, E)
    U_step = np.array([ctrl.step(e) for e in E])
    np.testing.assert_allclose(U_step, U_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ctrl.state, x_end, rtol=1e-12, atol=1e-12)
    U_run = ctrl.run(E)                                        # resets first by default
    np.testing.assert_allclose(U_run, U_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ctrl.state, x_end, rtol=1e-12, atol=1e-12)


def test_matches_python_control_simulation(npz_path):
    ct = pytest.importorskip("control")
    path, (A, B, C, D) = npz_path
    E = np.random.default_rng(2).normal(size=(300, 3))
    sys_d = ct.ss(A, B, C, D, DT)
    resp = ct.forced_response(sys_d, U=E.T)
    U = DiscreteController.from_npz(path).run(E)
    np.testing.assert_allclose(U, resp.outputs.T, rtol=1e-9, atol=1e-9)


def test_reset_and_continue(npz_path):
    path, _ = npz_path
    ctrl = DiscreteController.from_npz(path)
    E = np.ones((50, 3))
    first = ctrl.run(E)
    assert np.any(ctrl.state != 0)
    cont = ctrl.run(E, reset=False)                            # continues from the state
    assert not np.allclose(cont, first)
    ctrl.reset()
    np.testing.assert_array_equal(ctrl.state, 0.0)
    np.testing.assert_allclose(np.array([ctrl.step(e) for e in E]), first)
    with pytest.raises(ValueError, match="x0"):
        ctrl.reset(np.zeros(4))


def test_config_is_immutable(npz_path):
    path, _ = npz_path
    cfg = DiscreteController.from_npz(path).config
    with pytest.raises(Exception):
        cfg.dt = 1.0
    with pytest.raises(ValueError):
        cfg.Akd[0, 0] = 1.0                                    # read-only array
    assert isinstance(cfg, ControllerConfig)


def test_missing_file_and_keys(tmp_path):
    with pytest.raises(FileNotFoundError):
        DiscreteController.from_npz(tmp_path / "none.npz")
    A, B, C, D = random_controller()
    fileio.write_npz(tmp_path / "nokey.npz", Akd=A, Bkd=B, Ckd=C, dt=DT)
    with pytest.raises(ValueError, match="Dkd"):
        DiscreteController.from_npz(tmp_path / "nokey.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not an .npz file"):
        DiscreteController.from_npz(tmp_path / "junk.npz")


@pytest.mark.parametrize("mutate, match", [
    (lambda m: m.update(Bkd=m["Bkd"][:4]), "Bkd"),
    (lambda m: m.update(Akd=m["Akd"][:, :4]), "Akd"),
    (lambda m: m.update(Dkd=np.zeros((3, 2))), "Dkd"),
    (lambda m: m.update(Ckd=m["Ckd"] * np.nan), "NaN"),
    (lambda m: m.update(dt=-1.0), "dt"),
])
def test_bad_shapes(tmp_path, mutate, match):
    A, B, C, D = random_controller()
    m = dict(Akd=A, Bkd=B, Ckd=C, Dkd=D, dt=DT)
    mutate(m)
    fileio.write_npz(tmp_path / "bad.npz", **m)
    with pytest.raises(ValueError, match=match):
        DiscreteController.from_npz(tmp_path / "bad.npz")


def test_step_input_validation(npz_path):
    ctrl = DiscreteController.from_npz(npz_path[0])
    with pytest.raises(ValueError, match="shape"):
        ctrl.step(np.zeros(2))
    with pytest.raises(ValueError, match="NaN"):
        ctrl.step([0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="shape"):
        ctrl.run(np.zeros((10, 2)))


@pytest.mark.filterwarnings("ignore:overflow encountered in dot:RuntimeWarning")   # numpy's, beside the error
def test_overflowing_step_raises_and_keeps_the_state():
    """An input so large that the command overflows (3.37e5 x 6e302; 2 x 1e308) is an error, and the
    state stays as it was."""
    big = DiscreteController.from_matrices(np.zeros((1, 1)), np.zeros((1, 3)), np.zeros((1, 1)),
                                           np.full((1, 3), 3.37e5), DT)
    with pytest.raises(ValueError, match="error_V: the controller's next state or command overflows"):
        big.step([0.0, 0.0, 6e302])
    A, B, C, _ = random_controller(n=4)
    D = 2.0 * np.eye(3)
    ctrl, fresh = (DiscreteController.from_matrices(A, B, C, D, DT) for _ in range(2))
    e = np.array([1e-3, -2e-3, 5e-4])
    assert np.array_equal(ctrl.step(e), fresh.step(e))
    with pytest.raises(ValueError, match="overflows"):
        ctrl.step([1e308, 0.0, 0.0])
    assert np.array_equal(ctrl.step(e), fresh.step(e))          # the failed step left no trace


@pytest.mark.parametrize("n_error", [np.inf, -np.inf, np.nan, 1.5, "two"])
def test_n_error_must_be_an_integer(n_error):
    with pytest.raises(ValueError, match="n_error: expected"):
        ControllerConfig(np.zeros((1, 1)), np.zeros((1, 3)), np.zeros((3, 1)), np.zeros((3, 3)), DT, n_error)


def test_step_is_fast(npz_path):
    A, B, C, D = random_controller(n=19)
    ctrl = DiscreteController.from_matrices(A, B, C, D, DT)
    e = np.array([1e-3, -2e-3, 5e-4])
    for _ in range(200):
        ctrl.step(e)
    t0 = time.perf_counter()
    n = 4000
    for _ in range(n):
        ctrl.step(e)
    per_step = (time.perf_counter() - t0) / n
    print(f"DiscreteController.step: {per_step * 1e6:.1f} us per step (19 states, 3x3)")
    assert per_step < 250e-6          # 1/4 of the 4 kHz period even on a loaded machine


def test_closed_loop_tracking_with_designed_controller():
    """Controller designed with nanosim.design, run in a sampled loop with a ZOH plant:
    a step reference is tracked (confirms u = +K e with e = r - y in the time domain)."""
    ct = pytest.importorskip("control")
    pytest.importorskip("slycot")
    import nanosim.design as design
    from nanosim.design.weights import Weights, WeightSpec
    s = ct.tf("s")
    g = ct.ss(200 / ((10 * s + 1) * (0.05 * s + 1) ** 2))       # Skogestad & Postlethwaite Ex. 2.11
    G = ct.append(g, g, g)
    W = Weights(Wp=WeightSpec((1 / 1.5, 10.0), (1.0, 1e-3)), Wt=None, Wu=1.0)
    d = design.design_hinf(G, W)
    disc = design.discretize_controller(d.K, DT)
    ctrl = DiscreteController.from_matrices(disc.Kd.A, disc.Kd.B, disc.Kd.C, disc.Kd.D, DT)
    Gd = ct.c2d(G, DT, "zoh")
    x = np.zeros(Gd.nstates)
    r = np.array([0.4, 0.0, -0.2])                              # sensor V (2 um, 0, -1 um)
    ys = []
    for _ in range(int(2.0 / DT)):
        y = Gd.C @ x
        u = ctrl.step(r - y)
        x = Gd.A @ x + Gd.B @ u
        ys.append(y)
    ys = np.array(ys)
    np.testing.assert_allclose(ys[-1], r, atol=2e-3)
    assert np.all(np.abs(ys) < 1.0)                             # no runaway (wrong sign would diverge)


# --- starting a loop at a reading: reset_at is bumpless ---------------------------------------------
def _leaky_two_dof(lam=0.99998, b=0.5, c=40.0):
    """[e; y] controller whose leaky integrator also integrates the measurement (as an LQG observer's
    integrator does): x1+ = lam x1 + e + b y, x2+ = 0.9 x2 + 0.1 y, u = c (1 - lam) x1 + x2 + 0.1 e.
    Its plain equilibrium at a constant reading y holds the output u_eq = (c b + 1) y per axis."""
    A = np.diag([lam, 0.9])
    B = np.array([[1.0, b], [0.0, 0.1]])
    C = np.array([[c * (1 - lam), 1.0]])
    D = np.array([[0.1, 0.0]])
    return ControllerConfig(A, B, C, D, DT, n_error=1), c * b + 1.0


def test_reset_at_starts_with_the_command_held_and_no_kick():
    cfg, per_volt = _leaky_two_dof()
    y = np.array([-5.0])                                     # the home reading in Z: -25 um
    plain = DiscreteController(cfg)
    plain.reset(measurement_V=y)                             # the equilibrium: a kick of per_volt * y
    np.testing.assert_allclose(plain.step(np.zeros(1), y), per_volt * y, rtol=1e-9)
    ctrl = DiscreteController(cfg)
    ctrl.reset_at(y)                                         # bumpless: the stage's command at home, 0 V
    u = np.array([ctrl.step(np.zeros(1), y)[0] for _ in range(40)])
    assert abs(u[0]) < 1e-12
    # afterwards only the slow mode moves it: at most (1 - lam^k) of the equilibrium output
    k = np.arange(40)
    assert np.all(np.abs(u) <= (1 - 0.99998 ** k) * abs(per_volt * y[0]) * (1 + 1e-9) + 1e-12)
    ctrl.reset_at(y, command_V=[1.25])                       # a command the actuators already hold
    np.testing.assert_allclose(ctrl.step(np.zeros(1), y), [1.25], atol=1e-12)
    with pytest.raises(ValueError, match="command_V: expected 1"):
        ctrl.reset_at(y, command_V=[1.0, 2.0])
    with pytest.raises(ValueError, match="measurement_V"):
        ctrl.reset_at([np.nan])


def test_reset_at_of_a_one_dof_controller_is_the_zero_state(npz_path):
    ctrl = DiscreteController.from_npz(npz_path[0])
    ctrl.reset(np.ones(ctrl.config.n_states))
    ctrl.reset_at(np.array([0.3, -0.2, -5.0]))
    assert not ctrl.state.any()
