"""The model interface.

A model is *structure plus a pure kernel*: a frozen dataclass holds the structure (for PI the
number of operators and their thresholds), :meth:`Model.params` gives the parameter table for
a data scale, and :meth:`Model.simulate` maps a whole population of parameter vectors to
outputs at once::

    theta (P, d), u (N,) [V], dt [s]  →  y (P, N) [output unit]

The state is reset at the start of every call (one call per capture). Fitted values never live
on the model: an identification returns them (:class:`hystfit.identify.ConditionFit`), a parameter
file reads them back (:class:`hystfit.results.Cell`).
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from typing import Any, Callable, ClassVar

import numpy as np

from .._jit import readonly
from ..errors import ConfigError
from ..params import DataScale, Param, structure_kwargs, structure_of
from .inverse import invert_by_stepping


class Model(ABC):
    """Base class of every hysteresis model (subclasses are frozen dataclasses)."""

    name: ClassVar[str] = ""
    title: ClassVar[str] = ""
    reference: ClassVar[str] = ""
    equation: ClassVar[str] = ""
    rate_dependent: ClassVar[bool] = False
    #: the state after a first sample u0 from the virgin state is the state after any monotone ramp
    #: 0 → u0 (play and stop operators: PI, GPI), so a pre-roll need not ramp (:func:`hystfit.invert.preroll_voltage`)
    first_sample_is_a_ramp: ClassVar[bool] = False
    #: the structure option that sets the model's resolution (e.g. the number of play operators),
    #: or None; :meth:`refined` doubles it
    resolution_option: ClassVar[str | None] = None

    # ----------------------------------------------------------------- structure
    def adapt(self, scale: DataScale) -> "Model":
        """Fill data-dependent structure (e.g. PI thresholds) from the identification data.

        The default has none and returns ``self``. Called once per fit; the adapted model is
        what gets saved, so predictions on other captures use the same structure.
        """
        return self

    def prepare(self, captures) -> "Model":
        """Identify structure that is shared by every operating condition, from all captures.

        Called once by :func:`hystfit.identify.identify` and :func:`hystfit.compare.compare`
        before the per-condition fits (e.g. the stage's linear dynamics of a Hammerstein model,
        which do not change with amplitude or frequency). The default has none and returns
        ``self``; a model whose shared structure is already set also returns ``self``.
        """
        return self

    def shares_structure(self) -> bool:
        """Whether :meth:`prepare` may identify shared structure (the model's class overrides it):
        ``compare`` runs the cells of the models without any while it prepares the others."""
        return type(self).prepare is not Model.prepare

    def structure(self) -> dict[str, Any]:
        """JSON-serialisable constructor arguments (the inverse of :meth:`from_structure`)."""
        return structure_of(self)

    def as_options(self) -> dict[str, Any]:
        """The structure as ``--model-option`` keys: ``make_model(self.name, self.as_options())``
        rebuilds this model (a composite adds ``BLOCK.FIELD`` keys)."""
        return self.structure()

    @classmethod
    def from_structure(cls, data: dict[str, Any]) -> "Model":
        return cls(**structure_kwargs(cls, data, lambda unknown, names: (
            f"model {cls.name!r}: unknown structure field(s) {sorted(unknown)}")))

    # ----------------------------------------------------------------- parameters
    @abstractmethod
    def params(self, scale: DataScale) -> tuple[Param, ...]:
        """Parameter table with bounds derived from ``scale``."""

    # ----------------------------------------------------------------- simulation
    @abstractmethod
    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        """Simulate a population: θ (P, d), u (N,) in V, dt in s → y (P, N)."""

    def simulator(self, u: np.ndarray, dt: float) -> Callable[[np.ndarray], np.ndarray]:
        """A closure ``theta (P, d) → y (P, N)`` for one capture.

        Models override this to precompute what does not depend on θ (e.g. PI play-operator
        outputs for fixed thresholds), so an optimizer's thousands of calls share the work.
        """
        u = readonly(u)
        return lambda theta: self.simulate(theta, u, dt)

    def sse_evaluator(self, u: np.ndarray, dt: float, y: np.ndarray) -> Callable[[np.ndarray], np.ndarray] | None:
        """A closure ``theta (P, d) → (P,)`` giving Σ_k (ŷ_k(θ) − y_k)² for one capture, or None.

        The identification objective (:class:`hystfit.objective.Objective`) uses it instead of
        simulating when a model can compute the sum of squared errors without materialising the
        (P, N) outputs: a fused kernel (Bouc–Wen), or an exact quadratic form when the output is
        linear in θ (see :func:`linear_sse_evaluator`). It must equal the simulated sum to
        rounding (the contract tests check it). The default, None, means: simulate.
        """
        return linear_sse_evaluator(self, u, dt, y)

    def natural_frequency_Hz(self, theta: np.ndarray) -> float | None:
        """The natural frequency f_n (Hz) of a second-order stage in the model for θ (d,), None
        without one (the default).

        A stage discretized by the bilinear transform exists only below the Nyquist frequency of
        the data it runs on; above it the simulation is NaN (a search scores such candidates
        +inf). Commands that simulate an identified model on other data (``simulate``) ask for
        it to refuse a too-low sample rate in words (:func:`hystfit.blocks.dynamics.check_below_nyquist`)
        instead of writing empty predictions.
        """
        return None

    def simulate_one(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        """Simulate a single parameter vector θ (d,) → y (N,)."""
        return self.simulate(np.atleast_2d(np.asarray(theta, float)), np.asarray(u, float), dt)[0]

    def head_simulator(self, u: np.ndarray, dt: float) -> Callable[[np.ndarray, int], np.ndarray]:
        """A closure ``(theta (d,), n) → y (n,)``: ``simulate_one(theta, u[:n], dt)``, the same bits,
        for many θ and a few lengths ``n`` of one input (a diagnosis re-simulates each capture's fit
        part and the whole capture after every step of every fit). Models override it to compute
        what does not depend on θ once, for the whole input (PI: the play operators; causal, so the
        first n rows are those of the input's first n samples). Default: simulate each time."""
        u = np.asarray(u, float)
        return lambda theta, n: self.simulate_one(theta, u[:n], dt)

    @property
    def composition(self) -> "tuple[Model, tuple] | None":
        """(base, blocks) for a composite model (:mod:`hystfit.models.composite`); None otherwise."""
        return None

    def nuisance_basis(self, n: int, dt: float) -> np.ndarray | None:
        """Per-capture regressors (n, k) whose coefficients are fitted anew for every capture and
        projected out of the identification residual (a composite with a ``drift`` block); None
        (the default) for none. See :class:`hystfit.objective.Objective`."""
        return None

    # ----------------------------------------------------------------- structure for exact solves
    def separable(self):
        """The model's separable structure (:class:`hystfit.models.separable.Separable`) or None.

        Models whose output is linear in some parameters for fixed others declare it here, so
        the ``auto`` optimizer solves those exactly and searches only the rest.
        """
        return None

    # ----------------------------------------------------------------- declared optional contracts
    @classmethod
    def example(cls, scale: DataScale) -> "Model":
        """A ready-to-simulate instance for ``scale`` (tests, docs). The default adapts the default
        structure; models whose structure is identified from data (e.g. hammerstein) override it."""
        return cls().adapt(scale)

    def structure_summary(self) -> str | None:
        """One line on how the shared structure was identified (reports), or None when there is none."""
        return None

    def refined(self) -> "Model | None":
        """The same model at twice its resolution (:attr:`resolution_option` doubled, at most 200),
        or None when it has no resolution option, the structure is fixed (explicit thresholds) or it
        is already at the maximum. ``diagnose`` uses it to tell the base's resolution from an
        unmodelled effect."""
        opt = self.resolution_option
        if opt is None or getattr(self, "thresholds_V", None) is not None:
            return None
        n = int(getattr(self, opt))
        return None if n >= 200 else dataclasses.replace(self, **{opt: min(2 * n, 200)})

    @property
    def starts_at_rest(self) -> bool:
        """Whether the model's state before a first sample u0 is a rest at u0 (every loop closed there:
        :attr:`hystfit.models.pi.PI.history` ``"relaxed"``) rather than a history from 0 V: an inverse's
        pre-roll then holds u0 instead of ramping to it (:func:`hystfit.invert.preroll_voltage`)."""
        return False

    # ----------------------------------------------------------------- stepping (for inverses)
    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        """Model memory (S,) before the first sample, for input ``u0`` (same reset as :meth:`simulate`)."""
        raise ConfigError(f"model {self.name!r} does not support per-sample stepping")

    def step(self, theta: np.ndarray, state: np.ndarray, u_prev: float, u_new: np.ndarray,
             dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Advance one sample from ``state`` for each candidate input ``u_new`` (C,).

        Returns the outputs (C,) at the new sample and the new states (C, S). Must agree with
        :meth:`simulate`: stepping a whole input sample by sample reproduces ``simulate``.
        The numerical inverse (:func:`hystfit.models.inverse.invert_by_stepping`) is built on it.
        """
        raise ConfigError(f"model {self.name!r} does not support per-sample stepping")

    # ----------------------------------------------------------------- inverse
    def invert(self, theta: np.ndarray, y_target: np.ndarray, dt: float,
               u_range: tuple[float, float] | None = None) -> np.ndarray:
        """Input voltage u (N,) whose simulated output follows ``y_target`` (N,).

        The default is the robust per-sample numerical inverse: at every sample the input is
        found by a bracketed search on the model's one-step map, with the model's memory
        carried along (:func:`hystfit.models.inverse.invert_by_stepping`). ``u_range`` bounds
        the search (default: a wide range around the identification data). Models with an
        analytic inverse override this.
        """
        return invert_by_stepping(self, np.asarray(theta, float).ravel(), np.asarray(y_target, float), dt,
                                  u_range=u_range)

    # ----------------------------------------------------------------- helpers
    @staticmethod
    def check_theta(theta: np.ndarray, d: int) -> np.ndarray:
        theta = np.atleast_2d(np.asarray(theta, dtype=np.float64))
        if theta.ndim != 2 or theta.shape[1] != d:
            raise ValueError(f"theta must have shape (P, {d}), got {theta.shape}")
        return theta


class OptionalOffset:
    """Mixin of a model whose last parameter, the output offset y0, is optional: the model
    declares the structure field ``offset: bool`` (with its own default) and
    :attr:`n_params_without_offset`; the check of the flag and :attr:`n_params` live here."""

    #: the number of parameters without the offset
    n_params_without_offset: ClassVar[int] = 0

    def check_offset(self) -> None:
        if not isinstance(self.offset, bool):
            raise ConfigError(f"{self.name}: offset must be true or false, got {self.offset!r}")

    @property
    def n_params(self) -> int:
        return self.n_params_without_offset + (1 if self.offset else 0)


def linear_sse_evaluator(model: Model, u: np.ndarray, dt: float, y: np.ndarray):
    """Σ(ŷ − y)² as an exact quadratic form when the model's output is linear in all of θ.

    Applies when ``model.separable()`` declares every parameter linear (PI with fixed thresholds,
    Hammerstein with a fixed linear part): ŷ = C + B·θ with a basis B (N, d) that does not
    depend on θ. With θ* ≈ the least-squares solution (from the normal equations, so B is never
    copied: a 10⁶-sample capture needs one (N, d) basis in memory) and r* = y − C − Bθ*,
    Σ(ŷ − y)² = ‖r*‖² − 2δᵀBᵀr* + δᵀ BᵀB δ with δ = θ − θ*, exactly for any θ* (Bᵀr* ≈ 0 is
    kept, not assumed), so a population costs O(P·d²) instead of O(P·N·d) — and the form is
    centred on θ*, so there is no cancellation between large terms near the optimum. Returns None
    for any other model.
    """
    sep = model.separable()
    if sep is None or len(sep.nonlinear) != 0:
        return None
    d = len(sep.linear)
    B = sep.basis_factory(readonly(u), dt)(np.empty((1, 0)))
    C = None
    if isinstance(B, tuple):
        B, C = B
    B = np.asarray(B, dtype=np.float64)[0]  # (N, d)
    target = np.asarray(y, dtype=np.float64) - (0.0 if C is None else np.asarray(C, dtype=np.float64)[0])
    if B.ndim != 2 or B.shape[1] != d or not (np.all(np.isfinite(B)) and np.all(np.isfinite(target))):
        return None
    G = B.T @ B
    c = B.T @ target
    scale = np.sqrt(np.maximum(np.diag(G), 1e-300))  # equilibrate before solving
    Gs = G / np.outer(scale, scale)
    theta_star = np.linalg.lstsq(Gs, c / scale, rcond=None)[0] / scale
    r = target - B @ theta_star
    sse_min = float(r @ r)
    g = B.T @ r  # ≈ 0: the residual of the normal equations, kept so the form is exact
    del B, r
    order = np.asarray(sep.linear, dtype=int)

    def sse(theta: np.ndarray) -> np.ndarray:
        delta = np.atleast_2d(theta)[:, order] - theta_star
        with np.errstate(all="ignore"):
            return sse_min - 2.0 * (delta @ g) + np.einsum("pi,ij,pj->p", delta, G, delta)

    return sse
