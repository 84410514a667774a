"""``nanosim identify --data``: a user's record of a known linear system, its readers and their errors.

The system: three lightly damped modes (120, 310 and 655 Hz; damping 0.8, 1.2 and 2 %) of a 3x3
plant with full modal participation matrices, sampled at 4 kHz (ZOH), driven by three
uncorrelated PRBS inputs, 0.1 % rms output noise. Its modes are known exactly (the continuous
poles), so the identified ones are checked against them: frequency within 1 %, damping within 10 %.
"""
from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
import scipy.io
from scipy import signal

import identification as ident
from nanosim.cli import main

FS = 4000.0
F_HZ = np.array([120.0, 310.0, 655.0])
ZETA = np.array([0.008, 0.012, 0.02])


def _system():
    w = 2 * np.pi * F_HZ
    Bm = np.array([[1.0, 0.4, -0.3], [0.5, -1.0, 0.6], [-0.4, 0.7, 1.0]])      # modal input participation
    Cm = np.array([[1.0, 0.3, 0.5], [-0.2, 1.0, 0.4], [0.6, -0.5, 1.0]])       # modal output participation
    A = np.zeros((6, 6))
    B = np.zeros((6, 3))
    C = np.zeros((3, 6))
    for k in range(3):
        A[2 * k:2 * k + 2, 2 * k:2 * k + 2] = [[0, 1], [-w[k] ** 2, -2 * ZETA[k] * w[k]]]
        B[2 * k + 1] = w[k] ** 2 * Bm[k]
        C[:, 2 * k] = Cm[:, k]
    return signal.StateSpace(A, B, C, np.zeros((3, 3)))


def _record(seconds=6.0, seed=3):
    n = int(seconds * FS)
    u = ident.prbs_channels(n, 1000.0, fs=FS, n_channels=3, amplitude=1.0, seed=seed)
    sysd = _system().to_discrete(1 / FS, method="zoh")
    _, y, _ = signal.dlsim((sysd.A, sysd.B, sysd.C, sysd.D, 1 / FS), u)
    rng = np.random.default_rng(seed)
    y = y + 1e-3 * y.std(axis=0) * rng.standard_normal(y.shape)
    return u, y


@pytest.fixture(scope="module")
def record():
    return _record()


def _check_modes(doc):
    modes = [m for m in doc["modes_hz"] if m["damping_ratio"] < 0.1]
    f = np.array([m["freq_hz"] for m in modes])
    z = np.array([m["damping_ratio"] for m in modes])
    for f0, z0 in zip(F_HZ, ZETA):
        k = int(np.argmin(np.abs(f - f0)))
        assert abs(f[k] - f0) <= 0.01 * f0, (f0, f[k])
        assert abs(z[k] - z0) <= 0.10 * z0, (z0, z[k])


@pytest.mark.parametrize("kind", ["mat", "csv", "mat73"])
def test_identify_data_recovers_the_known_modes(tmp_path, record, kind):
    u, y = record
    if kind == "mat":
        path = tmp_path / "rec.mat"
        scipy.io.savemat(path, {"u": u, "y": y, "Ts": 1 / FS})
    elif kind == "mat73":
        path = tmp_path / "rec73.mat"
        with h5py.File(path, "w") as f:            # MATLAB v7.3 layout: column-major, so stored transposed
            f.create_dataset("u", data=u.T)
            f.create_dataset("y", data=y.T)
            f.create_dataset("Ts", data=np.array([[1 / FS]]))
    else:
        path = tmp_path / "rec.csv"
        t = np.arange(len(u)) / FS
        np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", fmt="%.9g",
                   header="t,u1,u2,u3,y1,y2,y3", comments="")
    out = tmp_path / "run"
    assert main(["identify", "--data", str(path), "--out", str(out)]) == 0
    doc = json.loads((out / "identify.json").read_text())
    _check_modes(doc)
    assert min(doc["fit_percent"]) > 95.0
    m = scipy.io.loadmat(out / "model.mat")
    assert float(m["Ts"].ravel()[0]) == pytest.approx(1 / FS, rel=1e-12)
    for name in ("fig04_time_domain_fit.png", "fig05_identified_frequency_response.png", "singular_values.png"):
        assert (out / name).is_file()
    # model.mat's discrete model is model.npz's
    z = np.load(out / "model.npz")
    np.testing.assert_allclose(m["A"], z["Ad"], rtol=0, atol=0)


def _malformed(tmp_path, record):
    u, y = record
    u, y = u[:2000], y[:2000]
    t = np.arange(len(u)) / FS
    files = {}

    def mat(name, **v):
        p = tmp_path / name
        scipy.io.savemat(p, v)
        files[name] = p

    mat("no_u.mat", y=y, Ts=1 / FS)
    mat("no_ts.mat", u=u, y=y)
    mat("transposed.mat", u=u.T, y=y, Ts=1 / FS)
    mat("unequal.mat", u=u, y=y[:-5], Ts=1 / FS)
    bad = y.copy()
    bad[17, 1] = np.nan
    mat("nan.mat", u=u, y=bad, Ts=1 / FS)
    mat("negative_ts.mat", u=u, y=y, Ts=-1.0)
    mat("three_d.mat", u=u.reshape(1000, 2, 3), y=y, Ts=1 / FS)
    p = tmp_path / "nonuniform.csv"
    t2 = t.copy()
    t2[500:] += 0.3 / FS
    np.savetxt(p, np.column_stack([t2, u, y]), delimiter=",", header="t,u1,u2,u3,y1,y2,y3", comments="")
    files[p.name] = p
    p = tmp_path / "no_y.csv"
    np.savetxt(p, np.column_stack([t, u]), delimiter=",", header="t,u1,u2,u3", comments="")
    files[p.name] = p
    p = tmp_path / "garbage.mat"
    p.write_bytes(b"this is not a MATLAB file at all" * 10)
    files[p.name] = p
    p = tmp_path / "constant.npz"
    np.savez(p, u=np.ones_like(u), y=y, Ts=1 / FS)
    files[p.name] = p
    return files


def test_malformed_records_give_one_line_and_exit_2(tmp_path, record, capsys):
    files = _malformed(tmp_path, record)
    assert len(files) >= 10
    expect = {"no_u.mat": "no inputs", "no_ts.mat": "no sample time", "transposed.mat": "transposed",
              "unequal.mat": "same number of samples", "nan.mat": "NaN", "negative_ts.mat": "> 0 s",
              "three_d.mat": "2-D", "nonuniform.csv": "uniformly sampled", "no_y.csv": "missing y1",
              "garbage.mat": "not a readable .mat", "constant.npz": "constant"}
    for name, path in files.items():
        rc = main(["identify", "--data", str(path), "--out", str(tmp_path / f"out_{name}")])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2, name
        assert len(err) == 1 and err[0].startswith("nanosim identify: error: --data: "), (name, err)
        assert expect[name] in err[0], (name, err[0])
        assert not (tmp_path / f"out_{name}").exists(), name


def test_design_accepts_a_mat_state_space(tmp_path):
    """A MATLAB ``ss(A, B, C, D, Ts)`` of the stage's identified model designs as its model.npz does."""
    from pathlib import Path
    src = np.load(Path(__file__).parent / "data" / "identified_seed0.npz")
    mat = tmp_path / "G.mat"
    scipy.io.savemat(mat, {"A": src["Ad"], "B": src["Bd"], "C": src["Cd"], "D": src["Dd"], "Ts": float(src["dt"])})
    from nanosim.pipeline.identify import model_npz_from_mat
    z = np.load(model_npz_from_mat(mat, tmp_path / "model.npz"))
    np.testing.assert_array_equal(z["Ad"], src["Ad"])
    np.testing.assert_allclose(z["A"], src["A"], rtol=1e-6, atol=1e-6 * np.abs(src["A"]).max())
    bad = tmp_path / "bad.mat"
    scipy.io.savemat(bad, {"A": src["Ad"], "B": src["Bd"], "C": src["Cd"], "D": src["Dd"], "Ts": 1e-3})
    assert main(["design", "--model", str(bad), "--out", str(tmp_path / "d")]) == 2
