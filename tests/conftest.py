import numpy as np
import pytest


@pytest.fixture
def rng():
    """A seeded generator per test (no global seeding)."""
    return np.random.default_rng(12345)
