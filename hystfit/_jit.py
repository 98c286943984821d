"""numba, configured once for every compiled kernel of hystfit, and imported only when a kernel runs.

Every module with a ``@njit(cache=True)`` kernel imports ``njit``/``prange`` from here, never from
numba directly, so that the on-disk cache location is decided before the first kernel is made.

Deferred. Importing numba takes ≈ 0.2–0.3 s and making a kernel's dispatcher ≈ 0.6 ms (there are
≈ 60), yet most commands run one or two kernels and many none (``hystfit models``, ``--help``, every
input check that fails before a fit). So :func:`njit` returns a :class:`Kernel`, a stand-in that
behaves as the function: on its first call (or first use of a dispatcher attribute) numba is
imported and configured, the kernel's numba dispatcher is made, and — before that dispatcher can
compile — the kernels it calls and ``prange`` are made real in its module (numba resolves a
kernel's globals when it compiles). Every loaded module that holds the stand-in under the kernel's
name gets the dispatcher in its place, so later calls (and kernels compiled later) go straight to
numba. numba then loads the kernel's machine code from its cache as before (one index and one
data file per kernel): the numbers and the cache files do not change, only when numba is
imported.

Why the cache does not live next to the source (numba's default ``__pycache__`` beside the module):
an installed package directory is not ours to write into. When numba writes ``*.nbi``/``*.nbc``
files into ``site-packages/hystfit/.../__pycache__``, ``pip uninstall`` (or the reinstall that
``pip install -e .`` performs after ``pip install .``) removes the files it installed but leaves
those directories behind; the orphaned ``site-packages/hystfit/`` without ``__init__.py`` then
shadows the real package as an empty *namespace package* and every ``import hystfit.models...``
fails. So the kernels are cached under the user's cache directory instead:
``$NUMBA_CACHE_DIR`` if the user set it (numba's own setting wins), else
``$XDG_CACHE_HOME/hystfit/numba`` (default ``~/.cache/hystfit/numba``). numba keys the entries on
the source file's full path, so several installs or checkouts never share machine code. If that
directory cannot be created, numba's own choice is left untouched.
"""

from __future__ import annotations

import functools
import math
import os
import sys
import threading
from pathlib import Path
from types import CodeType, ModuleType
from typing import Any, Callable

__all__ = ["njit", "prange", "fma", "cache_dir", "Kernel", "numba_loaded", "readonly"]

_lock = threading.RLock()
_numba: ModuleType | None = None


def _default_cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hystfit" / "numba"


def _configure(numba: ModuleType) -> None:
    if os.environ.get("NUMBA_CACHE_DIR") or numba.config.CACHE_DIR:
        return  # the user chose; respect it
    target = _default_cache_dir()
    try:
        target.mkdir(parents=True, exist_ok=True)
        probe = target / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError:
        return  # not writable: numba falls back to its own locators
    numba.config.CACHE_DIR = str(target)


def _load_numba() -> ModuleType:
    """numba, imported and configured (once)."""
    global _numba, prange, _fma_intrinsic
    with _lock:
        if _numba is None:
            import numba

            _configure(numba)
            prange = numba.prange
            _fma_intrinsic = _make_fma(numba)
            _numba = numba
        return _numba


def _make_fma(numba: ModuleType):
    """The compiled ``fma``: LLVM's ``llvm.fma.f64``, one correctly rounded a·b + c."""
    from numba.core import types
    from numba.extending import intrinsic

    @intrinsic
    def fma_f64(typingctx, a, b, c):
        f64 = types.float64

        def codegen(context, builder, signature, args):
            x, y, z = (context.cast(builder, v, t, f64) for v, t in zip(args, signature.args))
            return builder.fma(x, y, z)

        return f64(a, b, c), codegen

    return fma_f64


def readonly(x: Any, dtype: Any = None):
    """``x`` as the one array type a kernel is compiled for: C-contiguous, of ``dtype`` (default
    float64) and read-only — a read-only *view*, no copy, where ``x`` already is contiguous.

    Why every array a kernel only reads passes through here: numba types a read-only array apart
    from a writable one and compiles the kernel again for each combination, although the machine
    code is the same. A capture read from CSV holds read-only arrays; one made by the virtual
    actuator, a fit mask or arithmetic holds writable ones; a wrapper's stand-in for "no data"
    (``np.empty(0)``) is writable. Without one form, the first run after installing compiled the
    Bouc–Wen kernel twice in one ``identify`` (≈ 45–60 s each on the project's machine), and gPI
    with dynamics twice in ``compare``. Arrays a kernel writes are never passed through here.
    """
    import numpy as np

    a = np.ascontiguousarray(x, dtype=np.float64 if dtype is None else dtype)
    if a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a


def numba_loaded() -> bool:
    """Whether numba has been imported for a kernel in this process (its start-up is paid)."""
    return _numba is not None


def cache_dir() -> str | None:
    """The directory numba caches hystfit's kernels in (None: numba's default locators)."""
    return _load_numba().config.CACHE_DIR or None


class _Prange:
    """``prange`` until numba is loaded: :func:`_materialize` puts ``numba.prange`` in its place in a
    kernel's module before the kernel compiles (called from Python, it is ``range``)."""

    def __call__(self, *args):
        return _load_numba().prange(*args)

    def __repr__(self) -> str:
        return "<hystfit._jit.prange: numba.prange once numba is loaded>"


_PRANGE = _Prange()
prange: Any = _PRANGE


class _Fma:
    """``fma(a, b, c)``: a·b + c rounded once (a fused multiply–add), the same number in every
    kernel and every process. In a kernel it is LLVM's ``llvm.fma.f64`` (put in place by
    :func:`_materialize`, as ``prange``); called from Python, the exact value rounded once.

    Why kernels write their multiply–adds this way instead of letting the compiler fuse them
    (``fastmath={"contract", ...}``): a compiler fuses (and, with ``reassoc``, reorders) where the
    optimised code allows, and the same kernel is optimised in more than one context — alone,
    and inlined into each kernel that calls it — so the last bits of a result depended on which
    compiled copy ran, that is on what the process had compiled or loaded before (a first,
    compiling run gave other digits than the runs after it). An explicit fused multiply–add is
    one IEEE operation everywhere: the speed of fusing, and the same numbers in every process.
    """

    def __call__(self, a, b, c):
        from fractions import Fraction

        a, b, c = float(a), float(b), float(c)
        if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(c)):
            return a * b + c  # inf/NaN: what the fused operation gives too
        exact = Fraction(a) * Fraction(b) + Fraction(c)
        if exact == 0:  # the sign IEEE gives: −0 only when a·b and c are both −0
            z = a * b + c
            return z if z == 0 else 0.0
        try:
            return float(exact)  # correctly rounded
        except OverflowError:
            return math.inf if exact > 0 else -math.inf

    def __repr__(self) -> str:
        return "<hystfit._jit.fma: llvm.fma.f64 once numba is loaded>"


_FMA = _Fma()
fma: Any = _FMA
_fma_intrinsic: Any = None


class Kernel:
    """A ``@njit`` function whose numba dispatcher is made when it is first used (see the module)."""

    def __init__(self, py_func: Callable, options: dict[str, Any]) -> None:
        self.py_func = py_func
        self._options = options
        self._dispatcher = None
        functools.update_wrapper(self, py_func)

    def dispatcher(self):
        """The numba dispatcher (numba is imported and configured on the first call)."""
        if self._dispatcher is None:
            _materialize(self)
        return self._dispatcher

    def __call__(self, *args, **kwargs):
        dispatcher = self._dispatcher
        if dispatcher is None:
            dispatcher = self.dispatcher()
        return dispatcher(*args, **kwargs)

    def __getattr__(self, name: str):  # numba's attributes: signatures, stats, _numba_type_, ...
        if name in ("py_func", "_options", "_dispatcher", "__wrapped__") or name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.dispatcher(), name)

    def __reduce__(self):
        return _kernel_named, (self.__module__, self.__qualname__)

    def __repr__(self) -> str:
        state = "loaded" if self._dispatcher is not None else "not loaded yet"
        return f"<hystfit kernel {self.__module__}.{self.__qualname__} ({state})>"


def _kernel_named(module: str, qualname: str):
    __import__(module)
    return getattr(sys.modules[module], qualname)


def _code_names(code: CodeType) -> set[str]:
    """Global and attribute names a function's code (and the code nested in it) refers to."""
    names = set(code.co_names)
    for const in code.co_consts:
        if isinstance(const, CodeType):
            names |= _code_names(const)
    return names


def _materialize(kernel: Kernel) -> None:
    """Make ``kernel``'s dispatcher, and those of the kernels it calls, with them and ``prange`` real
    in its module; then publish them (other threads see a dispatcher only once it can compile)."""
    with _lock:
        if kernel._dispatcher is not None:
            return
        made: dict[Kernel, Any] = {}
        _make(kernel, made, _load_numba())
        for k, dispatcher in made.items():
            k._dispatcher = dispatcher
        for k in made:
            _replace_everywhere(k)


def _make(kernel: Kernel, made: dict, numba: ModuleType) -> None:
    made[kernel] = numba.njit(**kernel._options)(kernel.py_func)  # first: a kernel may call itself
    g = kernel.py_func.__globals__
    names = _code_names(kernel.py_func.__code__)
    for name in names:
        value = g.get(name)
        if value is _PRANGE:
            g[name] = numba.prange
        elif value is _FMA:
            g[name] = _fma_intrinsic
        elif isinstance(value, Kernel):
            g[name] = _dispatcher_of(value, made, numba)
        elif isinstance(value, ModuleType):  # module.kernel inside a kernel (no module __getattr__ runs)
            space = vars(value)
            for attr in names:
                inner = space.get(attr)
                if isinstance(inner, Kernel):
                    _dispatcher_of(inner, made, numba)


def _dispatcher_of(kernel: Kernel, made: dict, numba: ModuleType):
    if kernel._dispatcher is not None:
        return kernel._dispatcher
    if kernel not in made:
        _make(kernel, made, numba)
    return made[kernel]


def _replace_everywhere(kernel: Kernel) -> None:
    """Put the dispatcher in place of the stand-in in every loaded module that binds the kernel's name."""
    name = kernel.__name__
    for module in list(sys.modules.values()):
        space = module.__dict__ if isinstance(module, ModuleType) else None
        if space is not None and space.get(name) is kernel:
            space[name] = kernel._dispatcher


def njit(*args, **options):
    """``numba.njit`` for hystfit's kernels: ``@njit(cache=True, ...)`` (or bare ``@njit``); the
    dispatcher is made on first use (:class:`Kernel`)."""

    def decorate(py_func: Callable) -> Kernel:
        return Kernel(py_func, options)

    if args and callable(args[0]) and len(args) == 1:
        return decorate(args[0])
    if args:
        raise TypeError("hystfit._jit.njit takes keyword options only (no signatures)")
    return decorate
