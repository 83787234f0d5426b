"""Fixtures for the factor tests (helpers live in factor_scene.py)."""

from __future__ import annotations

import numpy as np
import pytest
from factor_scene import Scene, make_scene


@pytest.fixture
def scene() -> Scene:
    return make_scene()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20240611)
