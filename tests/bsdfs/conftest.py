import numpy as np
import pytest


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator: statistical tests are deterministic."""
    return np.random.default_rng(20240611)
