"""Name → component registries (one per axis: models, blocks, optimizers).

Adding a model or optimizer is adding one file that decorates its class with
``@models.register`` / ``@optimizers.register``; the CLI choices, ``hystfit models``,
the docs and the contract tests all read from here. A duplicate name is an error.
"""

from __future__ import annotations

import importlib
from typing import Generic, Iterator, TypeVar

from .errors import ConfigError

T = TypeVar("T")


class Registry(Generic[T]):
    """A mapping from a short lower-case name to a component class."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._items: dict[str, type[T]] = {}

    def register(self, cls: type[T]) -> type[T]:
        name = getattr(cls, "name", None)
        if not isinstance(name, str) or not name:
            raise TypeError(f"{cls!r} has no 'name' class attribute")
        if name in self._items:
            raise ValueError(f"{self.kind} {name!r} is registered twice")
        self._items[name] = cls
        return cls

    def get(self, name: str) -> type[T]:
        _load_builtin()
        key = name.strip().lower()
        if key not in self._items:
            raise ConfigError(
                f"unknown {self.kind} {name!r}: choose one of {', '.join(self.names())}"
            )
        return self._items[key]

    def names(self) -> list[str]:
        _load_builtin()
        return list(self._items)

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __contains__(self, name: object) -> bool:
        _load_builtin()
        return isinstance(name, str) and name.strip().lower() in self._items


models: Registry = Registry("model")
optimizers: Registry = Registry("optimizer")
blocks: Registry = Registry("block")

_loaded = False


def _load_builtin() -> None:
    """Import the built-in model and optimizer packages (they register themselves)."""
    global _loaded
    if _loaded:
        return
    _loaded = True

    importlib.import_module(f"{__package__}.models")
    importlib.import_module(f"{__package__}.optimizers")
    importlib.import_module(f"{__package__}.blocks")


