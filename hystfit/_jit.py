"""numba, configured once for every compiled kernel of hystfit.

Every module with a ``@njit(cache=True)`` kernel imports ``njit``/``prange`` from here, never from
numba directly, so that the on-disk cache location is decided before the first kernel is defined.

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

import os
from pathlib import Path

import numba
from numba import njit, prange

__all__ = ["njit", "prange", "cache_dir"]


def _default_cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hystfit" / "numba"


def _configure() -> None:
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


def cache_dir() -> str | None:
    """The directory numba caches hystfit's kernels in (None: numba's default locators)."""
    return numba.config.CACHE_DIR or None


_configure()
