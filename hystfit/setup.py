"""Building models and optimizers from names and KEY=VALUE options (validated, with clear errors)."""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping

from .errors import ConfigError, HystfitError


def _build(cls: type, options: Mapping[str, Any], what: str):
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = [k for k in options if k not in fields]
    if unknown:
        raise ConfigError(f"{what} {cls.name!r}: unknown option {unknown[0]!r}; valid options: {', '.join(fields) or 'none'}")
    try:
        return cls(**options)
    except HystfitError:
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{what} {cls.name!r}: invalid options {dict(options)!r} ({exc})") from None


def make_model(model: "str | type", options: Mapping[str, Any] | None = None):
    """The model named by an expression (``pi``, ``pi+creep+delay``; see
    :mod:`hystfit.models.composite`) or a registered model class, with structure options
    (e.g. ``n_operators=12``; ``creep.tau_s=[0.01,0.1]`` for a block of the expression).

    JSON lists (e.g. ``thresholds_V=[0,5,10]`` or a saved structure) become tuples, as the
    frozen model dataclasses store them.
    """
    from .models.composite import build_model

    opts = {k: tuple(v) if isinstance(v, list) else v for k, v in dict(options or {}).items()}
    if isinstance(model, str):
        return build_model(model, opts, builder=lambda cls, o: _build(cls, o, "model"))
    return _build(model, opts, "model")


def make_optimizer(cls: type, options: Mapping[str, Any] | None = None, *, pop: int | None = None,
                   iters: int | None = None):
    """Instantiate a registered optimizer; ``pop``/``iters`` apply where the optimizer has them."""
    opts = dict(options or {})
    names = {f.name for f in dataclasses.fields(cls)}
    for key, val in (("pop", pop), ("iters", iters)):
        if val is None:
            continue
        if key not in names:
            raise ConfigError(f"--{key} does not apply to optimizer {cls.name!r}")
        if val < 1:
            raise ConfigError(f"--{key} must be a positive integer, got {val}")
        opts[key] = val
    return _build(cls, opts, "optimizer")
