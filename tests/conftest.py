"""Scenes shared by several test modules, built once per session (results are not mutated by the tests)."""

import pytest

from gtsam_rotid import simulate
from gtsam_rotid.calibration import calibrate


@pytest.fixture(scope="session")
def reference_weighted():
    """The reference scene (seed 0, 10 s spins) and its ``weighted`` calibration: (dataset, truth, result)."""
    dataset, truth = simulate.reference_scene(seed=0, duration=10.0)
    return dataset, truth, calibrate(dataset, method="weighted")
