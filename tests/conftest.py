"""Shared fixtures: the bundled stage model, the ideal stage and its linear twin (built once per session)."""
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
