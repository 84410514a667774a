"""Shared fixtures: the bundled stage model, the ideal stage and its linear twin (built once per session),
and the order the test files start in."""
import pytest

from nanosim.plant.linearize import linearize
from nanosim.plant.mjcf import load_model
from nanosim.plant.stage import Stage, StageConfig


@pytest.fixture(scope="session")
def model():
    """The bundled MJCF stage, compiled."""
    return load_model()


@pytest.fixture(scope="session")
def ideal():
    """The MuJoCo stage with every electromechanical effect off."""
    return Stage(config=StageConfig.ideal())


@pytest.fixture(scope="session")
def twin(ideal):
    """MuJoCo's linearization of the ideal stage."""
    return linearize(ideal)


# The files that take longest, longest first (seconds in one process on a 2-vCPU machine, `--durations`):
# on two workers (`-n 2 --dist loadfile`, the README's command) each worker takes the next file in this
# order when it is free, so the long files start early and the workers finish together. The order
# changes no result: every test is independent of the others.
LONGEST_FILES = ("test_cli.py",                 # ~310 s, the pipeline end to end
                 "test_bench_controllers.py",   # ~155 s
                 "test_stage.py",               # ~150 s
                 "test_damping.py",             # ~90 s
                 "test_run_folders.py", "test_cli_arguments.py",   # the CLI's edges in subprocesses
                 "test_ablation.py",            # ~75 s
                 "test_montecarlo.py", "test_lqg.py", "test_sysid_orders.py", "test_identify_stage.py",
                 "test_design.py")


def pytest_configure(config):
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False      # xdist would order the files by their number of tests


def pytest_collection_modifyitems(config, items):
    rank = {name: k for k, name in enumerate(LONGEST_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))        # stable: in-file order kept
