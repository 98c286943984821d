"""Composite models: a base hysteresis model followed by blocks, written ``BASE+BLOCK+...``.

``pi+creep+delay`` is the classical PI model whose output passes through the ``creep`` block and
then the ``delay`` block (:mod:`hystfit.blocks`); every registered model can be the base and
every registered block can follow it, in the written order, each at most once. A composite is a
:class:`~hystfit.models.base.Model` like any other: ``identify``, ``simulate``, ``invert``,
``track``, ``compare`` and ``diagnose`` accept the expression wherever they accept a model name.

Parameter vector: the base's parameters, then each block's, prefixed with the block's name
(``creep.c0``, ``dynamics.fn_Hz``, ``delay.delay_s``, ``asymmetry.a2``), so ``--bounds
dynamics.fn_Hz=300:3000`` addresses one. Options: ``--model-option KEY=VALUE`` sets a base
structure field, ``--model-option BLOCK.KEY=VALUE`` a block's (e.g. ``creep.tau_s=[0.01,0.1]``).

Nuisance blocks (``drift``) have no parameters: the identification objective projects their
per-capture regressors out of every capture's residual (:meth:`Composite.nuisance_basis`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable, Mapping

import numpy as np

from ..blocks.base import Block
from ..errors import ConfigError
from ..params import DataScale, Param, with_output_unit
from .. import registry
from .base import Model
from .separable import Separable

SEPARATOR = "+"

#: a placeholder scale for reading parameter names and units (never bounds) off a block
_UNIT_SCALE = DataScale(u_min=0.0, u_max=1.0, y_min=0.0, y_max=1.0, dt=1e-4, rate_max=1.0, duration_s=1.0)


@dataclass(frozen=True)
class Composite(Model):
    """A base hysteresis model followed by blocks (see the module docstring).

    Attributes
    ----------
    base : the hysteresis model (any registered model).
    blocks : the blocks, in the order the signal passes through them.

    Simulation: y = B_k[… B_1[H_θb[u]]] for a whole population; each block maps (P, N) → (P, N).
    Inverse (feedforward): the blocks are inverted in reverse order, then the base
    (:meth:`invert`). Stepping (closed loop): the base's and every block's one-sample maps.
    """

    base: Model
    blocks: tuple[Block, ...] = ()

    def __post_init__(self) -> None:
        if isinstance(self.base, Composite):
            raise ConfigError("a composite's base must be a hysteresis model, not another composite")
        names = [b.name for b in self.blocks]
        if len(set(names)) != len(names):
            raise ConfigError(f"model expression {self.name!r}: each block may appear once")
        object.__setattr__(self, "blocks", tuple(self.blocks))

    # ------------------------------------------------------------------ identity
    @property  # type: ignore[override]
    def name(self) -> str:
        return SEPARATOR.join([self.base.name] + [b.name for b in self.blocks])

    @property  # type: ignore[override]
    def title(self) -> str:
        return " → ".join([self.base.title] + [b.title for b in self.blocks])

    @property  # type: ignore[override]
    def reference(self) -> str:
        return "; ".join([self.base.reference] + [f"{b.name}: {b.reference}" for b in self.blocks])

    @property  # type: ignore[override]
    def equation(self) -> str:
        return "; ".join([f"x = {self.base.equation}"] + [f"{b.name}: {b.equation}" for b in self.blocks])

    @property  # type: ignore[override]
    def rate_dependent(self) -> bool:
        return self.base.rate_dependent or any(b.name in ("dynamics", "delay", "creep") for b in self.blocks)

    @property
    def composition(self) -> tuple[Model, tuple[Block, ...]]:
        return self.base, self.blocks

    # ------------------------------------------------------------------ structure
    def adapt(self, scale: DataScale) -> "Composite":
        return replace(self, base=self.base.adapt(scale), blocks=tuple(b.adapt(scale) for b in self.blocks))

    def prepare(self, captures) -> "Composite":
        return replace(self, base=self.base.prepare(captures), blocks=tuple(b.prepare(captures) for b in self.blocks))

    def shares_structure(self) -> bool:
        return self.base.shares_structure() or any(b.shares_structure() for b in self.blocks)

    def structure_summary(self) -> str:
        """How the shared structure was found (the base's, if it has any) and the block chain."""
        summary = self.base.structure_summary()
        chain = " → ".join(b.name for b in self.blocks)
        return f"{summary}; then {chain}" if summary is not None else f"{self.base.name} followed by {chain}"

    def refined(self) -> "Composite | None":
        """The composite with its base at twice the resolution (:meth:`Model.refined`), or None."""
        base = self.base.refined()
        return None if base is None else replace(self, base=base)

    def describe_blocks(self, theta: np.ndarray, unit: str) -> list[dict[str, Any]]:
        """Per block: name, structure and parameter values (units in the names) for params.json."""
        _, parts = self.split(np.asarray(theta, dtype=np.float64).ravel()[None, :])
        out = []
        for b, th in zip(self.blocks, parts):
            ps = b.params(_UNIT_SCALE)
            out.append({"name": b.name, "title": b.title, "equation": b.equation, "structure": b.structure(),
                        "parameters": {f"{p.name}_{with_output_unit(p.unit, unit)}" if p.unit not in ("1", "")
                                       and not p.name.endswith(("_s", "_Hz")) else p.name: float(v)
                                       for p, v in zip(ps, th[0])}})
        return out

    def structure(self) -> dict[str, Any]:
        return {"base": self.base.structure(), "blocks": [{"name": b.name, **b.structure()} for b in self.blocks]}

    def as_options(self) -> dict[str, Any]:
        out = dict(self.base.structure())
        for b in self.blocks:
            out.update({f"{b.name}.{k}": v for k, v in b.structure().items()})
        return out

    @classmethod
    def from_structure(cls, data: dict[str, Any]) -> "Model":  # pragma: no cover - use model_from_structure
        raise ConfigError("a composite is rebuilt from its expression: use hystfit.models.composite.model_from_structure")

    # ------------------------------------------------------------------ parameters
    def _sizes(self, scale: DataScale | None = None) -> list[int]:
        # per instance, once (the blocks are frozen): split() runs twice per sample when a loop is
        # stepped (track), and each block's n_theta builds its search bounds
        cache = self.__dict__.setdefault("_cache", {})
        if "sizes" not in cache:
            cache["sizes"] = [b.n_theta for b in self.blocks]
        return cache["sizes"]

    def split(self, theta: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        """θ (P, d) → base part (P, d_b) and one (P, k_i) part per block."""
        theta = np.atleast_2d(np.asarray(theta, dtype=np.float64))
        sizes = self._sizes()
        d_b = theta.shape[1] - sum(sizes)
        parts, start = [], d_b
        for k in sizes:
            parts.append(theta[:, start:start + k])
            start += k
        return theta[:, :d_b], parts

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        out = list(self.base.params(scale))
        for b in self.blocks:
            out += [replace(p, name=f"{b.name}.{p.name}") for p in b.params(scale)]
        return tuple(out)

    def natural_frequency_Hz(self, theta: np.ndarray) -> float | None:
        """The base's stage f_n, else the first block's that has one (each block appears once)."""
        tb, parts = self.split(np.asarray(theta, dtype=np.float64).ravel()[None, :])
        found = [self.base.natural_frequency_Hz(tb[0])] + [b.natural_frequency_Hz(th[0])
                                                           for b, th in zip(self.blocks, parts)]
        return next((f for f in found if f is not None), None)

    # ------------------------------------------------------------------ simulation
    def _chain(self, x: np.ndarray, parts: list[np.ndarray], dt: float) -> np.ndarray:
        with np.errstate(all="ignore"):
            for b, th in zip(self.blocks, parts):
                x = b.apply_population(x, th, dt)
        return x

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        tb, parts = self.split(theta)
        return self._chain(self.base.simulate(tb, u, dt), parts, dt)

    def simulator(self, u: np.ndarray, dt: float) -> Callable[[np.ndarray], np.ndarray]:
        base_sim = self.base.simulator(u, dt)

        def sim(theta):
            tb, parts = self.split(theta)
            return self._chain(np.asarray(base_sim(tb), dtype=np.float64), parts, dt)

        return sim

    def sse_evaluator(self, u, dt, y):
        return None  # the chain needs the outputs; the objective simulates

    def separable(self):
        """The base's separable structure when every block is a nuisance (``pi+drift``), with the
        basis projected off the nuisance regressors (the same least-squares minimizer as the
        objective's projected residual); None otherwise (``auto`` then fits in stages)."""
        if any(not b.nuisance for b in self.blocks):
            return None
        sep = self.base.separable()
        if sep is None:
            return None
        def factory(u, dt):
            inner = sep.basis_factory(u, dt)
            Q = np.linalg.qr(self.nuisance_basis(len(u), dt))[0]

            def basis(theta_nl):
                out = inner(theta_nl)
                B, C = out if isinstance(out, tuple) else (out, None)
                B = np.asarray(B, dtype=np.float64)
                B = B - np.einsum("nk,pkl->pnl", Q, np.einsum("nk,pnl->pkl", Q, B))
                if C is None:
                    return B
                C = np.asarray(C, dtype=np.float64)
                return B, C - (C @ Q) @ Q.T

            return basis

        return Separable(sep.linear, sep.nonlinear, factory)

    def nuisance_basis(self, n: int, dt: float) -> np.ndarray | None:
        cols = [B for B in (b.nuisance_basis(n, dt) for b in self.blocks) if B is not None]
        return np.hstack(cols) if cols else None

    # ------------------------------------------------------------------ stepping
    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        tb, parts = self.split(np.asarray(theta, dtype=np.float64).ravel()[None, :])
        states = [np.asarray(self.base.initial_state(tb[0], u0, dt), dtype=np.float64)]
        x = float(self.base.simulate_one(tb[0], np.array([u0, u0]), dt)[0])
        for b, th in zip(self.blocks, parts):
            states.append(np.asarray(b.step_init(th[0], x, dt), dtype=np.float64))
            x = float(b.apply_population(np.array([[x, x]]), th, dt)[0, 0])
        return np.concatenate(states)

    def _state_sizes(self, theta: np.ndarray, dt: float) -> list[int]:
        """Each block's state size for θ (a delay's depends on it): per θ and dt, computed once (the
        stepping of a loop asks once per sample)."""
        theta = np.asarray(theta, dtype=np.float64).ravel()
        cache = self.__dict__.setdefault("_cache", {})
        key = ("state_sizes", theta.tobytes(), float(dt))
        if key not in cache:
            if len(cache) > 64:
                cache.clear()
            tb, parts = self.split(theta[None, :])
            cache[key] = [b.step_init(th[0], 0.0, dt).size for b, th in zip(self.blocks, parts)]
        return cache[key]

    def step(self, theta, state, u_prev, u_new, dt):
        theta = np.asarray(theta, dtype=np.float64).ravel()
        tb, parts = self.split(theta[None, :])
        state = np.asarray(state, dtype=np.float64)
        sizes = self._state_sizes(theta, dt)
        n_base = state.size - sum(sizes)
        x, base_states = self.base.step(tb[0], state[:n_base], u_prev, u_new, dt)
        new = [np.atleast_2d(base_states)]
        start = n_base
        for b, th, k in zip(self.blocks, parts, sizes):
            x, st = b.step(th[0], state[start:start + k], x, dt)
            new.append(np.asarray(st, dtype=np.float64).reshape(x.size, k))
            start += k
        return x, np.hstack(new)

    # ------------------------------------------------------------------ inverse
    def invert(self, theta: np.ndarray, y_target: np.ndarray, dt: float,
               u_range: tuple[float, float] | None = None) -> np.ndarray:
        """Input u (N,) for the target: the blocks inverted in reverse order, then the base.

        Each block's inverse is its own (:meth:`hystfit.blocks.base.Block.invert`): delay → time
        advance, dynamics → stable continuous-time inversion, creep → exact causal inverse filter,
        asymmetry → monotone static inverse, drift → none (a feedforward cannot know it).
        """
        theta = np.asarray(theta, dtype=np.float64).ravel()
        tb, parts = self.split(theta[None, :])
        x = np.asarray(y_target, dtype=np.float64)
        for b, th in zip(reversed(self.blocks), reversed(parts)):
            x = b.invert(th[0], x, dt)
        return self.base.invert(tb[0], x, dt, u_range=u_range)


# ----------------------------------------------------------------------------------------------
# Expressions
# ----------------------------------------------------------------------------------------------


def split_expression(expr: str) -> tuple[str, list[str]]:
    """``"pi+creep+delay"`` → ("pi", ["creep", "delay"]) (names stripped and lower-cased)."""
    parts = [p.strip().lower() for p in str(expr).split(SEPARATOR)]
    if not parts or not parts[0] or any(not p for p in parts):
        raise ConfigError(f"model expression {expr!r}: expected BASE[+BLOCK...], e.g. pi+creep+delay")
    return parts[0], parts[1:]


def build_model(expr: str, options: Mapping[str, Any] | None = None, *, builder=None) -> Model:
    """The model named by ``expr`` (a registered model name or ``BASE+BLOCK+...``) with options.

    ``options`` keys ``KEY`` go to the base model, ``BLOCK.KEY`` to that block. Unknown or repeated
    blocks, a block name as base and options of absent blocks are :class:`ConfigError` s that list
    the valid choices.
    """
    block_registry, model_registry = registry.blocks, registry.models  # looked up per call (swappable)
    base_name, block_names = split_expression(expr)
    if base_name in block_registry and base_name not in model_registry:
        raise ConfigError(f"model expression {expr!r}: {base_name!r} is a block; the expression starts with a "
                          f"hysteresis model ({', '.join(model_registry.names())})")
    base_cls = model_registry.get(base_name)
    seen = set()
    for n in block_names:
        if n not in block_registry:
            raise ConfigError(f"model expression {expr!r}: unknown block {n!r}; valid blocks: "
                              f"{', '.join(block_registry.names())}")
        if n in seen:
            raise ConfigError(f"model expression {expr!r}: block {n!r} appears twice; each block may appear once")
        seen.add(n)
    base_opts: dict[str, Any] = {}
    block_opts: dict[str, dict[str, Any]] = {n: {} for n in block_names}
    for key, val in dict(options or {}).items():
        head, dot, tail = str(key).partition(".")
        if dot:
            if head not in block_opts:
                raise ConfigError(f"--model-option {key}: no block {head!r} in {expr!r}"
                                  + (f" (blocks: {', '.join(block_names)})" if block_names else ""))
            block_opts[head][tail] = val
        else:
            base_opts[key] = val
    base = builder(base_cls, base_opts) if builder is not None else base_cls(**base_opts)
    if not block_names:
        return base
    blocks = tuple(block_registry.get(n).from_structure(block_opts[n]) for n in block_names)
    return Composite(base, blocks)


def model_from_structure(expr: str, structure: Mapping[str, Any]) -> Model:
    """Rebuild a saved model: ``expr`` as written in params.json, ``structure`` its ``model_structure``."""
    block_registry, model_registry = registry.blocks, registry.models  # looked up per call (swappable)
    base_name, block_names = split_expression(expr)
    if not block_names:
        return model_registry.get(base_name).from_structure(dict(structure))
    base = model_registry.get(base_name).from_structure(dict(structure["base"]))
    saved = list(structure.get("blocks", []))
    if [s.get("name") for s in saved] != block_names:
        raise ConfigError(f"model {expr!r}: the saved blocks {[s.get('name') for s in saved]} do not match the expression")
    blocks = tuple(block_registry.get(n).from_structure({k: v for k, v in s.items() if k != "name"})
                   for n, s in zip(block_names, saved))
    return Composite(base, blocks)
