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



#: appended to code run in a fresh process by :func:`kernel_twins`: prints one ``TWIN`` line per
#: hystfit kernel that numba compiled for two argument lists differing only in arrays' read-only
#: flags (the same machine code twice: :func:`hystfit._jit.readonly`)
TWINS_CODE = """
import re as _re, sys as _sys

def _plain(sig):
    return _re.sub(r"'([CFA])', (True|False)", r"'\\1'", repr(sig))

_found = set()
for _module in list(_sys.modules.values()):
    if not getattr(_module, "__name__", "").startswith("hystfit"):
        continue
    for _value in list(vars(_module).values()):
        _sigs = getattr(_value, "signatures", None) if type(_value).__name__ == "CPUDispatcher" else None
        if _sigs and len({_plain(s) for s in _sigs}) < len(_sigs):
            _found.add(f"{_value.py_func.__module__}.{_value.py_func.__qualname__}: " + " | ".join(map(repr, _sigs)))
for _line in sorted(_found):
    print("TWIN", _line)
"""


@pytest.fixture
def server():
    """A figure server of :mod:`hystfit.report.render` of its own (forked whatever threads this test
    process runs), closed afterwards."""
    from hystfit.report import render

    render._close_server()
    render._server = render._FigureServer()
    yield render._server
    render._close_server()


@pytest.fixture
def kernel_twins():
    """``run(code)``: runs ``code`` in a fresh process (so that no other test's calls count), then
    returns the kernels it made numba compile twice for read-only and writable arrays."""
    import subprocess
    import sys

    def run(code: str) -> list[str]:
        r = subprocess.run([sys.executable, "-c", code + TWINS_CODE], capture_output=True, text=True, timeout=900)
        assert r.returncode == 0, r.stderr[-3000:]
        return [line[len("TWIN "):] for line in r.stdout.splitlines() if line.startswith("TWIN ")]

    return run
