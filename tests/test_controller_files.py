"""One controller file, three spellings (``.npz`` with ``Akd..Dkd``, ``.npz`` with ``A, B, C, D``, ``.mat``),
through every command that takes one: characterize, view, montecarlo and compare read the same matrices
and give the same numbers."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.io import savemat

from nanosim.cli import main
from nanosim.design.architectures.protocol import load_controller, read_controller_file
from nanosim.fileio import write_npz

DT = 2.5e-4
#: Integral gain per sample: the closed-loop integrator pole at z = 1 - KI (KI x 4 kHz = 0.8 rad/s), below the modes.
KI = 2e-4


def _integrator():
    """A decoupling integral controller, ``x+ = x + e``, ``u = KI G0^-1 x``: three states, error-only.

    ``G0`` is the static gain of the stage's linear twin (controller V -> sensor V), so the loop is
    ``KI z^-1 / (1 - z^-1)`` per axis at low frequency: stable for a small ``KI``.
    """
    import functools

    @functools.lru_cache(maxsize=1)
    def g0():
        from nanosim.plant.linearize import linearize
        from nanosim.plant.stage import Stage, StageConfig

        s = linearize(Stage(config=StageConfig.ideal())).sysd_V
        return s.C @ np.linalg.solve(np.eye(s.A.shape[0]) - s.A, s.B) + s.D

    return np.eye(3), np.eye(3), KI * np.linalg.inv(g0()), np.zeros((3, 3))


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    d = tmp_path_factory.mktemp("ctrl")
    A, B, C, D = _integrator()
    out = {"npz_kd": write_npz(d / "k_kd.npz", Akd=A, Bkd=B, Ckd=C, Dkd=D, dt=DT),
           "npz_abcd": write_npz(d / "k_abcd.npz", A=A, B=B, C=C, D=D, dt=DT)}
    savemat(d / "k.mat", {"A": A, "B": B, "C": C, "D": D, "dt": DT})
    out["mat"] = d / "k.mat"
    return out, (A, B, C, D)


@pytest.fixture(scope="module")
def files(made):
    return made[0]


def test_every_spelling_reads_as_the_same_state_space(made):
    files, (A, B, C, D) = made
    for f in files.values():
        cfg = read_controller_file(f)
        for got, want in zip((cfg.Akd, cfg.Bkd, cfg.Ckd, cfg.Dkd), (A, B, C, D)):
            np.testing.assert_array_equal(np.atleast_2d(got), want)
        assert cfg.dt == DT and cfg.n_error == 3


def test_a_missing_sample_time_is_refused_naming_the_variable(made, tmp_path):
    A, B, C, D = made[1]
    savemat(tmp_path / "nodt.mat", {"A": A, "B": B, "C": C, "D": D})
    write_npz(tmp_path / "nodt.npz", Akd=A, Bkd=B, Ckd=C, Dkd=D)
    for f in ("nodt.mat", "nodt.npz"):
        with pytest.raises(ValueError, match=r"^--controller: .*dt: expected the variable dt"):
            read_controller_file(tmp_path / f, name="--controller")


def test_view_and_compare_read_every_spelling(files):
    from nanosim.viewer.sim import load_controller as view_controller

    ref = read_controller_file(files["npz_kd"])
    for f in files.values():
        v = view_controller(f).config
        c = load_controller(str(f)).config
        for cfg in (v, c):
            np.testing.assert_array_equal(cfg.Akd, ref.Akd)
            np.testing.assert_array_equal(cfg.Ckd, ref.Ckd)
            assert cfg.dt == ref.dt


def test_characterize_runs_every_spelling_with_the_same_numbers(files, tmp_path, capsys):
    got = {}
    for key, f in files.items():
        out = tmp_path / key
        rc = main(["characterize", "--controller", str(f), "--out", str(out), "--twin", "--only", "small_steps"])
        assert rc == 0, capsys.readouterr().err
        got[key] = json.loads((out / "metrics.json").read_text())["small_steps"]
    assert got["npz_abcd"] == got["npz_kd"] and got["mat"] == got["npz_kd"]


def test_montecarlo_runs_every_spelling_with_the_same_numbers(files, tmp_path):
    from nanosim.pipeline.config import MonteCarloConfig
    from nanosim.pipeline.montecarlo import run_montecarlo

    cfg = MonteCarloConfig(n=1, crosscheck=0, workers=1, experiments=("small_steps",))
    got = {}
    for key in ("npz_kd", "mat"):
        out = tmp_path / key
        run_montecarlo(files[key], out, cfg, progress=False, say=lambda msg: None)
        rec = json.loads((out / "samples" / "sample_00000.json").read_text())
        got[key] = rec["metrics"]
    assert got["mat"] == got["npz_kd"]
