"""Identification objectives: pooled mean squared error of a model over several captures.

Captures of one condition are *pooled*: each is simulated separately from a reset state (never
concatenated into one simulation) and the squared errors are summed over all samples.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .models.base import Model

#: candidates × samples evaluated per block; bounds the (P, N) working memory (~64 MB of float64).
BLOCK_ELEMENTS = 8_000_000


@dataclass(frozen=True)
class Series:
    """One capture as the objective sees it: input (V), measured output, sample period (s).

    ``skip``: the first ``skip`` samples are simulated (they set the model's state) but not
    scored — a warm-up for a capture whose actuator state at the start is unknown (``--warmup``).
    """

    u: np.ndarray
    y: np.ndarray
    dt: float
    skip: int = 0

    def __post_init__(self) -> None:
        if not 0 <= int(self.skip) <= self.y.shape[0] - 2:
            raise ValueError(f"Series.skip {self.skip} must leave at least 2 of the {self.y.shape[0]} samples scored")


def _project(Y: np.ndarray, Q: np.ndarray, skip: int) -> np.ndarray:
    """The rows of Y (P, N) with the components of their scored part Y[:, skip:] in span(Q)
    removed (Q (N − skip, k) orthonormal); the warm-up part is left as it is."""
    Y = np.array(Y, dtype=np.float64, copy=True)
    S = Y[:, skip:]
    Y[:, skip:] = S - (S @ Q) @ Q.T
    return Y


def _projected(sim, Q: np.ndarray, skip: int):
    return lambda theta: _project(np.asarray(sim(theta), dtype=np.float64), Q, skip)


class ObjectiveFunction(ABC):
    """The contract between an objective and the optimizers: what an optimizer may ask of it.

    Required: ``__call__(θ (P, d)) → (P,)`` scores (mean squared error) of a population. Optional
    capabilities are *declared* here as ``None`` and provided by the objectives that have them, so an
    optimizer tests ``objective.residuals is not None`` instead of probing attributes:

    - ``model`` / ``series``: the model simulated and the captures scored (``auto`` uses the model's
      separable structure and composition);
    - ``residuals(θ (d,)) → (m,)`` with ``n_total`` = m, and ``jacobian(θ, upper=…, lower=…)``: least
      squares (the box sets each parameter's finite-difference step: :meth:`Objective._fd_population`);
    - ``normal_equations(θ, upper=…, lower=…)``: the fused JᵀJ, Jᵀr of long captures (the
      normal-equation LM).

    A plain callable is accepted wherever an objective is: :func:`as_objective` wraps it.
    """

    model: Model | None = None
    series: Sequence[Series] = ()
    n_total: int | None = None
    residuals = None
    jacobian = None
    normal_equations = None

    @abstractmethod
    def __call__(self, theta: np.ndarray) -> np.ndarray:
        """Scores (mean squared error) of a population θ (P, d) → (P,)."""


class CallableObjective(ObjectiveFunction):
    """A plain population function ``f(θ (P, d)) → (P,)`` with no optional capability."""

    def __init__(self, fn) -> None:
        self.fn = fn

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        return self.fn(theta)


def as_objective(f) -> ObjectiveFunction:
    """``f`` itself when it is an :class:`ObjectiveFunction`, else ``f`` wrapped as one."""
    return f if isinstance(f, ObjectiveFunction) else CallableObjective(f)


class Objective(ObjectiveFunction):
    """MSE(θ) = Σ_captures Σ_k (ŷ_k(θ) − y_k)² / Σ_captures N, for a whole population θ (P, d).

    ``residuals(θ)`` returns the concatenated residual vector of one candidate (for least
    squares). Non-finite simulations (a diverging parameter vector) score +inf, never raise.
    ``nfev`` counts candidate evaluations.

    Nuisance regressors: when the model declares per-capture regressors R_c
    (:meth:`hystfit.models.base.Model.nuisance_basis`, e.g. the ``drift`` block's offset and rate),
    every scored residual is projected onto the orthogonal complement of span(R_c) — the exact
    least-squares nuisance coefficients of each capture, for every candidate — so the objective is
    min_a Σ‖ŷ_c(θ) + R_c a_c − y_c‖². :meth:`predict` returns ŷ_c + R_c a_c with those coefficients.
    """

    def __init__(self, model: Model, series: Sequence[Series]) -> None:
        self.model = model
        self.series = list(series)
        raw = [model.simulator(s.u, s.dt) for s in self.series]
        self._raw_sims = raw
        self._Q: list[np.ndarray | None] = []
        for s in self.series:
            R = model.nuisance_basis(s.y.shape[0], s.dt)
            self._Q.append(None if R is None else np.linalg.qr(np.asarray(R, dtype=np.float64)[s.skip:])[0])
        self._sims = [sim if Q is None else _projected(sim, Q, s.skip) for sim, Q, s in zip(raw, self._Q, self.series)]
        # what the projected simulations are compared with (the original series without nuisance)
        self._scored = [s if Q is None else Series(s.u, _project(s.y[None, :], Q, s.skip)[0], s.dt, s.skip)
                        for s, Q in zip(self.series, self._Q)]
        # fused sums of squared errors where the model offers them (no (P, N) outputs in memory),
        # built at the first population scored: residual-only users (the polish, linearizations)
        # never pay their set-up
        self._sse_fns: list | None = None
        self._prefix_sse: list | None = None
        self.n_total = int(sum(s.y.shape[0] - s.skip for s in self.series))
        self.nfev = 0

    def _build_sse(self) -> None:
        model = self.model
        fns = [model.sse_evaluator(s.u, s.dt, s.y) if Q is None else None for s, Q in zip(self.series, self._Q)]
        # a warm-up is subtracted as the error of the prefix alone: exact for causal models (every
        # registered model; tests/contract check it), so fused kernels need no change
        prefix = [model.sse_evaluator(s.u[:s.skip], s.dt, s.y[:s.skip]) if s.skip and fn is not None else None
                  for s, fn in zip(self.series, fns)]
        self._prefix_sse, self._sse_fns = prefix, fns  # _sse_fns last: it marks both as built

    def _sse(self, theta: np.ndarray) -> np.ndarray:
        if self._sse_fns is None:
            self._build_sse()
        total = np.zeros(theta.shape[0])
        for sim, sse_fn, prefix, s in zip(self._sims, self._sse_fns, self._prefix_sse, self._scored):
            if sse_fn is not None:
                with np.errstate(all="ignore"):
                    total += sse_fn(theta)
                    if prefix is not None:
                        total -= prefix(theta)
                continue
            block = max(1, BLOCK_ELEMENTS // max(s.y.shape[0], 1))
            for i in range(0, theta.shape[0], block):
                with np.errstate(all="ignore"):
                    e = sim(theta[i:i + block])[:, s.skip:] - s.y[None, s.skip:]
                    total[i:i + block] += np.einsum("ij,ij->i", e, e)
        return total

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        theta = np.atleast_2d(np.asarray(theta, dtype=np.float64))
        self.nfev += theta.shape[0]
        # a sum of squares is ≥ 0; its quadratic form (less a skipped prefix's) can round below 0
        # at an exact fit of noiseless data (≈ −1e-26): 0 then, as the simulated sum would give
        mse = np.maximum(self._sse(theta), 0.0) / self.n_total
        return np.where(np.isfinite(mse), mse, np.inf)

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        theta = np.atleast_2d(np.asarray(theta, dtype=np.float64))
        self.nfev += 1
        with np.errstate(all="ignore"):
            return np.concatenate([sim(theta)[0][s.skip:] - s.y[s.skip:] for sim, s in zip(self._sims, self._scored)])

    def predict(self, theta: np.ndarray) -> list[np.ndarray]:
        """Per capture the prediction of ``theta`` (d,) — with the fitted nuisance terms, if any."""
        theta = np.atleast_2d(np.asarray(theta, dtype=np.float64))
        out = []
        for sim, s, Q in zip(self._raw_sims, self.series, self._Q):
            p = np.asarray(sim(theta)[0], dtype=np.float64)
            if Q is not None:
                p = p.copy()
                p[s.skip:] += Q @ (Q.T @ (s.y[s.skip:] - p[s.skip:]))
            out.append(p)
        return out

    def nuisance_coefficients(self, theta: np.ndarray) -> list[np.ndarray | None]:
        """Per capture the least-squares nuisance coefficients a_c over the scored samples (None
        without nuisance)."""
        theta = np.atleast_2d(np.asarray(theta, dtype=np.float64))
        out = []
        for sim, s in zip(self._raw_sims, self.series):
            R = self.model.nuisance_basis(s.y.shape[0], s.dt)
            if R is None:
                out.append(None)
                continue
            r = s.y - np.asarray(sim(theta)[0], dtype=np.float64)
            out.append(np.linalg.lstsq(R[s.skip:], r[s.skip:], rcond=None)[0])
        return out

    @staticmethod
    def _fd_population(theta: np.ndarray, rel_step: float, upper: np.ndarray | None,
                       lower: np.ndarray | None = None):
        """θ (d,) → (steps h (d,), population (d+1, d): θ and θ + h_j e_j).

        Step h_j = rel_step·max(|θ_j|, floor_j): with the box given (``lower`` and ``upper``) the floor
        is 1e-3 of each parameter's own width, else 1e-3·max|θ| — which lets the largest parameter
        set every step (an output offset of 5e6 nm made a step of 5e-3 for a parameter of 0.05: the
        Jacobian was wrong). With ``upper`` given, a step that would leave the box is taken
        backwards instead (a model need not be defined outside its bounds).
        """
        theta = np.asarray(theta, dtype=np.float64).ravel()
        d = theta.size
        if lower is not None and upper is not None:  # each parameter's floor from its own box
            floor = 1e-3 * (np.asarray(upper, dtype=np.float64) - np.asarray(lower, dtype=np.float64))
        else:
            floor = 1e-3 * (np.max(np.abs(theta)) + 1e-12)
        h = rel_step * np.maximum(np.abs(theta), floor)
        if upper is not None:
            h = np.where(theta + h > np.asarray(upper, dtype=np.float64), -h, h)
        pop = np.repeat(theta[None, :], d + 1, axis=0)
        pop[1:] += np.diag(h)
        return h, pop

    def _linear_jacobian(self) -> np.ndarray | None:
        """The Jacobian (M, d) of a model linear in every parameter (its :meth:`separable` has no
        nonlinear entry, e.g. ``pi``) without nuisance regressors: its basis, the same at every θ —
        made once and kept (read-only); None for any other model."""
        if not hasattr(self, "_linear_J"):
            self._linear_J = None
            sep = self.model.separable()
            if sep is not None and not sep.nonlinear and all(Q is None for Q in self._Q):
                parts = []
                for s in self.series:
                    B = sep.basis_factory(s.u, s.dt)(np.empty((1, 0)))
                    B = np.asarray(B[0] if isinstance(B, tuple) else B, dtype=np.float64)[0]
                    J = np.empty((B.shape[0] - s.skip, len(sep.linear)))
                    J[:, list(sep.linear)] = B[s.skip:]
                    parts.append(J)
                J = np.concatenate(parts, axis=0) if len(parts) > 1 else parts[0]
                J.flags.writeable = False
                self._linear_J = J
        return self._linear_J

    def jacobian(self, theta: np.ndarray, rel_step: float = 1e-6, upper: np.ndarray | None = None,
                 lower: np.ndarray | None = None) -> np.ndarray:
        """Jacobian of the residuals (M, d): for a model linear in every parameter its basis
        (:meth:`_linear_jacobian`, exact, made once: a linearization of an 80-operator PI cost 82
        simulations of every capture), else forward differences, all d+1 candidates in one
        population call per capture (steps as :meth:`_fd_population`)."""
        exact = self._linear_jacobian()
        if exact is not None:
            return exact
        h, pop = self._fd_population(theta, rel_step, upper, lower)
        out = np.empty((h.size, self.n_total))  # Jᵀ, filled capture by capture (no stacked copy of the simulations)
        col = 0
        with np.errstate(all="ignore"):
            for sim, s in zip(self._sims, self._scored):
                y = sim(pop)[:, s.skip:]
                part = out[:, col:col + y.shape[1]]
                np.subtract(y[1:], y[0], out=part)
                np.divide(part, h[:, None], out=part)
                col += y.shape[1]
        self.nfev += h.size + 1
        return out.T

    def normal_equations(self, theta: np.ndarray, rel_step: float = 1e-6,
                         upper: np.ndarray | None = None,
                         lower: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float, int]:
        """(JᵀJ (d, d), Jᵀr (d,), rᵀr, M) at θ without forming the (M, d) Jacobian or the (M,)
        residual vector: one pass, one capture at a time (its d + 1 candidates θ, θ + h_j e_j in one
        population call, steps as :meth:`_fd_population`), differences and products over time
        chunks, so the working memory is one capture's (d+1, N) simulation plus O(d·chunk).

        J is the forward-difference Jacobian of :meth:`jacobian` and r the residuals of
        :meth:`residuals` (r = ŷ(θ) − y): the bounded Levenberg–Marquardt route of
        :class:`hystfit.optimizers.lsq.LSQ` and the parameter standard errors need only these sums
        on a 10⁶-sample capture. Counts d + 1 evaluations. Non-finite simulations propagate
        (callers check).
        """
        h, pop = self._fd_population(theta, rel_step, upper, lower)
        d = h.size
        JtJ = np.zeros((d, d))
        Jtr = np.zeros(d)
        rr = 0.0
        chunk = 1 << 16
        for sim, s in zip(self._sims, self._scored):
            with np.errstate(all="ignore"):
                Y = np.asarray(sim(pop), dtype=np.float64)[:, s.skip:]  # (d+1, N − skip)
                y = s.y[s.skip:]
                for a in range(0, Y.shape[1], chunk):  # differences over time chunks: O(d·chunk) extra memory
                    r = Y[0, a:a + chunk] - y[a:a + chunk]
                    rr += float(r @ r)
                    D = (Y[1:, a:a + chunk] - Y[0, a:a + chunk]) / h[:, None]
                    JtJ += D @ D.T
                    Jtr += D @ r
            del Y
        self.nfev += d + 1
        return JtJ, Jtr, rr, self.n_total

    def normal_matrix(self, theta: np.ndarray, rel_step: float = 1e-6, upper: np.ndarray | None = None,
                      lower: np.ndarray | None = None) -> tuple[np.ndarray, float, int]:
        """(JᵀJ (d, d), rᵀr, M) at θ without forming the (M, d) Jacobian: one capture at a time,
        differences taken in place, so the working memory is one capture's (d+1, N) simulation
        (what parameter standard errors need on a 10⁶-sample capture). The first, third and fourth
        entries of :meth:`normal_equations`."""
        JtJ, _, rr, m = self.normal_equations(theta, rel_step, upper, lower)
        return JtJ, rr, m
