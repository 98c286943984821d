"""Building models and optimizers from names and KEY=VALUE options (validated, with clear errors).

The model and optimizer packages are imported inside the functions on purpose: importing them
registers every model, block and optimizer (≈ 0.1 s), which ``hystfit --help`` and the input checks
that run before any fit need not pay. numba itself is imported only when a kernel first runs
(:class:`hystfit._jit.Kernel`).
"""

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


def budget_options(cls: type, *, pop: int | None = None, iters: int | None = None,
                   max_evals: int | None = None) -> dict[str, Any]:
    """The options that give optimizer ``cls`` the budget ``--pop`` × ``--iters`` (one rule for all).

    ``pop`` applies to population searches. ``iters`` sets the iteration count of those that have
    one; a population search without an iteration count (``ipso``) honours it as the evaluation
    budget ``max_evals = pop · iters`` (its own default ``pop`` if none is given), so that
    ``--iters`` means the same budget for every population search. ``max_evals`` (already chosen
    by the caller) makes that translation a conflict. Local solvers take neither flag.
    """
    from .optimizers.base import IteratedSearch

    out: dict[str, Any] = {}
    for key, val in (("pop", pop), ("iters", iters)):
        if val is None:
            continue
        if isinstance(val, bool) or not isinstance(val, int) or val < 1:
            raise ConfigError(f"--{key} must be a positive integer, got {val}")
        if not cls.takes_budget_flags():
            raise ConfigError(f"--{key} does not apply to optimizer {cls.name!r} (not a population search); "
                              f"bound it with --opt-option max_evals=N")
    if pop is not None:
        out["pop"] = pop
    if iters is not None:
        if issubclass(cls, IteratedSearch):
            out["iters"] = iters
        elif max_evals is not None:
            raise ConfigError(f"optimizer {cls.name!r} has no iteration count: --iters {iters} means "
                              f"max_evals = pop·iters, which conflicts with max_evals={max_evals}; give one of them")
        else:
            out["max_evals"] = (pop if pop is not None else cls.pop) * iters
    return out


def make_optimizer(cls: type, options: Mapping[str, Any] | None = None, *, pop: int | None = None,
                   iters: int | None = None):
    """Instantiate a registered optimizer from flat KEY=VALUE options (own settings and stop rules
    by name) and the ``--pop`` / ``--iters`` budget (:func:`budget_options`)."""
    opts = dict(options or {})
    opts.update(budget_options(cls, pop=pop, iters=iters, max_evals=opts.get("max_evals")))
    return cls.from_options(opts)


def model_option_names(expr: str) -> list[str]:
    """The ``--model-option`` keys the model ``expr`` accepts: its base's structure fields and, for
    a composite, ``BLOCK.FIELD`` for each of its blocks' fields."""
    from .models.composite import split_expression
    from .registry import blocks, models

    base, names = split_expression(expr)
    keys = [f.name for f in dataclasses.fields(models.get(base))]
    for n in names:
        if n in blocks:
            keys += [f"{n}.{f.name}" for f in dataclasses.fields(blocks.get(n))]
    return keys


def model_param_names(expr: str) -> list[str]:
    """The parameter names (for ``--bounds``) of the model ``expr``, on a reference data scale."""
    from .catalog import REFERENCE_SCALE

    m = make_model(expr).adapt(REFERENCE_SCALE)
    return [p.name for p in m.params(REFERENCE_SCALE)]
