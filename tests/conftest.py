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


#: runs the hystfit command line in a fresh process and prints its peak resident set size (kB) on
#: stderr after ``peak_kB``. VmHWM of the process image, not ru_maxrss: Linux carries ru_maxrss over
#: exec from the forking parent, so a test run whose pytest process had grown past 1 GB made a
#: 530 MB command read as 1,039 MB.
PEAK_RSS_CODE = (
    "import sys\n"
    "from hystfit.cli import main\n"
    "try:\n    main(sys.argv[1:])\nexcept SystemExit as exc:\n    assert exc.code in (0, None), exc.code\n"
    "hwm = [ln.split()[1] for ln in open('/proc/self/status') if ln.startswith('VmHWM:')][0]\n"
    "print('peak_kB', hwm, file=sys.stderr)\n"
)


@pytest.fixture
def peak_rss_code():
    """:data:`PEAK_RSS_CODE` (``python -c CODE ARGS...``)."""
    return PEAK_RSS_CODE
