"""hystfit._jit: kernels are numba dispatchers made on first use, with what they call made real first."""

import importlib
import json
from pathlib import Path
import pickle
import subprocess
import sys

import numpy as np

from hystfit._jit import Kernel, fma, njit, prange


KERNELS = """
import numpy as np
from hystfit._jit import njit, prange


@njit(cache=False)
def inner(x):
    return 2.0 * x


@njit(cache=False)
def outer(a):
    out = np.empty_like(a)
    for i in range(a.shape[0]):
        out[i] = inner(a[i]) + 1.0
    return out


@njit(cache=False, parallel=True)
def threaded(a):
    out = np.empty_like(a)
    for i in prange(a.shape[0]):
        out[i] = inner(a[i])
    return out


@njit(cache=False)
def factorial(n):
    return 1 if n <= 1 else n * factorial(n - 1)


@njit
def bare(x):
    return x + 1
"""


def _module(tmp_path, monkeypatch, name):
    (tmp_path / f"{name}.py").write_text(KERNELS)
    (tmp_path / f"{name}_user.py").write_text(f"from {name} import outer\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    return importlib.import_module(name), importlib.import_module(f"{name}_user")


def test_a_kernel_is_a_stand_in_until_first_called_then_numba_everywhere(tmp_path, monkeypatch):
    import numba
    from numba.core.registry import CPUDispatcher

    mod, user = _module(tmp_path, monkeypatch, "jit_kernels_a")
    assert all(isinstance(getattr(mod, n), Kernel) for n in ("inner", "outer", "threaded", "factorial", "bare"))
    assert isinstance(user.outer, Kernel)
    a = np.arange(4.0)
    np.testing.assert_array_equal(user.outer(a), 2.0 * a + 1.0)
    # numba's dispatchers replace the stand-ins of the kernel and of the kernel it calls, in every module
    assert isinstance(mod.outer, CPUDispatcher) and isinstance(user.outer, CPUDispatcher)
    assert isinstance(mod.inner, CPUDispatcher) and mod.outer.py_func.__name__ == "outer"
    assert isinstance(mod.threaded, Kernel)  # not used yet: not made
    np.testing.assert_array_equal(mod.threaded(a), 2.0 * a)
    assert mod.prange is numba.prange and mod.threaded.targetoptions["parallel"]
    assert mod.factorial(5) == 120 and mod.bare(1) == 2


def test_stand_in_behaves_as_the_function():
    def f(x):
        """Doc of f."""
        return x * 3

    k = Kernel(f, {"cache": False})
    assert k.__name__ == "f" and k.__doc__ == "Doc of f." and k.py_func is f
    assert "not loaded yet" in repr(k)
    assert k(2) == 6
    assert k.signatures  # numba's attributes, through the dispatcher
    assert "loaded" in repr(k) and "not" not in repr(k)


def test_stand_in_pickles_by_name():
    from hystfit.models import _kernels

    k = _kernels.__dict__["_play_recurrence"]
    assert pickle.loads(pickle.dumps(k)) is _kernels._play_recurrence


def test_prange_called_from_python_is_range():
    assert list(prange(3)) == [0, 1, 2]


def test_importing_the_package_does_not_import_numba_or_pandas():
    """What ``hystfit models``/``--help`` and the input checks run: no numba, no pandas, no rich."""
    code = ("import sys, json\n"
            "import hystfit.cli, hystfit.models, hystfit.optimizers, hystfit.blocks, hystfit.identify, hystfit.io\n"
            "print(json.dumps(sorted(m for m in ('numba', 'pandas', 'rich', 'matplotlib') if m in sys.modules)))\n")
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    assert json.loads(out) == []


FMA_KERNEL = """
from hystfit._jit import fma, njit


@njit(cache=False)
def fused(a, b, c):
    out = a.copy()
    for i in range(a.shape[0]):
        out[i] = fma(a[i], b[i], c[i])
    return out
"""


def test_fma_is_one_rounding_in_a_kernel_and_from_python(tmp_path, monkeypatch):
    """``fma`` in a kernel is the fused operation (it differs from a·b + c rounded twice), and
    the Python stand-in gives the same numbers."""
    (tmp_path / "jit_fma_kernel.py").write_text(FMA_KERNEL)
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module("jit_fma_kernel")
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=2000), rng.normal(size=2000)
    c = -a * b  # a·b + c is then exactly the rounding error of a·b: 0 unfused, not 0 fused
    got = mod.fused(a, b, c)
    assert np.count_nonzero(got) > 1000 and np.all(a * b + c == 0.0)
    assert [fma(x, y, z) for x, y, z in zip(a, b, c)] == list(got)
    assert fma(2.0, 3.0, 1.0) == 7.0 and np.isnan(fma(np.inf, 0.0, 1.0)) and fma(1e308, 10.0, 0.0) == np.inf


def test_no_kernel_asks_the_compiler_to_fuse_or_reorder_by_itself():
    """No hystfit kernel uses fastmath: fusing or reordering is decided per compiled copy of a
    helper (alone, inlined into each caller), so the last bits would depend on what a process
    compiled or loaded before. Multiply–adds are written as :data:`hystfit._jit.fma`."""
    import pkgutil

    import hystfit

    flagged = []
    for info in pkgutil.walk_packages(hystfit.__path__, "hystfit."):
        if info.name.startswith("hystfit.cli") or info.name.startswith("hystfit.report"):
            continue
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            options = value._options if isinstance(value, Kernel) else getattr(value, "targetoptions", None)
            if isinstance(options, dict) and options.get("fastmath"):
                flagged.append(f"{info.name}.{name}")
    assert flagged == []


GPI_THREADED = """
import hashlib
import sys
import numpy as np
from hystfit.io import load_capture
from hystfit.models import gpi as G
from hystfit._jit import readonly

c = load_capture(sys.argv[1])
u, y = readonly(c.u), readonly(c.y)
rng = np.random.default_rng(11)
P = 100
theta = [readonly(rng.uniform(lo, hi, P)) for lo, hi in ((0.5, 2.0), (0.01, 0.1), (-1.0, 1.0), (-1.0, 1.0), (0.5, 2.0),
                                                          (0.01, 0.1), (-1.0, 1.0), (-1.0, 1.0), (0.0, 0.2), (0.1, 2.0))]
no_levels = (u, readonly(np.empty(0, dtype=np.int64), np.int64))
for levels in (no_levels, G.input_levels(u)):
    levels = (readonly(levels[0]), readonly(levels[1], np.int64))
    for target in (readonly(np.empty(0)), y):
        out = np.empty((u.size, P)) if target.size == 0 else np.empty((P, 3))
        G._gpi_parallel(u, *levels, target, *theta, 10, out, 0, 2)
        print(hashlib.sha256(out.tobytes()).hexdigest())
"""


def test_a_kernel_gives_the_same_bits_compiled_here_and_loaded_from_the_cache(tmp_path):
    """A threaded kernel (gPI's) in a process that compiles it (a first run after installing) and
    in one that loads it from numba's cache: the same bits, outputs and moments. With fastmath
    flags they differ: the compiling process runs the block kernel as compiled alone, the loading
    one the copy optimised again inside the threaded kernel (shown by adding ``fastmath=True`` to
    gpi.py's kernels: the outputs of the two runs differ). The Bouc–Wen kernels, where the
    difference was first seen (a first run's squared errors differed in the last digits from
    every later run's), write their multiply–adds as explicit fused operations and no longer show
    it even with fastmath flags; their compilation also costs more."""
    env = {**__import__("os").environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    capture = str(Path(__file__).resolve().parents[2] / "sample_data" / "a40V_f80Hz.csv")
    runs = [subprocess.run([sys.executable, "-c", GPI_THREADED, capture], check=True, capture_output=True, text=True,
                           env=env, timeout=300).stdout for _ in range(2)]
    assert any((tmp_path / "numba").rglob("*.nbi"))  # the first run compiled and cached, the second loaded
    assert runs[0] == runs[1] and len(runs[0].split()) == 4
