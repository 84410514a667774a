"""Same seed, same bits, whatever the machine's BLAS threads: the identification (tall QR and least
squares over 16000-sample records, which OpenBLAS splits differently with more threads) runs on one
BLAS thread, so the identified model does not depend on the core count."""
import numpy as np
import pytest

threadpoolctl = pytest.importorskip("threadpoolctl")


def _twin_runner():
    from nanosim.plant.batch import BatchTwinStage
    from nanosim.plant.floor import floor_model
    from nanosim.plant.linearize import linearize
    from nanosim.plant.mjcf import load_model
    from nanosim.plant.stage import Stage, StageConfig

    model = load_model()
    mech = linearize(Stage(config=StageConfig.ideal(), model=model))
    home, fm = Stage(model=model).table_um.copy(), floor_model(model)

    def runner(u_batch, *, seeds, config=None, model=None):      # run_open_loop_batch's call, on the twin
        return BatchTwinStage(mech, seeds, config=config, home_um=home, floor_models=fm).run(u_batch)
    return runner


def test_identification_bits_do_not_depend_on_blas_threads():
    from nanosim.experiments.sysid import IdentifySettings, identify_stage

    runner = _twin_runner()
    out = []
    for threads in (1, 2):
        with threadpoolctl.threadpool_limits(limits=threads, user_api="blas"):
            r = identify_stage(IdentifySettings(seed=3), runner=runner)
        out.append((np.asarray(r.sysd.A), np.asarray(r.sysd.B), np.asarray(r.sysd.C), r.fit_percent))
    for a, b in zip(*out):
        np.testing.assert_array_equal(a, b)
