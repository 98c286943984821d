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


def _twins() -> list[str]:
    """hystfit's compiled kernels that numba compiled for two argument lists differing only in
    arrays' read-only flags (the same machine code twice: :func:`hystfit._jit.readonly`)."""
    import re
    import sys

    def plain(sig) -> str:
        return re.sub(r"'([CFA])', (True|False)", r"'\1'", repr(sig))

    found = []
    for module in list(sys.modules.values()):
        if not getattr(module, "__name__", "").startswith("hystfit"):
            continue
        for name, value in list(vars(module).items()):
            sigs = getattr(value, "signatures", None) if type(value).__name__ == "CPUDispatcher" else None
            if sigs and len({plain(s) for s in sigs}) < len(sigs):
                found.append(f"{value.py_func.__module__}.{value.py_func.__qualname__}: "
                             + " | ".join(repr(s) for s in sigs))
    return sorted(set(found))


@pytest.fixture
def readonly_twins():
    """A function listing the kernels compiled twice for read-only and writable arrays (see ``_twins``)."""
    return _twins
