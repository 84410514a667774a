"""Joint re-estimation of shared resonances (identification.shared_poles)."""
import numpy as np
import pytest

import identification as ident
from identification.shared_poles import refine_shared_poles, shared_pole_groups

DT = 250e-6
# three structural modes seen by every column (Hz, zeta), one creep pole (rad/s)
MODES = ((175.5, 0.0029), (462.7, 0.0039), (472.0, 0.0040))
CREEP_RAD_S = -2.0
CREEP_GAIN = np.array([[0.05, 0.02, 0.0], [0.02, 0.05, 0.0], [0.0, 0.0, 0.04]])
# residue per (column, mode, output): column 2 barely excites the 462/472 Hz pair, as actuator C
RESIDUE = np.array([[[1.0, 0.4, 0.0], [0.05, 0.01, 0.0], [0.01, 0.04, 0.0]],
                    [[0.4, 1.0, 0.0], [0.01, 0.05, 0.0], [0.04, 0.01, 0.0]],
                    [[0.02, 0.02, 0.3], [0.002, 0.001, 0.0], [0.001, 0.002, 0.0]]])


def _column(j, modes=MODES):
    """A 3x1 discrete (ZOH) model of column j: per mode ``RESIDUE[j, i] w^2 / (s^2 + 2 z w s + w^2)``, plus creep."""
    import scipy.signal as sig
    n = 2 * len(modes) + 1
    A, B, C = np.zeros((n, n)), np.zeros((n, 1)), np.zeros((3, n))
    for i, ((f, z), r) in enumerate(zip(modes, RESIDUE[j])):
        w = 2 * np.pi * f
        A[2 * i:2 * i + 2, 2 * i:2 * i + 2] = [[0, 1], [-w * w, -2 * z * w]]
        B[2 * i + 1, 0] = w * w
        C[:, 2 * i] = r
    A[-1, -1], B[-1, 0], C[:, -1] = CREEP_RAD_S, -CREEP_RAD_S, CREEP_GAIN[j]
    Ad, Bd, Cd, Dd, _ = sig.cont2discrete((A, B, C, np.zeros((3, 1))), DT, "zoh")
    return ident.IdentifiedModel(A=Ad, B=Bd, C=Cd, D=Dd, K=np.zeros((n, 3)), dt_s=DT, order=n,
                                 singular_values=np.ones(1), x0=np.zeros(n), noise_cov=np.eye(3), horizon=20)


def _records(noise, seed):
    rng = np.random.default_rng(seed)
    out = []
    for j in range(3):
        col = _column(j)
        u = rng.choice([-0.5, 0.5], 6000)
        y = ident.simulate(col, u[:, None])
        out.append((u, y + noise * rng.standard_normal(y.shape)))
    return out


def _perturbed(j, df, dz):
    modes = tuple((f * (1 + df), z * dz) for f, z in MODES) if j == 2 else MODES
    return _column(j, modes)


def test_groups_one_pole_per_column_and_mode():
    cols = [_perturbed(j, 0.006, 3.0) for j in range(3)]
    groups = shared_pole_groups(cols)
    assert len(groups) == 3                                  # 462.7 and 472.0 (2 % apart) stay distinct
    assert all(sorted(g) == [0, 1, 2] for g in groups)


def test_noise_free_records_recover_the_true_poles():
    """Column 2's estimate of every mode is 0.6 % high and 3x too damped; the joint fit finds the truth."""
    recs = _records(0.0, 0)
    res = refine_shared_poles([_perturbed(j, 0.006, 3.0) for j in range(3)], recs)
    f_true = np.array([f for f, _ in MODES])
    z_true = np.array([z for _, z in MODES])
    np.testing.assert_allclose(res.freq_hz, f_true, rtol=1e-6)
    np.testing.assert_allclose(res.damping, z_true, rtol=1e-4)
    assert res.cost_after < 1e-3 * res.cost_before
    for col, (u, y) in zip(res.columns, recs):           # each column reproduces its record
        sim = ident.simulate(col, u[:, None], col.x0)
        assert np.max(np.abs(sim - y)) < 1e-6 * np.max(np.abs(y))
        np.testing.assert_allclose(ident.modes_from_model(col.A, DT).freq_hz, f_true, rtol=1e-6)


@pytest.mark.parametrize("seed", range(5))
def test_noisy_records_weak_column_takes_the_strong_columns_poles(seed):
    """With noise, the refined poles are as close to the truth as the best column's own estimate."""
    recs = _records(2e-3, seed)
    cols = [ident.subspace_id(y, u[:, None], order=7, fs=1 / DT, enforce_stability=True) for u, y in recs]
    res = refine_shared_poles(cols, recs)
    f_true = np.array([f for f, _ in MODES])
    assert res.freq_hz.shape == (3,)
    err_after = np.abs(res.freq_hz / f_true - 1)
    err_before = np.nanmax(np.abs(res.freq_hz_before / f_true[:, None] - 1), axis=1)
    assert np.all(err_after < 2e-4)
    assert np.all(err_after <= err_before + 1e-5)
    np.testing.assert_allclose(res.damping, [z for _, z in MODES], rtol=0.1)
    assert res.cost_after <= res.cost_before * (1 + 1e-9)


def test_bad_input_names_the_argument():
    cols = [_column(j) for j in range(3)]
    with pytest.raises(ValueError, match="data: expected one"):
        refine_shared_poles(cols, _records(0.0, 0)[:2])
    with pytest.raises(ValueError, match="columns: expected at least one"):
        refine_shared_poles([], [])
    u, y = _records(0.0, 0)[0]
    with pytest.raises(ValueError, match=r"data\[0\] u: expected one input channel, got 2"):
        refine_shared_poles(cols[:1], [(np.column_stack([u, u]), y)])
