import os

# One BLAS thread per test process: the suite runs on 2 cores, and small dense solves
# (SVDs of Jacobians, least squares) are slower with oversubscribed BLAS threads.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture
def rng():
    """A seeded generator per test (no global seeding)."""
    return np.random.default_rng(12345)
