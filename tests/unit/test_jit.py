"""hystfit._jit: kernels are numba dispatchers made on first use, with what they call made real first."""

import importlib
import json
import pickle
import subprocess
import sys

import numpy as np

from hystfit._jit import Kernel, njit, prange


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
