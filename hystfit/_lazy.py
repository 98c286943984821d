"""Deferred imports of heavy modules, so that ``hystfit --help`` and short commands start fast.

``signal = lazy_module("scipy.signal")`` binds a stand-in that imports ``scipy.signal`` on the
first attribute access (importing it eagerly costs ≈ 0.5–0.8 s, mostly through ``scipy.stats``,
and most commands never need it). Nothing else changes for the code that uses the name.
"""

from __future__ import annotations

import importlib
from types import ModuleType


class _LazyModule:
    __slots__ = ("_name", "_module")

    def __init__(self, name: str) -> None:
        self._name = name
        self._module: ModuleType | None = None

    def __getattr__(self, attr: str):
        module = self._module
        if module is None:
            module = importlib.import_module(self._name)
            self._module = module
        return getattr(module, attr)

    def __repr__(self) -> str:
        return f"<lazy module {self._name!r}{' (loaded)' if self._module is not None else ''}>"


def lazy_module(name: str):
    """A module stand-in that imports ``name`` on first use."""
    return _LazyModule(name)
