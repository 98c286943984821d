"""hystfit.parallel.one_blas_thread: the library's entry points run one BLAS thread, as the CLI does.

Run in fresh processes: the test session itself sets OPENBLAS_NUM_THREADS=1 (tests/conftest.py)
before numpy loads, which is the case the limit leaves alone.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

PROBE = r"""
import json, os
import numpy as np
from threadpoolctl import threadpool_info
from hystfit.parallel import one_blas_thread, fork_map

def blas():
    return sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})

@one_blas_thread
def inner():
    return blas()

@one_blas_thread
def outer():
    first = blas()
    nested = inner()
    after_nested = blas()
    in_child = fork_map(lambda i: blas(), 2, 2)
    return first, nested, after_nested, in_child

before = blas()
first, nested, after_nested, in_child = outer()
print(json.dumps({"before": before, "first": first, "nested": nested, "after_nested": after_nested,
                  "in_child": in_child, "after": blas()}))
"""

BLAS_VARS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "OMP_NUM_THREADS")


def _probe(code: str = PROBE, **env_vars) -> dict:
    """The JSON last printed by ``code`` run in a fresh process without BLAS thread variables
    (but ``env_vars``)."""
    env = {k: v for k, v in os.environ.items() if k not in BLAS_VARS}
    env.update(env_vars)
    out = subprocess.run([sys.executable, "-c", code], env=env, check=True, capture_output=True, text=True,
                         timeout=120).stdout
    return json.loads(out.strip().splitlines()[-1])


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="BLAS runs one thread on one core anyway")
def test_one_blas_thread_inside_nested_and_in_children_then_restored():
    got = _probe()
    if not got["before"]:
        pytest.skip("threadpoolctl sees no BLAS library in this build")
    assert max(got["before"]) > 1  # numpy loaded without a variable: a thread per core
    assert got["first"] == [1]
    assert got["nested"] == [1]
    assert got["after_nested"] == [1], "a nested call must not restore the caller's threads early"
    assert got["in_child"] == [[1], [1]]
    assert got["after"] == got["before"]


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="BLAS runs one thread on one core anyway")
def test_a_users_explicit_blas_threads_are_left_alone():
    got = _probe(OPENBLAS_NUM_THREADS="2")
    assert got["before"] == [2]
    assert got["first"] == [2] and got["nested"] == [2] and got["after"] == [2]


def test_the_library_entry_points_are_limited():
    from hystfit import compare, diagnose, identify, invert, track
    from hystfit.parallel import one_blas_thread

    limited = one_blas_thread(len).__code__
    for fn in (identify.identify, compare.compare, diagnose.diagnose, diagnose.fit_recommended,
               invert.invert_target, track.track, track.measure_bandwidths):
        assert getattr(fn, "__wrapped__", None) is not None, fn.__qualname__
        assert fn.__code__ is limited, fn.__qualname__


FAILING_PROBE = r"""
import json
import numpy as np
import threadpoolctl
from hystfit import parallel

def broken(*a, **k):
    raise RuntimeError("no BLAS control here")

real = threadpoolctl.threadpool_limits
threadpoolctl.threadpool_limits = broken

@parallel.one_blas_thread
def call():
    return parallel._blas_depth

inside = call()
after_failure = parallel._blas_depth
threadpoolctl.threadpool_limits = real

@parallel.one_blas_thread
def limited():
    return sorted({i["num_threads"] for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"})

print(json.dumps({"inside": inside, "after_failure": after_failure, "limited_later": limited(),
                  "depth_at_end": parallel._blas_depth}))
"""


def test_a_limit_that_cannot_be_set_costs_only_time():
    got = _probe(FAILING_PROBE)
    assert got["inside"] == 1 and got["after_failure"] == 0 and got["depth_at_end"] == 0
    assert got["limited_later"] in ([], [1])  # the next call is limited again (no BLAS seen: nothing to limit)


LATE_CLI_PROBE = r"""
import json, os
import numpy as np  # loaded first: the command line's defaults come too late for its BLAS
from threadpoolctl import threadpool_info
import hystfit.cli  # noqa: F401 - sets OPENBLAS_NUM_THREADS=1, now without effect on numpy's BLAS
from hystfit._blas import user_chose_blas_threads
from hystfit.parallel import one_blas_thread

def blas():
    return sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})

@one_blas_thread
def call():
    return blas()

print(json.dumps({"var": os.environ.get("OPENBLAS_NUM_THREADS"), "chose": user_chose_blas_threads(),
                  "before": blas(), "inside": call()}))
"""


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="BLAS runs one thread on one core anyway")
def test_the_command_lines_defaults_set_after_numpy_loaded_are_not_a_users_choice():
    # a program that imported numpy before hystfit.cli (CliRunner in a test suite, a notebook):
    # before the fix the limit took the command line's own variable for the user's choice and left
    # numpy's BLAS at a thread per core (diagnose on sample_data ≈ 3× as long)
    got = _probe(LATE_CLI_PROBE)
    if not got["before"]:
        pytest.skip("threadpoolctl sees no BLAS library in this build")
    assert got["var"] == "1" and got["chose"] is False
    assert max(got["before"]) > 1
    assert got["inside"] == [1]


def test_the_command_lines_defaults_set_before_numpy_loaded_are_kept(monkeypatch):
    from hystfit import _blas

    for var in BLAS_VARS:
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setattr(_blas, "_set_too_late", set())
    monkeypatch.setattr(sys, "modules", {k: v for k, v in sys.modules.items() if k != "numpy"})
    _blas.set_cli_defaults()
    assert all(os.environ[v] == "1" for v in _blas.CLI_DEFAULTS)
    assert _blas.user_chose_blas_threads()  # in time: numpy's BLAS reads them, nothing to limit
    assert "OMP_NUM_THREADS" not in os.environ
