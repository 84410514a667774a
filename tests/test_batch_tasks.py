"""The pipeline's experiment tasks (one experiment per process-pool task, on the batch engine) give the
numbers of ``nanosim characterize``: the schedule of ``nanosim pipeline`` and ``--seeds`` changes no metric."""
import json

import numpy as np
import pytest

from nanosim.pipeline.characterize import experiment_task, run_characterize, write_task_metrics
from nanosim.pipeline.config import CharacterizeConfig
from nanosim.plant.mjcf import load_model
from nanosim.plant.modes import modal_analysis


@pytest.fixture(scope="module")
def controller_npz(tmp_path_factory):
    """A leaky integrator through inv(G0) (20 Hz), written as ``controller.npz``."""
    T = 2.5e-4
    g = 2 * np.pi * 20 * T * np.linalg.inv(modal_analysis(load_model()).static_gain_um_per_V / 5.0)
    path = tmp_path_factory.mktemp("ctrl") / "controller.npz"
    np.savez(path, Akd=0.9995 * np.eye(3), Bkd=np.eye(3), Ckd=g, Dkd=g, dt=np.array(T))
    return path


@pytest.mark.parametrize("twin", [True, False], ids=["twin", "mujoco"])
def test_experiment_task_gives_run_characterize_numbers_bitwise(controller_npz, tmp_path, twin):
    name, met, seconds = experiment_task(controller_npz, tmp_path / "task", "small_steps", 3, twin=twin)
    ref = run_characterize(controller_npz, tmp_path / "ref", CharacterizeConfig(seed=3, twin=twin, only="small_steps"),
                           progress=False)
    assert name == "small_steps" and seconds >= 0
    assert met and json.dumps(met, sort_keys=True) == json.dumps({k: ref[k] for k in met}, sort_keys=True)
    assert (tmp_path / "task" / "fig17_small_steps.png").is_file()


def test_task_metrics_need_every_experiment(tmp_path):
    with pytest.raises(ValueError, match="parts: .*'hysteresis' is missing"):
        write_task_metrics(tmp_path, {"creep": ({}, 1.0)}, seed=0)
