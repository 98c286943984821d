"""Candidate unmodelled effects: augmentations of any base hysteresis model, and how they are fitted.

Every effect is an operator on the *base prediction* ŷ (the output of whatever base model was
identified: PI, Bouc–Wen, …), so it works for any registered model::

    y ≈ E_φ,a[ŷ] = T_φ[ŷ] + R_φ(ŷ) · a

- ``T_φ`` is a linear operator on the base output (a stage filter, a delay; identity for the
  additive effects), with a few *searched* parameters φ (natural frequency and damping, delay);
- ``R_φ(ŷ)`` are regressors whose coefficients ``a`` enter linearly (creep gains, polynomial
  coefficients, drift offsets and rates): they are solved exactly.

Fitting is variable projection (Golub & Pereyra 1973): for each candidate φ, the linear
coefficients ``a`` — and, optionally, a Gauss–Newton step δ of the base model's own parameters —
come from one linear least-squares solve, so only φ (0–2 numbers) is searched. The base step uses
the base model's Jacobian J = ∂ŷ/∂θ pushed through the effect, ``y ≈ T_φ[ŷ + Jδ] + R a``: the
base is re-fitted *with* the effect instead of keeping the compromise it made without it (a PI
model fitted to a lagging stage widens its loops to mimic the lag; the effect can only remove the
lag if those loops may narrow again). For a model linear in its parameters (PI with fixed
thresholds) this is the exact joint optimum; otherwise one step of Gauss–Newton, which
:mod:`hystfit.diagnose` iterates and checks against a true re-simulation.

Units: time s, input V, output in the capture's unit (written ``out``, e.g. µm).
This module never prints and holds no state between calls.
"""

from __future__ import annotations

import math
import threading
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, replace
from typing import ClassVar, Sequence

import numpy as np

from ._jit import njit
from ._lazy import lazy_module
from .errors import ConfigError
from .registry import blocks as _blocks

# scipy submodules are imported on first use: keeps start-up fast
optimize = lazy_module("scipy.optimize")

__all__ = [
    "CaptureView",
    "EffectParam",
    "EffectFit",
    "Linearization",
    "Effect",
    "Placebo",
    "phase_surrogate",
    "surrogate_spectrum",
    "EFFECTS",
    "make_effect",
    "prepare_design",
    "scoring_design",
    "solve_coefficients",
    "signature_share",
]


# ----------------------------------------------------------------------------------------------
# Data the effects see
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class CaptureView:
    """One capture as the effects see it.

    Attributes
    ----------
    t : (N,) time from the start of the capture (s).
    dt : sample period (s).
    y : (N,) measured output (output unit).
    fit : (N,) bool, the samples used to fit (the rest is held out). Fitting only ever reads
        samples up to the last ``True`` one (every operator here is causal).
    frequency_Hz : excitation frequency of the capture (Hz), the loader's condition value.
    periodic : whether the input repeats with period 1/frequency_Hz.
    index : position of the capture in the data set (per-capture coefficients use it).
    u : (N,) the input (V), or None where the caller did not give it (an effect whose structure
        needs it then falls back, see :meth:`hystfit.blocks.asymmetry.Asymmetry.configure`).
    local : (N,) bool or None: samples that fit only this capture's own coefficients (an effect's
        per-capture ones, e.g. drift's offset and rate) while nothing shared is fitted on them —
        the first part of a capture the ``capture`` split holds out (``hystfit.diagnose``).
    """

    t: np.ndarray
    dt: float
    y: np.ndarray
    fit: np.ndarray
    frequency_Hz: float = float("nan")
    periodic: bool = False
    index: int = 0
    u: np.ndarray | None = None
    local: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(self.y.shape[0])

    @property
    def fit_end(self) -> int:
        """One past the last fitted sample: operators on ``[:fit_end]`` see all the fit data."""
        idx = np.flatnonzero(self.fit)
        return int(idx[-1]) + 1 if idx.size else 0

    def head(self, n: int) -> "CaptureView":
        """The first ``n`` samples (same sample period and flags)."""
        return replace(self, t=self.t[:n], y=self.y[:n], fit=self.fit[:n], u=None if self.u is None else self.u[:n],
                       local=None if self.local is None else self.local[:n])


@dataclass(frozen=True)
class EffectParam:
    """One parameter of an effect.

    ``kind`` is ``"searched"`` (nonlinear, found by a bounded search), ``"linear"`` (one
    coefficient for all captures, solved exactly), ``"per-capture"`` (one coefficient per
    capture, solved exactly) or ``"fixed"`` (set from the data, not fitted).
    """

    name: str
    unit: str
    kind: str
    description: str


#: A base with more step parameters than this is scored in the directions its fit samples determine
#: (:meth:`Linearization.reduced`) while an effect's searched parameters are sought; the final
#: solve uses every parameter. Up to it (a ten- or twenty-operator PI) scoring is exact as before.
REDUCE_ABOVE = 24
#: Relative eigenvalue below which a direction of the scaled Gram matrix counts as undetermined.
REDUCED_RTOL = 1e-8
#: A stage's search grid (an effect whose every φ filters the design's columns: no knots, no
#: regressors) is first ranked on every COARSE_STRIDE-th fit sample (:func:`coarse_design`) when
#: the fit samples number at least COARSE_MIN_ROWS; the best COARSE_KEEP_SHARE of the ranking (at
#: least COARSE_KEEP_MIN points) are then scored on every sample, and the search starts from the
#: best of those (:func:`ranked_on_rows`).
COARSE_STRIDE = 4
COARSE_MIN_ROWS = 8000
COARSE_KEEP_SHARE = 0.05
COARSE_KEEP_MIN = 4


@dataclass(frozen=True)
class Linearization:
    """The local linear model of the base (and of effects already added): ŷ(θ + δ) ≈ ŷ + J δ.

    Attributes
    ----------
    jac : per capture, (N_c, m_c) columns ∂ŷ_c/∂δ over the capture's first N_c samples
        (N_c ≥ the capture's ``fit_end``).
    cols : per capture, (m_c,) int indices of those columns in the step vector δ.
    lower, upper : (n,) bounds of δ (parameter bounds minus current values; ±inf when free).
    """

    jac: tuple[np.ndarray, ...]
    cols: tuple[np.ndarray, ...]
    lower: np.ndarray
    upper: np.ndarray

    @property
    def n(self) -> int:
        return int(self.lower.shape[0])

    def directions(self, views: Sequence["CaptureView"], rtol: float = REDUCED_RTOL) -> np.ndarray:
        """V (n, k): the directions of δ the fit samples determine (see :meth:`reduced`)."""
        M = np.zeros((self.n, self.n))
        for J, cols, v in zip(self.jac, self.cols, views):
            Jf = J[: v.fit_end][v.fit[: v.fit_end]]
            M[np.ix_(cols, cols)] += Jf.T @ Jf
        d = np.sqrt(np.maximum(np.diag(M), 0.0))
        d[d == 0] = 1.0
        w, U = np.linalg.eigh(M / np.outer(d, d))
        keep = w > rtol * max(float(w[-1]), 1e-300)
        return U[:, keep] / d[:, None]

    def reduced(self, views: Sequence["CaptureView"], rtol: float = REDUCED_RTOL,
                directions: np.ndarray | None = None) -> "Linearization":
        """The same linear model in the directions of δ the fit samples determine: δ = V z, with V
        the eigenvectors of the Jacobi-scaled Gram matrix Σ_c J_cᵀJ_c (fit samples) whose eigenvalues
        exceed ``rtol`` × the largest, unscaled (:meth:`directions`; ``directions``: V when already
        known). Every column operator of an effect is linear, so
        T_φ[J V] = T_φ[J] V: an *unbounded* least-squares fit in z reaches the SSE of the full one up
        to the dropped near-null directions (a fine PI base: 81 columns, 47 directions at 1e-8).
        The bounds become ±inf; for scoring candidates φ only, never for the final bounded solve."""
        V = self.directions(views, rtol) if directions is None else directions
        k = V.shape[1]
        jac = tuple(np.ascontiguousarray(J @ V[cols]) for J, cols in zip(self.jac, self.cols))
        return Linearization(jac, tuple(np.arange(k) for _ in self.cols), np.full(k, -np.inf), np.full(k, np.inf))


@dataclass(frozen=True)
class EffectFit:
    """A fitted effect: its searched parameters φ and linear coefficients.

    Attributes
    ----------
    effect : the (configured) effect.
    phi : (m,) searched parameters, in the order of ``effect.searched_params()``.
    shared : (k_s,) coefficients common to all captures.
    local : (C, k_l) per-capture coefficients.
    delta : (n,) step of the linearized parameters (base model, earlier effects); empty when the
        base was held fixed.
    sse : residual sum of squares on the fit samples predicted by the linear model (out²).
    evaluations : number of distinct candidates φ evaluated.
    """

    effect: "Effect"
    phi: np.ndarray
    shared: np.ndarray
    local: np.ndarray
    delta: np.ndarray
    sse: float
    evaluations: int = 0

    def apply(self, yhat: np.ndarray, view: CaptureView, index: int) -> np.ndarray:
        """The augmented prediction E[ŷ] of capture ``index``."""
        return self.effect.apply(yhat, view, self.phi, self.shared, self.local[index])

    def tangent(self, x: np.ndarray, yhat: np.ndarray, view: CaptureView, index: int) -> np.ndarray:
        """∂E/∂ŷ applied to the columns of ``x`` (N, m)."""
        return self.effect.tangent(x, yhat, view, self.phi, self.shared, self.local[index])

    def params(self, views: Sequence[CaptureView], sources: Sequence[str] | None = None) -> dict:
        """Named parameters with units (see :meth:`Effect.describe`)."""
        return self.effect.describe(self.phi, self.shared, self.local, views, sources)

    @property
    def n_parameters(self) -> int:
        return int(self.phi.size + self.shared.size + self.local.size)


# ----------------------------------------------------------------------------------------------
# Signal operators (pure)
# ----------------------------------------------------------------------------------------------


def _as_cols(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    return x[:, None] if x.ndim == 1 else x


def surrogate_spectrum(x: np.ndarray) -> np.ndarray:
    """The spectrum of every column of ``x`` (N, m) that :func:`phase_surrogate` randomizes."""
    return np.fft.rfft(_as_cols(np.asarray(x, dtype=np.float64)), axis=0)


@njit(cache=True)
def _unit_phasors(r):
    """e^{2πi r} for every element of r (F, q): cos and sin of 2πr, the numbers of ``np.exp(2j·π·r)``
    without its complex multiply and exponential."""
    F, q = r.shape
    out = np.empty((F, q), np.complex128)
    for i in range(F):
        for j in range(q):
            t = 2.0 * math.pi * r[i, j]
            out[i, j] = complex(math.cos(t), math.sin(t))
    return out


def _random_phases(X: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """X (a spectrum of ``n`` samples per column) with uniformly random phases, DC and Nyquist kept."""
    ph = _unit_phasors(rng.random(X.shape))
    ph[0] = 1.0
    if n % 2 == 0:
        ph[-1] = 1.0
    return X * ph


def phase_surrogate(x: np.ndarray, rng: np.random.Generator, spectrum: np.ndarray | None = None) -> np.ndarray:
    """Phase-randomized surrogate of every column of ``x`` (N, m): the same amplitude spectrum
    (hence the same RMS and smoothness), uniformly random phases (DC and Nyquist kept).
    ``spectrum``: ``surrogate_spectrum(x)`` when it is already known (many surrogates of one ``x``)."""
    x = _as_cols(np.asarray(x, dtype=np.float64))
    n = x.shape[0]
    X = surrogate_spectrum(x) if spectrum is None else spectrum
    return np.fft.irfft(_random_phases(X, n, rng), n=n, axis=0)


# ----------------------------------------------------------------------------------------------
# The effect interface
# ----------------------------------------------------------------------------------------------


class Effect(ABC):
    """An augmentation E_φ,a of a base model's output ŷ (see the module docstring).

    Subclasses are frozen dataclasses. Data-dependent settings (search ranges, time constants,
    normalisation) are filled by :meth:`configure` from the fit data, which returns a new
    instance; nothing is stored after a fit (results live in :class:`EffectFit`).
    """

    name: ClassVar[str] = ""
    title: ClassVar[str] = ""
    equation: ClassVar[str] = ""

    # ------------------------------------------------------------------ structure
    def configure(self, views: Sequence[CaptureView], yhats: Sequence[np.ndarray]) -> "Effect":
        """Fill data-dependent settings from the fit data (default: none)."""
        return self

    def param_table(self) -> tuple[EffectParam, ...]:
        """Every parameter, with unit and kind."""
        return ()

    def searched_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of the searched parameters φ: (lower (m,), upper (m,)); m = 0 when none."""
        return np.empty(0), np.empty(0)

    def search_grid(self) -> np.ndarray:
        """Start candidates for φ, (G, m). The default for m = 0 is one empty candidate."""
        return np.empty((1, 0))

    def layout(self) -> tuple[int, int]:
        """(k_s, k_l): number of shared and of per-capture linear coefficients."""
        return 0, 0

    def coefficient_bounds(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Bounds of (shared lower, shared upper, local lower, local upper); default unbounded."""
        ks, kl = self.layout()
        return (np.full(ks, -np.inf), np.full(ks, np.inf), np.full(kl, -np.inf), np.full(kl, np.inf))

    def n_parameters(self, n_captures: int) -> int:
        """Number of fitted parameters for ``n_captures`` captures (searched + linear)."""
        ks, kl = self.layout()
        return int(self.searched_bounds()[0].size + ks + kl * n_captures)

    # ------------------------------------------------------------------ the operator
    def operator(self, x: np.ndarray, view: CaptureView, phi: np.ndarray) -> np.ndarray:
        """T_φ applied to the columns of ``x`` (N, m) (identity by default)."""
        return x

    def operator_rows(self, x: np.ndarray, view: CaptureView, phi: np.ndarray, rows: np.ndarray, out: np.ndarray,
                      offset: int) -> None:
        """:meth:`operator` of ``x`` at the sorted ``rows`` only, written into
        ``out[offset : offset + len(rows)]``: what :func:`solve_coefficients` forms its Gram products
        from. By default the whole output, then those rows; an operator that need not form the
        other rows overrides it with the same numbers (the stage's filter). ``out`` may have more
        columns than ``x``: those after the first ``x.shape[1]`` are left as they are."""
        out[offset:offset + rows.shape[0], :x.shape[1]] = self.operator(x, view, phi)[rows]

    def operator_knots(self, phi: np.ndarray, view: CaptureView) -> tuple | None:
        """T_φ as an interpolation between two operators that many φ share: (a, b, f) with
        T_φ = (1 − f)·B_a + f·B_b, f in [0, 1), B_key = :meth:`knot_operator` — or None (the default)
        when T_φ is not of that form. :func:`solve_coefficients` then forms the Gram products of
        T_φ[X] from those of B_a[X] and B_b[X], computed once per design instead of once per φ."""
        return None

    def knot_operator(self, x: np.ndarray, view: CaptureView, key) -> np.ndarray:
        """B_key applied to the columns of ``x`` (N, m), for the keys of :meth:`operator_knots`
        (default: the key is a φ, B_key = T_key)."""
        return self.operator(x, view, np.atleast_1d(np.asarray(key, float)))

    def regressors(self, yhat: np.ndarray, view: CaptureView, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """R_φ(ŷ): (N, k_s) shared and (N, k_l) per-capture regressors (default: none)."""
        N = yhat.shape[0]
        ks, kl = self.layout()
        return np.zeros((N, ks)), np.zeros((N, kl))

    def apply(self, yhat: np.ndarray, view: CaptureView, phi: np.ndarray, shared: np.ndarray,
              local: np.ndarray) -> np.ndarray:
        """E[ŷ] = T_φ[ŷ] + R_s a_s + R_l a_l for one capture; (N,)."""
        out = self.operator(yhat[:, None], view, phi)[:, 0]
        Rs, Rl = self.regressors(yhat, view, phi)
        if Rs.shape[1]:
            out = out + Rs @ shared
        if Rl.shape[1]:
            out = out + Rl @ local
        return out

    def tangent(self, x: np.ndarray, yhat: np.ndarray, view: CaptureView, phi: np.ndarray, shared: np.ndarray,
                local: np.ndarray) -> np.ndarray:
        """∂E/∂ŷ applied to the columns of ``x`` (N, m); equals :meth:`operator` for effects linear in ŷ."""
        return self.operator(x, view, phi)

    # ------------------------------------------------------------------ evidence
    def signature(self, yhat: np.ndarray, view: CaptureView) -> tuple[np.ndarray, np.ndarray]:
        """First-order signature of the effect in the residual y − ŷ: (N, q_s) shared and (N, q_l)
        per-capture columns. A residual explained by these columns points to the effect."""
        return self.regressors(yhat, view, self.search_grid()[0])

    @abstractmethod
    def describe(self, phi: np.ndarray, shared: np.ndarray, local: np.ndarray, views: Sequence[CaptureView],
                 sources: Sequence[str] | None = None) -> dict:
        """Named parameter values with units in the names (and derived quantities)."""

    # ------------------------------------------------------------------ fitting
    def fit(self, yhats: Sequence[np.ndarray], views: Sequence[CaptureView], lin: Linearization | None = None, *,
            phi0: np.ndarray | None = None, local_search: bool = False, bounded: bool = True,
            design: "_Design | None" = None, grid_scores: np.ndarray | None = None) -> EffectFit:
        """Fit the effect to the measured outputs given the base predictions.

        Parameters
        ----------
        yhats : per capture, the base prediction ŷ_c (output unit), at least ``fit_end`` samples.
        views : the captures (:class:`CaptureView`); only fit samples are used.
        lin : the base's linearization; None holds the base output fixed.
        phi0 : a start for the search of φ (e.g. from a previous iteration).
        local_search : search only around ``phi0`` (no global grid).
        bounded : solve the final coefficients within their bounds (and δ within the base's).
        design : ``prepare_design(yhats, views, lin)`` when it is already made (shared by the
            effects fitted on one linearization: what they share is computed once).
        grid_scores : the :meth:`score` of every candidate of :meth:`search_grid` on
            ``scoring_design(design)`` when already known (computed in parallel); used without ``phi0``.

        Returns
        -------
        EffectFit
            φ minimizing the fit-sample SSE (coarse grid, then a polish in log space: L-BFGS-B on the
            exact gradient for an effect that filters the design's columns, :func:`_gradient_polish`;
            Nelder–Mead, or a bounded Brent search for one linear parameter, otherwise), with the
            linear coefficients (and base step) solved exactly for it.
        """
        lo, hi = self.searched_bounds()
        m = lo.size
        design = prepare_design(yhats, views, lin) if design is None else design
        scoring = scoring_design(design) if m > 0 else design
        seen: dict[bytes, float] = {}  # φ → score: the grid, the polish and its final comparison revisit points
        grid = None
        if grid_scores is not None and phi0 is None:
            # NaN: a grid point not scored (ranked out on a subsample of rows: :func:`ranked_on_rows`);
            # the search starts from the best of those scored
            g = np.asarray(grid_scores, float)
            grid = np.asarray(self.search_grid(), float)[~np.isnan(g)]
            seen.update((c.tobytes(), float(v)) for c, v in zip(grid, g[~np.isnan(g)]))

        def score(phi: np.ndarray) -> float:
            key = np.asarray(phi, float).tobytes()
            if key not in seen:
                seen[key] = self.score(phi, scoring)
            return seen[key]

        if m == 0:
            best = np.empty(0)
        else:
            gradient = filters_columns(self, scoring)  # polished on the SSE's gradient
            if not (local_search and phi0 is not None):
                cands = self.search_grid()
            elif gradient:  # the polish goes on from φ0 itself
                cands = np.empty((0, m))
            else:
                cands = _local_grid(phi0, lo, hi)
            if grid is not None:
                cands = grid
            if phi0 is not None:
                cands = np.vstack([cands, np.clip(np.asarray(phi0, float), lo, hi)[None, :]])
            scores = np.array([score(c) for c in cands])
            best = cands[int(np.argmin(scores))]
            if gradient:
                best = _gradient_polish(self, scoring, seen, best, lo, hi, self._log_scaled())
            else:
                best = _polish(score, best, lo, hi, self._log_scaled())
        shared, local, delta, sse = solve_coefficients(self, best, design=design, bounded=bounded)
        return EffectFit(self, np.asarray(best, float), shared, local, delta, float(sse), len(seen))

    def score(self, phi: np.ndarray, scoring: "_Design") -> float:
        """The fit-sample SSE of candidate φ on a :func:`scoring_design` (unbounded linear solve;
        +inf where φ is invalid): what the search of :meth:`fit` minimizes."""
        try:
            return solve_coefficients(self, phi, design=scoring, bounded=False)[3]
        except (ConfigError, np.linalg.LinAlgError, ValueError):
            return math.inf

    def widened(self, phi: np.ndarray) -> "Effect | None":
        """This effect with its search range reaching past the bound at which ``phi`` ended, when
        that bound is one the data's scale chose, not the physics (a stage's lowest f_n, twice the
        fastest drive) and can move — or None (the default: no such bound, or not at it). A fit
        that ends on such a bound did not find its optimum: :func:`hystfit.diagnose._augment`
        searches the wider range."""
        return None

    def handover_options(self, views: Sequence[CaptureView]) -> dict:
        """Structure options (``--model-option`` names of this block, without the block's prefix)
        that a model identified with this effect as a block needs to search where this effect was
        fitted: those of a range :meth:`widened` beyond what the block sets from ``views``'
        scale (default: none)."""
        return {}

    def absent_at(self, phi: np.ndarray) -> bool:
        """Whether searched parameters ``phi`` say the effect is not in the data although its refit
        gains (default: never). A stage whose f_n (or ζ) ends at the top of its search range has no
        resonance below it: what it fits there is a small lag, and naming a stage for it sends an
        engineer after the wrong fix (a blind test's 4.5 kHz, ζ 1.0 "stage" beside a delay)."""
        return False

    def _log_scaled(self) -> np.ndarray:
        """Which searched parameters are searched in log space (all positive scale parameters)."""
        lo, _ = self.searched_bounds()
        return lo > 0


def _local_grid(phi0: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """A small grid around φ0: ×/÷ 1.25 in log-scaled coordinates (±5 % of the range otherwise)."""
    phi0 = np.clip(np.asarray(phi0, float), lo, hi)
    axes = []
    for p, a, b in zip(phi0, lo, hi):
        if a > 0:
            axes.append(np.clip(p * np.array([0.8, 1.0, 1.25]), a, b))
        else:
            axes.append(np.clip(p + 0.05 * (b - a) * np.array([-1.0, 0.0, 1.0]), a, b))
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([g.ravel() for g in mesh], axis=1)


#: the most evaluations (each an SSE and its gradient) of :func:`_gradient_polish`
GRADIENT_POLISH_MAXFUN = 30
#: L-BFGS-B's tolerances in :func:`_gradient_polish`, on the SSE scaled by its value at the start: a
#: relative reduction per iteration, and the largest component of the projected gradient (per unit
#: of log φ) — the SSE within ≈ 1e-6 relative of its minimum, φ within ≈ 1e-4 relative (a
#: Nelder–Mead polish of 40 scores ends about as far: it never met its own tolerance)
GRADIENT_POLISH_FTOL = 1e-9
GRADIENT_POLISH_GTOL = 1e-4
#: the finite-difference step of the gradient's operator derivatives, in the search coordinates
#: (log φ where φ is log-scaled): the operator is smooth in φ, its columns differ by ≈ 1e-6 relative
GRADIENT_STEP = 1e-6


def _search_coordinates(lo: np.ndarray, hi: np.ndarray, logs: np.ndarray):
    """(to_z, from_z): φ → the coordinates a polish searches in (log φ where ``logs``) and back,
    clipped into [lo, hi]."""
    def to_z(x):
        return np.where(logs, np.log(np.maximum(x, 1e-300)), x)

    def from_z(z):
        return np.clip(np.where(logs, np.exp(z), z), lo, hi)

    return to_z, from_z


def _score_and_gradient(effect: "Effect", scoring: "_Design", z: np.ndarray, from_z, zlo: np.ndarray,
                        zhi: np.ndarray, rows: Sequence[np.ndarray]) -> tuple[float, np.ndarray]:
    """:meth:`Effect.score` at φ = from_z(z) and its gradient in z, for an effect whose operator
    filters the design's columns (:func:`filters_columns`).

    Variable projection: with δ the unbounded least-squares step at φ, the SSE's gradient is that
    of ‖y − T_φ[x]‖² at the fixed combination x = X·(1, δ) (the envelope theorem: ∂SSE/∂δ = 0 at
    δ), −2 rᵀ ∂T_φ[x]/∂z_i, r = y − T_φ[x] on the fit rows. ∂T_φ[x]/∂z_i is a central difference
    of the operator on that one column (:data:`GRADIENT_STEP`, one-sided at a bound): a gradient
    costs 1 + 2m filterings of one column per capture beside the score's filtering of every column."""
    phi = from_z(z)
    _, _, delta, sse = solve_coefficients(effect, phi, design=scoring, bounded=False)
    m = z.size
    pairs = []
    for i in range(m):
        up, down = z.copy(), z.copy()
        up[i], down[i] = min(z[i] + GRADIENT_STEP, zhi[i]), max(z[i] - GRADIENT_STEP, zlo[i])
        pairs.append((from_z(up), from_z(down), up[i] - down[i]))
    grad = np.zeros(m)
    for (c, _, y), at in zip(scoring.fitted, rows):
        X, view = scoring.X[c], scoring.views[c]
        x = X[:, 0] if X.shape[1] == 1 else X[:, 0] + X[:, 1:] @ delta[scoring.cols[c]]
        x = np.ascontiguousarray(x[:, None])
        t = np.empty((at.size, 1))
        effect.operator_rows(x, view, phi, at, t, 0)
        r = y - t[:, 0]
        for i, (p_up, p_down, dz) in enumerate(pairs):
            if dz <= 0:
                continue
            effect.operator_rows(x, view, p_up, at, t, 0)
            d = t[:, 0].copy()
            effect.operator_rows(x, view, p_down, at, t, 0)
            grad[i] -= 2.0 * float(r @ (d - t[:, 0])) / dz
    return float(sse), grad


def _gradient_polish(effect: "Effect", scoring: "_Design", seen: dict, x0: np.ndarray, lo: np.ndarray,
                     hi: np.ndarray, logs: np.ndarray, maxfun: int = GRADIENT_POLISH_MAXFUN) -> np.ndarray:
    """φ from ``x0`` by L-BFGS-B on the SSE and its exact gradient (:func:`_score_and_gradient`), in
    the coordinates of :func:`_search_coordinates` within the bounds: for an effect whose every φ
    filters the design's columns (a stage), where a Nelder–Mead polish spent ≈ 40 scores of every
    column on what a few scores with their gradients find. ``seen`` (φ → score) is the fit's
    cache: the scores computed here join it. The SSE is scaled by its value at ``x0`` (the
    tolerances are relative). Returns ``x0`` unless a φ with a lower score was found."""
    to_z, from_z = _search_coordinates(lo, hi, logs)
    zlo, zhi = to_z(lo), to_z(hi)
    rows = [np.arange(scoring.X[c].shape[0]) if mask is None else np.flatnonzero(mask)
            for c, mask, _ in scoring.fitted]
    x0 = np.asarray(x0, float)
    key0 = x0.tobytes()
    scale = None

    def fg(z):
        nonlocal scale
        try:
            f, g = _score_and_gradient(effect, scoring, np.asarray(z, float), from_z, zlo, zhi, rows)
        except (ConfigError, np.linalg.LinAlgError, ValueError):
            return math.inf, np.zeros(z.size)
        seen.setdefault(from_z(np.asarray(z, float)).tobytes(), f)
        if scale is None:
            scale = max(f, 1e-300)
        return f / scale, g / scale

    res = optimize.minimize(fg, to_z(x0), jac=True, method="L-BFGS-B", bounds=list(zip(zlo, zhi)),
                            options={"maxfun": maxfun, "ftol": GRADIENT_POLISH_FTOL, "gtol": GRADIENT_POLISH_GTOL})
    best = from_z(np.asarray(res.x, float))
    f_best = seen.get(best.tobytes())
    if f_best is None:
        f_best = effect.score(best, scoring)
        seen[best.tobytes()] = f_best
    f0 = seen.get(key0)
    if f0 is None:
        f0 = seen[key0] = effect.score(x0, scoring)
    return best if f_best <= f0 else x0


def _polish(score, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, logs: np.ndarray,
            maxfev: int = 40) -> np.ndarray:
    """Nelder–Mead from ``x0`` in a coordinate system where log-scaled parameters are logs;
    points outside the bounds are clipped (so the search never leaves the box)."""
    x0 = np.asarray(x0, float)
    if x0.size == 1 and not logs[0]:
        # one linear parameter: bounded Brent around the start
        span = 0.1 * (hi[0] - lo[0])
        a, b = max(lo[0], x0[0] - span), min(hi[0], x0[0] + span)
        if b <= a:
            return x0
        res = optimize.minimize_scalar(lambda v: score(np.array([v])), bounds=(a, b), method="bounded",
                                       options={"xatol": 1e-4 * (hi[0] - lo[0]), "maxiter": maxfev})
        return np.array([res.x]) if res.fun <= score(x0) else x0

    to_z, from_z = _search_coordinates(lo, hi, logs)
    z0 = to_z(x0)
    step = np.where(logs, 0.15, 0.05 * (hi - lo))
    simplex = np.vstack([z0] + [z0 + np.eye(x0.size)[i] * step[i] for i in range(x0.size)])
    res = optimize.minimize(lambda z: score(from_z(z)), z0, method="Nelder-Mead",
                            options={"initial_simplex": simplex, "maxfev": maxfev, "xatol": 1e-3, "fatol": 0.0})
    best = from_z(res.x)
    return best if score(best) <= score(x0) else x0


# ----------------------------------------------------------------------------------------------
# The exact linear solve (variable projection)
# ----------------------------------------------------------------------------------------------


#: the largest bounded solve :func:`_scaled_solve` gives BVLS (an exact active-set method, O(n³) per
#: step); beyond, trf
BVLS_MAX = 600


def _scaled_solve(G: np.ndarray, b: np.ndarray, lo: np.ndarray | None = None, hi: np.ndarray | None = None,
                  ridge: float = 1e-10) -> np.ndarray:
    """argmin xᵀGx − 2bᵀx (within [lo, hi] if given), on the Jacobi-scaled problem.

    Columns are scaled to unit norm and a relative ridge of 1e-10 is added, so collinear
    regressors (a per-capture offset next to the base model's offset, PI weights of thresholds
    the input never reaches) get a unique, small solution instead of a singular matrix.
    """
    n = b.shape[0]
    if n == 0:
        return np.empty(0)
    d = np.sqrt(np.maximum(np.diag(G), 0.0))
    d = np.where(d > 1e-12 * max(d.max(), 1e-300), d, 1.0)
    Gs = G / d[:, None] / d[None, :] + ridge * np.eye(n)
    bs = b / d
    try:
        z = np.linalg.solve(Gs, bs)
    except np.linalg.LinAlgError:
        z = np.linalg.lstsq(Gs, bs, rcond=None)[0]
    x = z / d
    if lo is None or (np.all(x >= lo) and np.all(x <= hi)):
        return x
    w, V = np.linalg.eigh(Gs)
    R = (V * np.sqrt(np.maximum(w, ridge))).T  # Gs = RᵀR
    q = np.linalg.lstsq(R.T, bs, rcond=None)[0]
    los, his = lo * d, hi * d
    # bvls: an exact active set; trf stopped short of the minimizer on a 160-operator base and was
    # accepted: the SSE jumped 77 → 138 between φ 10⁻⁵ apart (a blind stage at 2 kHz then went
    # unnamed; tests/unit/test_effects.py). trf only past BVLS_MAX, with room to converge
    if n <= BVLS_MAX:
        res = optimize.lsq_linear(R, q, bounds=(los, his), method="bvls", tol=1e-12)
    else:
        res = optimize.lsq_linear(R, q, bounds=(los, his), method="trf", tol=1e-12, max_iter=max(1000, 10 * n))
    z = res.x if res.status >= 0 else np.clip(z, los, his)
    return z / d


@dataclass(frozen=True, eq=False)
class _Design:
    """What every candidate φ of one fit shares: per capture the fit-part view, the stacked
    columns X = [ŷ | J] (C order: the operators run down time with the columns innermost, as the
    stage kernel and the delay's row slices want), y·y, and the column indices of the base step.

    ``compact`` (a :func:`scoring_design`'s): per capture None, or (Z, W) with fewer columns Z
    (N, r) than X's w and X = Z·W (:func:`_compact_columns`): an operator without knots then acts
    on Z, and the Gram products are W's transforms of Z's (:func:`_in_basis`)."""

    views: tuple
    X: tuple
    yy: tuple
    cols: tuple
    lin: Linearization | None
    indices: dict = field(default_factory=dict)  # (k_s, k_l) → per capture the index sets of the solve
    fitted: tuple = ()  # per capture: (fit mask, or None when every sample is fitted; y on the fit samples);
    #                     captures without a fit sample are left out
    index: dict = field(default_factory=dict)  # capture → its position in ``fitted``
    knots: dict = field(default_factory=dict)  # Gram products of the knot operators (:func:`_knot_gram`)
    plain: dict = field(default_factory=dict)  # capture → (X, XᵀX, Xᵀy) on its fit samples (:func:`_plain_gram`)
    derived: dict = field(default_factory=dict)  # designs made from this one (:func:`scoring_design`)
    compact: tuple = ()  # per capture None or (Z, W) with X = Z·W (empty: None for every capture)
    batches: dict = field(default_factory=dict)  # the captures summed in one Gram product (:func:`_batches`)


def _plain_gram(design: _Design, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(X, XᵀX, Xᵀy) over the fit samples of capture ``c``, X = [ŷ | J] untransformed: the part of the
    normal equations of every effect whose operator is the identity (creep, asymmetry, drift, the
    placebos) that none of them changes — computed once per design, not once per effect and φ."""
    if c not in design.plain:
        _, mask, y = design.fitted[design.index[c]]
        X = design.X[c] if mask is None else design.X[c][mask]
        design.plain[c] = (X, X.T @ X, X.T @ y)
    return design.plain[c]


def _regressor_gram(effect: "Effect", design: _Design, c: int, T: np.ndarray | None, Rs: np.ndarray, Rl: np.ndarray,
                    y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(AᵀA, Aᵀy) of A = [R_s | R_l | T] on the fit samples of capture ``c``; T = None: the effect's
    operator is the identity, T = X and its Gram block comes from :func:`_plain_gram`."""
    if T is not None:
        A = np.hstack([Rs, Rl, T])
        return A.T @ A, A.T @ y
    X, XX, Xy = _plain_gram(design, c)
    R = np.hstack([Rs, Rl])
    k = R.shape[1]
    P = np.empty((k + XX.shape[0], k + XX.shape[0]))  # [[RᵀR, RᵀX], [XᵀR, XᵀX]] (np.block: the same, slower)
    P[:k, :k] = R.T @ R
    P[:k, k:] = R.T @ X
    P[k:, :k] = P[:k, k:].T
    P[k:, k:] = XX
    return P, np.concatenate([R.T @ y, Xy])


def _knot_products(effect: "Effect", design: _Design, c: int, a, b) -> tuple:
    """(Q_a, B_a[X]ᵀy) and, for ``b`` not None, (Q_b, B_b[X]ᵀy, M_ab) of :func:`_knot_gram` over the
    fit samples of capture ``c``: each computed once per design and capture."""
    _, mask, y = design.fitted[design.index[c]]
    vv, X = design.views[c], design.X[c]
    cache = design.knots

    def rows(key):
        B = effect.knot_operator(X, vv, key)
        return B if mask is None else B[mask]

    shifted = getattr(type(effect), "knot_shift", None) is not None  # B_key = X delayed by key samples
    runs = _ShiftedRuns.of(design, c, X, mask, y) if shifted else None

    def gram(key):
        if (c, key) not in cache:
            if runs is not None:
                cache[(c, key)] = runs.gram(effect.knot_shift(key))
            else:
                B = rows(key)
                cache[(c, key)] = (B.T @ B, B.T @ y)
        return cache[(c, key)]

    Qa, ya = gram(a)
    if b is None:
        return Qa, ya
    Qb, yb = gram(b)
    if (c, a, b) not in cache:
        if runs is not None and effect.knot_shift(b) == effect.knot_shift(a) + 1:
            L = runs.lag_one(effect.knot_shift(a))  # B_aᵀB_b
            cache[(c, a, b)] = L + L.T
        else:
            mid = 0.5 * (rows(a) + rows(b))
            cache[(c, a, b)] = 4.0 * (mid.T @ mid) - Qa - Qb
    return Qa, ya, Qb, yb, cache[(c, a, b)]


def _knot_gram(effect: "Effect", design: _Design, members: Sequence[int], knots: tuple) -> tuple[np.ndarray, np.ndarray]:
    """(TᵀT, Tᵀy) summed over the fit samples of the captures ``members`` (whose knots are ``knots``),
    T = T_φ[X] = (1 − f)·B_a[X] + f·B_b[X] for the ``knots`` (a, b, f) of :meth:`Effect.operator_knots`:

        TᵀT = (1 − f)²·Q_a + f(1 − f)·M_ab + f²·Q_b,  Tᵀy = (1 − f)·B_a[X]ᵀy + f·B_b[X]ᵀy

    with Q_k = B_k[X]ᵀB_k[X] and M_ab = B_a[X]ᵀB_b[X] + B_b[X]ᵀB_a[X] = 4·Q_½ − Q_a − Q_b, Q_½ the Gram
    matrix of the midpoint ½(B_a[X] + B_b[X]). Each is computed once per design and capture
    (:func:`_knot_products`), and their sums over ``members`` once per design (a search then combines
    one set of products per φ, not one per capture). The same numbers as TᵀT up to rounding: a delay
    search visits a few whole-sample knots only."""
    a, b, f = knots
    members = tuple(members)
    if len(members) == 1:
        parts = _knot_products(effect, design, members[0], a, None if f == 0.0 else b)
    else:
        key = ("sum", members, a, None if f == 0.0 else b)
        if key not in design.knots:
            each = [_knot_products(effect, design, c, a, None if f == 0.0 else b) for c in members]
            design.knots[key] = tuple(sum(p[i] for p in each) for i in range(len(each[0])))
        parts = design.knots[key]
    if f == 0.0:
        return parts
    Qa, ya, Qb, yb, M = parts
    g = 1.0 - f
    return (g * g) * Qa + (f * g) * M + (f * f) * Qb, g * ya + f * yb


class _ShiftedRuns:
    """The Gram products of a capture's columns X (N, w) delayed by whole samples, over its fit
    samples, from the fit samples' own runs: B_n = X delayed by n samples (row k is X[max(k − n, 0)])
    restricted to a run [s, e) of fit samples reads X[s − n : e − n) (the first row held before the
    start), so B_nᵀB_n is the run's Gram X[s:e)ᵀX[s:e) less its last n rows' and plus the n rows'
    before it — O(n·w²) per delay instead of O(N·w²) (a 10⁶-sample capture's delay grid took 23 s of a
    116-s diagnosis). The same numbers as the products of the delayed rows up to rounding."""

    def __init__(self, X: np.ndarray, mask: np.ndarray | None, y: np.ndarray) -> None:
        N = X.shape[0]
        if mask is None:
            starts, stops = np.array([0]), np.array([N])
        else:
            edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
            starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        self.X, self.x0 = X, X[0]
        offsets = np.concatenate(([0], np.cumsum(stops - starts)))
        self.runs = [(int(s), int(e), y[int(o):int(o) + int(e - s)]) for s, e, o in zip(starts, stops, offsets)]
        self.G = [X[s:e].T @ X[s:e] for s, e, _ in self.runs]

    @classmethod
    def of(cls, design: "_Design", c: int, X: np.ndarray, mask, y) -> "_ShiftedRuns":
        key = ("runs", c)
        if key not in design.knots:
            design.knots[key] = cls(X, mask, y)
        return design.knots[key]

    def _window(self, a: int, b: int) -> np.ndarray:
        """X[j] for j in [a, b), with j < 0 read as X[0]."""
        if a >= 0:
            return self.X[a:b]
        lead = np.repeat(self.x0[None, :], min(b, 0) - a, axis=0)
        return np.vstack([lead, self.X[0:max(b, 0)]]) if b > 0 else lead

    def gram(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(B_nᵀB_n, B_nᵀy) over the fit samples."""
        w = self.X.shape[1]
        Q, v = np.zeros((w, w)), np.zeros(w)
        for (s, e, y), G in zip(self.runs, self.G):
            if n == 0:
                Q += G
                v += self.X[s:e].T @ y
                continue
            # rows [s − n, e − n) = the run's rows, less its last n, plus the n before it (a run
            # shorter than the delay: all of its rows less, the e − s before it plus)
            lost, gained = self.X[max(e - n, s):e], self._window(s - n, min(s, e - n))
            Q += G - lost.T @ lost + gained.T @ gained
            v += self._window(s - n, e - n).T @ y
        return Q, v

    def _pairs(self, a: int, b: int) -> np.ndarray:
        """Σ over j in [a, b) of X[j]·X[j − 1]ᵀ (indices below 0 read as 0)."""
        return self._window(a, b).T @ self._window(a - 1, b - 1)

    def lag_one(self, n: int) -> np.ndarray:
        """B_nᵀB_{n+1} over the fit samples: the run's lag-one products moved by n rows, as :meth:`gram`."""
        if not hasattr(self, "L1"):
            self.L1 = [self._pairs(s, e) for s, e, _ in self.runs]
        w = self.X.shape[1]
        L = np.zeros((w, w))
        for (s, e, _), L1 in zip(self.runs, self.L1):
            L += L1 - self._pairs(max(e - n, s), e) + self._pairs(s - n, min(s, e - n))
        return L


def _solve_indices(design: _Design, ks: int, kl: int) -> list[tuple]:
    """Per capture of ``design``, for ``ks`` shared and ``kl`` per-capture coefficients: the mesh of
    its columns in the normal equations (slices when they are consecutive) and, with regressors, the
    mesh and the rows of the columns other than t₀ in its Gram matrix [R | t₀ | TJ] (None without).
    The same for every φ: computed once."""
    key = (ks, kl)
    if key not in design.indices:
        # the same for every design of the same column layout (the designs a fit's true re-solves make,
        # one per step length, share it): made once per layout in this process
        C = len(design.views)
        layout = (ks, kl, C, design.lin is not None,
                  tuple((X.shape[1], None if b is None else np.asarray(b).tobytes())
                        for X, b in zip(design.X, design.cols)))
        if layout in _INDICES:
            design.indices[key] = _INDICES[layout]
            return design.indices[key]
        out = []
        for c, (X, bcols) in enumerate(zip(design.X, design.cols)):
            idx = [np.arange(ks), ks + c * kl + np.arange(kl)] if ks + kl else []
            if design.lin is not None:
                idx.append(ks + C * kl + bcols)
            ix = np.concatenate(idx).astype(int) if idx else np.empty(0, int)
            k = ks + kl
            sel = np.r_[0:k, k + 1:k + X.shape[1]] if k else None
            # a run of consecutive columns (a global base) is a slice: the same sums without fancy indexing
            run = ix.size > 0 and bool(np.all(np.diff(ix) == 1))
            at = slice(int(ix[0]), int(ix[-1]) + 1) if run else ix
            out.append(((at, at) if run else np.ix_(ix, ix), at, None if sel is None else np.ix_(sel, sel), sel))
        if len(_INDICES) >= 256:
            _INDICES.clear()
        design.indices[key] = _INDICES[layout] = out
    return design.indices[key]


#: :func:`_solve_indices` per column layout (of every design made in this process, at most 256)
_INDICES: dict = {}


def scoring_design(design: _Design) -> _Design:
    """The design on which searched parameters φ are scored, made once per design (every searched
    effect of a selection step shares it): ``design``'s normal equations, for a base with more than
    :data:`REDUCE_ABOVE` step parameters in the directions the fit samples determine
    (:meth:`Linearization.reduced`), with the compacted columns of each capture where they cost
    less (:func:`_compact_columns`, used by the operators without knots: the stage's filter).

    The compacted columns give the same scores up to rounding (a few 1e-11 relative on sample_data's
    fine PI base): the stage's search compares scores only (grid minimum, Nelder–Mead), and the
    final solve of :meth:`Effect.fit` uses ``design``. A delay's knots and every other path use
    the columns as they were (its bounded Brent polish interpolates the scores themselves)."""
    lin = design.lin
    if lin is None:
        return design
    if "scoring" not in design.derived:
        V = lin.directions(design.views) if lin.n > REDUCE_ABOVE else None
        red = lin if V is None else lin.reduced(design.views, directions=V)
        Xs = design.X if V is None else tuple(np.ascontiguousarray(np.hstack([X[:, :1], J[: X.shape[0]]]))
                                             for X, J in zip(design.X, red.jac))
        compact = [_compact_columns(X[:, 0], lin.jac[c][: X.shape[0]], None if V is None else V[lin.cols[c]], X)
                   for c, X in enumerate(Xs)]
        compact = tuple(compact) if any(z is not None for z in compact) else ()
        design.derived["scoring"] = design if V is None and not compact else _Design(
            design.views, Xs, design.yy, tuple(np.asarray(c, int) for c in red.cols), red,
            fitted=design.fitted, index=design.index, knots=design.knots if V is None else {},
            plain=design.plain if V is None else {}, compact=compact)
    return design.derived["scoring"]


def filters_columns(effect: Effect, design: _Design) -> bool:
    """Whether every φ of ``effect`` filters the columns of ``design``: searched parameters, no
    regressors, no knots (a stage). Its scores cost a filtering of every column: its grid is ranked
    on a subsample of rows (:func:`ranked_on_rows`) and its polish follows the SSE's gradient
    (:func:`_gradient_polish`)."""
    if effect.searched_bounds()[0].size == 0 or sum(effect.layout()) or not design.fitted:
        return False
    c = design.fitted[0][0]
    return effect.operator_knots(np.asarray(effect.search_grid()[0], float), design.views[c]) is None


def ranked_on_rows(effect: Effect, design: _Design) -> bool:
    """Whether ``effect``'s search grid is ranked on a subsample of rows first (see
    :data:`COARSE_STRIDE`): its every φ filters the columns of ``design`` (:func:`filters_columns`:
    a stage, whose filter runs over every sample but whose Gram product — the cost, w² per row —
    then needs only the rows scored), and the fit samples are many."""
    if not filters_columns(effect, design):
        return False
    rows = sum(design.X[c].shape[0] if mask is None else int(mask.sum()) for c, mask, _ in design.fitted)
    return rows >= COARSE_MIN_ROWS


def coarse_design(design: _Design) -> _Design:
    """``design`` on every :data:`COARSE_STRIDE`-th fit sample of each capture (its columns, views and
    compacted columns shared; the operators still run over every sample): scores about
    1/COARSE_STRIDE of the full ones, to rank a search grid (:func:`ranked_on_rows`). Made once per
    design."""
    if "coarse" not in design.derived:
        fitted, yy = [], list(design.yy)
        for c, mask, y in design.fitted:
            n = design.X[c].shape[0]
            rows = np.arange(n) if mask is None else np.flatnonzero(mask)
            keep = np.zeros(n, bool)
            keep[rows[::COARSE_STRIDE]] = True
            yk = np.ascontiguousarray(y[::COARSE_STRIDE])
            fitted.append((c, keep, yk))
            yy[c] = float(yk @ yk)
        design.derived["coarse"] = _Design(design.views, design.X, tuple(yy), design.cols, design.lin,
                                           fitted=tuple(fitted), index=design.index, compact=design.compact)
    return design.derived["coarse"]


def _compact_columns(yhat: np.ndarray, J: np.ndarray, V: np.ndarray | None, X: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray] | None:
    """(Z, W) with Z·W = X = [ŷ | J·V] (V None: the identity) up to rounding, Z = [ŷ | the columns of
    J that are not zero on these samples] — a base parameter this capture does not reach (a PI
    operator whose threshold lies above its input's amplitude) leaves an exact zero column — or
    None when that does not save work.

    Every operator is linear in the columns, T_φ[Z·W] = T_φ[Z]·W, so T_φ[X]ᵀT_φ[X] = Wᵀ(T_φ[Z]ᵀT_φ[Z])W:
    per φ, N·r² + 2r·w² products instead of N·w² (w columns of X, r of Z). A capture of the
    smallest amplitude on sample_data's fine PI base: r = 32 where w = 69."""
    N, w = X.shape
    active = np.flatnonzero(np.any(J != 0.0, axis=0))
    r = 1 + active.size
    if N * r * r + 2 * r * w * w >= N * w * w:
        return None
    Z = np.empty((N, r))
    Z[:, 0] = yhat
    Z[:, 1:] = J[:, active]
    W = np.zeros((r, w))
    W[0, 0] = 1.0
    if V is None:
        W[np.arange(1, r), 1 + active] = 1.0
    else:
        W[1:, 1:] = V[active]
    return Z, W


def _in_basis(P: np.ndarray, v: np.ndarray, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(AᵀA, Aᵀy) of A = Z·W from (P, v), those of Z, exactly symmetric as a Gram product is."""
    G = W.T @ (P @ W)
    return 0.5 * (G + G.T), W.T @ v


def prepare_design(yhats: Sequence[np.ndarray], views: Sequence[CaptureView],
                   lin: Linearization | None = None) -> _Design:
    """Precompute the data of :func:`solve_coefficients` for the fit samples of every capture."""
    vs, Xs, yys, cols = [], [], [], []
    for c, (yh, v) in enumerate(zip(yhats, views)):
        N = min(int(np.asarray(yh).shape[0]), v.fit_end)
        vv = v.head(N)
        parts = [np.asarray(yh, float)[:N, None]]
        if lin is not None:
            parts.append(lin.jac[c][:N])
        Xs.append(np.ascontiguousarray(np.hstack(parts)))
        yf = vv.y[vv.fit]
        yys.append(float(yf @ yf))
        vs.append(vv)
        cols.append(None if lin is None else np.asarray(lin.cols[c], int))
    fitted = []
    for c, vv in enumerate(vs):
        if not vv.fit.any():  # a capture held out whole (or none of its samples fitted)
            continue
        fitted.append((c, None, vv.y) if vv.fit.all() else (c, vv.fit, vv.y[vv.fit]))
    return _Design(tuple(vs), tuple(Xs), tuple(yys), tuple(cols), lin, fitted=tuple(fitted),
                   index={f[0]: i for i, f in enumerate(fitted)})


#: at most this many bytes of filtered columns in one Gram product of :func:`_batch_gram` (a capture
#: larger than that is one batch on its own, as it was before captures were batched)
BATCH_BYTES = 32 * 2**20
#: at most this many bytes of :meth:`_Batch.scratch` arrays kept per design (the rest are made per call)
RETAINED_BYTES = 64 * 2**20


@dataclass(frozen=True, eq=False)
class _Batch:
    """Captures whose Gram products :func:`solve_coefficients` sums in one product: their blocks
    of the normal equations are the same (``mesh``, ``ix``), their compacted columns have the same
    transform ``W`` (None: they use X). ``rows``: per member its fit rows (indices into its
    columns); ``y``: the members' fit outputs one after the other; ``yy``: the sum of their y·y;
    ``n_rows``: the rows of the product."""

    members: tuple
    rows: tuple
    y: np.ndarray
    yy: float
    mesh: tuple
    ix: object
    W: np.ndarray | None
    n_rows: int
    buffers: dict = field(default_factory=dict)

    def scratch(self, r: int, budget: dict) -> np.ndarray:
        """An (n_rows, r + 1) array whose last column is ``y``: the operator writes its r columns,
        and one Gram product of it holds TᵀT and Tᵀy. Kept for the batch, width and thread (a fresh
        array of this size costs its page faults at every φ) while the arrays its design keeps
        (``budget["retained"]``, bytes) stay within :data:`RETAINED_BYTES`; beyond that it is made
        anew each time, so that a design of long captures holds no more than one such array at a
        time, as before batches (a review's find: 24 captures of 20,000 samples kept 182 MB)."""
        key = (threading.get_ident(), r)
        if key in self.buffers:
            return self.buffers[key]
        A = np.empty((self.n_rows, r + 1))
        A[:, r] = self.y
        size = A.nbytes
        if budget.get("retained", 0) + size <= RETAINED_BYTES:
            budget["retained"] = budget.get("retained", 0) + size
            self.buffers[key] = A
        return A


def _batches(design: _Design, indices: list) -> list[_Batch]:
    """The captures of ``design`` (fitted by an effect without regressors, ``indices`` from
    :func:`_solve_indices`) in batches whose Gram products are summed in one product: ΣTᵀT over
    captures of the same block of the normal equations is the Gram product of their rows stacked.
    One product of many rows instead of one per capture (24 on sample_data, each a Python round
    trip and a small matrix product), the same numbers up to rounding. A batch holds at most
    :data:`BATCH_BYTES` of columns. Made once per design."""
    if "batches" not in design.batches:
        groups: dict = {}
        for c, mask, y in design.fitted:
            mesh, ix, _, _ = indices[c]
            comp = design.compact[c] if design.compact else None
            W = None if comp is None else comp[1]
            key = (_index_key(ix), None if W is None else (W.shape, W.tobytes()))
            groups.setdefault(key, []).append((c, mask, y, W))
        out = []
        for members in groups.values():
            part: list = []
            size = 0
            for c, mask, y, W in members:
                n = design.X[c].shape[0] if mask is None else int(np.count_nonzero(mask))
                width = design.X[c].shape[1] if W is None else W.shape[0]
                if part and size + n * width * 8 > BATCH_BYTES:
                    out.append(_make_batch(design, indices, part))
                    part, size = [], 0
                part.append((c, mask, y, W))
                size += n * width * 8
            if part:
                out.append(_make_batch(design, indices, part))
        design.batches["batches"] = out
    return design.batches["batches"]


def _index_key(ix) -> tuple:
    return ("slice", ix.start, ix.stop) if isinstance(ix, slice) else ("index", np.asarray(ix).tobytes())


def _make_batch(design: _Design, indices: list, part: list) -> _Batch:
    rows = tuple(np.arange(design.X[c].shape[0]) if mask is None else np.flatnonzero(mask) for c, mask, _, _ in part)
    y = part[0][2] if len(part) == 1 else np.concatenate([y for _, _, y, _ in part])
    mesh, ix, _, _ = indices[part[0][0]]
    return _Batch(tuple(c for c, _, _, _ in part), rows, np.ascontiguousarray(y),
                  float(sum(design.yy[c] for c, _, _, _ in part)), mesh, ix, part[0][3],
                  int(sum(r.size for r in rows)))


def _batch_gram(effect: Effect, design: _Design, batch: _Batch, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(TᵀT, Tᵀy) of T = T_φ[X] over the fit rows of every capture of ``batch``, X = [ŷ | J]: from
    the knots' Gram products where T_φ interpolates between knots the members share
    (:func:`_knot_gram`), else from the operator's rows stacked (:meth:`Effect.operator_rows`) —
    on the compacted columns Z with X = Z·W where the batch has them (:func:`_in_basis`)."""
    knots = [effect.operator_knots(phi, design.views[c]) for c in batch.members]
    if knots[0] is not None:
        if all(k == knots[0] for k in knots):
            return _knot_gram(effect, design, batch.members, knots[0])
        parts = [_knot_gram(effect, design, (c,), k) for c, k in zip(batch.members, knots)]
        return sum(p[0] for p in parts), sum(p[1] for p in parts)
    W = batch.W
    Zs = [design.X[c] if W is None else design.compact[c][0] for c in batch.members]
    r = Zs[0].shape[1]
    A = batch.scratch(r, design.batches)
    at = 0
    for c, Z, rows in zip(batch.members, Zs, batch.rows):
        effect.operator_rows(Z, design.views[c], phi, rows, A, at)
        at += rows.size
    Q = A.T @ A  # [[TᵀT, Tᵀy], [yᵀT, yᵀy]]: one symmetric product
    P, Ty = Q[:r, :r], Q[:r, r]
    return (P, Ty) if W is None else _in_basis(P, Ty, W)


def solve_coefficients(effect: Effect, phi: np.ndarray, yhats: Sequence[np.ndarray] | None = None,
                       views: Sequence[CaptureView] | None = None, lin: Linearization | None = None, *,
                       bounded: bool = True, design: _Design | None = None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Exact least-squares coefficients of ``effect`` at fixed φ, over the fit samples.

    Model: y_c ≈ T_φ[ŷ_c + J_c δ] + R_s,c a_s + R_l,c a_l,c (J, δ only with ``lin``). Pass either
    ``yhats``, ``views`` (and ``lin``) or a ``design`` from :func:`prepare_design` (reused across
    candidates φ).

    The normal equations are assembled from Gram products: with T = T_φ[X], X = [ŷ | J], the
    block of the base step is (TJ)ᵀTJ, its right-hand side (TJ)ᵀy − (TJ)ᵀt₀, and
    ‖y − t₀‖² = yᵀy − 2t₀ᵀy + t₀ᵀt₀ — one matrix product per capture for an effect with regressors, one
    per batch of captures (:func:`_batches`) for one without.

    Returns
    -------
    shared (k_s,), local (C, k_l), delta (n,), sse
        ``sse`` is the fit-sample residual sum of squares of that linear model (out²).
    """
    if design is None:
        design = prepare_design(yhats, views, lin)
    lin = design.lin
    phi = np.asarray(phi, float)
    ks, kl = effect.layout()
    C = len(design.views)
    nb = 0 if lin is None else lin.n
    n = ks + C * kl + nb
    G = np.zeros((n, n))
    b = np.zeros(n)
    s0 = 0.0
    indices = _solve_indices(design, ks, kl)
    if ks + kl:
        plain = type(effect).operator is Effect.operator  # the identity: its Gram block is the design's
        for c, mask, y in design.fitted:
            vv, X = design.views[c], design.X[c]
            mesh, ix, sel_mesh, sel = indices[c]
            T = None
            if not plain:
                T = effect.operator(X, vv, phi)
                if mask is not None:
                    T = T[mask]
            Rs, Rl = effect.regressors(X[:, 0], vv, phi)
            if mask is not None:
                Rs, Rl = Rs[mask], Rl[mask]
            P, Ay = _regressor_gram(effect, design, c, T, Rs, Rl, y)  # of [R | t0 | TJ]
            k = ks + kl
            t0A = P[k]  # t0 against every column
            Gc = P[sel_mesh]
            bc = Ay[sel] - t0A[sel]
            if bc.size:
                G[mesh] += Gc
                b[ix] += bc
            s0 += design.yy[c] - 2.0 * float(Ay[k]) + float(P[k, k])
    else:
        for batch in _batches(design, indices):
            P, Ty = _batch_gram(effect, design, batch, phi)
            Gc = P[1:, 1:]
            bc = Ty[1:] - P[1:, 0]
            if bc.size:
                G[batch.mesh] += Gc
                b[batch.ix] += bc
            s0 += batch.yy - 2.0 * float(Ty[0]) + float(P[0, 0])
    if bounded:
        sl, sh, ll, lh = effect.coefficient_bounds()
        lo = np.concatenate([sl, np.tile(ll, C), lin.lower if lin is not None else np.empty(0)])
        hi = np.concatenate([sh, np.tile(lh, C), lin.upper if lin is not None else np.empty(0)])
        x = _scaled_solve(G, b, lo, hi)
    else:
        x = _scaled_solve(G, b)
    sse = max(s0 - 2.0 * float(x @ b) + float(x @ G @ x), 0.0)
    shared = x[:ks]
    local = x[ks: ks + C * kl].reshape(C, kl)
    delta = x[ks + C * kl:]
    return shared, local, delta, sse


def signature_share(effect: Effect, yhats: Sequence[np.ndarray], views: Sequence[CaptureView],
                    noise_var: float) -> tuple[float, float]:
    """How much of the base residual on the fit samples the effect's first-order signature explains.

    Regresses r = y − ŷ on the effect's :meth:`Effect.signature` columns (base held fixed).

    Returns
    -------
    (share, r2)
        ``r2`` = 1 − SSE₁/SSE₀; ``share`` = (SSE₀ − SSE₁)/(SSE₀ − N·σ²), the fraction of the
        residual *above the noise floor* it explains, clipped to [0, 1].
    """
    ks = kl = None
    G_parts = []
    for yh, v in zip(yhats, views):
        Ss, Sl = effect.signature(np.asarray(yh, float)[: v.n], v)
        ks, kl = Ss.shape[1], Sl.shape[1]
        G_parts.append((Ss, Sl))
    C = len(views)
    n = ks + C * kl
    G = np.zeros((n, n))
    b = np.zeros(n)
    s0 = 0.0
    n_fit = 0
    for c, ((Ss, Sl), yh, v) in enumerate(zip(G_parts, yhats, views)):
        m = v.fit
        r = (v.y - np.asarray(yh, float)[: v.n])[m]
        A = np.hstack([Ss[m], Sl[m]])
        ix = np.concatenate([np.arange(ks), ks + c * kl + np.arange(kl)]).astype(int)
        G[np.ix_(ix, ix)] += A.T @ A
        b[ix] += A.T @ r
        s0 += float(r @ r)
        n_fit += int(m.sum())
    x = _scaled_solve(G, b)
    s1 = max(s0 - 2.0 * float(x @ b) + float(x @ G @ x), 0.0)
    r2 = 1.0 - s1 / s0 if s0 > 0 else 0.0
    above = s0 - n_fit * noise_var
    share = (s0 - s1) / above if above > 0 else 0.0
    return float(np.clip(share, 0.0, 1.0)), float(r2)


# ----------------------------------------------------------------------------------------------
# Helpers shared by configure()
# ----------------------------------------------------------------------------------------------


def fmt_list(x) -> list[float]:
    return [float(v) for v in np.asarray(x, float).ravel()]


# ----------------------------------------------------------------------------------------------
# The candidate effects
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Inserted(Effect):
    """``effect`` (its operator the identity) fitted before the last links of a chain: the output is
    L[E(x)], x the signal where ``effect`` acts and L the later links, so the regressors are those of
    ``effect`` at x pushed through the tangents of L (exact for links linear in their input: creep,
    dynamics, delay, drift). ``signals``: per capture, x and the later links with their inputs
    (:func:`hystfit.diagnose._chain_signals`). The coefficients fitted are ``effect``'s; ``diagnose``
    fits an effect this way where it joins a chain before links already named."""

    effect: Effect = None
    signals: tuple = field(default=(), repr=False)

    def searched_bounds(self):
        return self.effect.searched_bounds()

    def search_grid(self):
        return self.effect.search_grid()

    def layout(self):
        return self.effect.layout()

    def coefficient_bounds(self):
        return self.effect.coefficient_bounds()

    def regressors(self, yhat, view, phi):
        n = yhat.shape[0]
        x, later = self.signals[view.index]
        Rs, Rl = self.effect.regressors(x[:n], view, phi)
        R = np.hstack([Rs, Rl])
        for link, x_in in later:
            if R.shape[1]:
                R = link.tangent(R, x_in[:n], view, view.index)
        return R[:, :Rs.shape[1]], R[:, Rs.shape[1]:]

    def describe(self, phi, shared, local, views, sources=None):
        return self.effect.describe(phi, shared, local, views, sources)


@dataclass(frozen=True)
class Placebo(Effect):
    r"""A random augmentation of a given size: the yardstick an effect must beat.

    Its regressors are random linear combinations of *phase-randomized surrogates* (Theiler et
    al. 1992) of a library — the first-order signatures of every candidate effect, each scaled
    to unit RMS over the fit samples — with ``n_shared`` coefficients common to all captures and
    ``n_local`` per capture: the same number of parameters as the effect it is compared with.
    A surrogate keeps a column's amplitude spectrum (so it is as smooth or as sharp as a real
    augmentation, and fits the fit samples by chance as well as one) but randomizes its phases,
    so it has no causal relation to the input. Its held-out improvement is what that many
    parameters gain by chance; a named effect must gain more.

    (Mixing the signatures themselves, without surrogates, is not a placebo: with two real
    effects in the data a random mixture captures part of both and can beat the correct single
    effect.)

    Parameters
    ----------
    columns : per capture (in the order of ``CaptureView.index``), (N_c, n_shared + n_local) the
        regressors over the whole capture (fit and held-out samples): the surrogates of the library
        (q columns) mixed by ``weights``. (Mixed in the frequency domain, before the inverse
        transform, which is linear: the same columns up to rounding, at a fraction of the cost.)
    weights : (q, n_shared + n_local) random mixing matrix.
    """

    name: ClassVar[str] = "placebo"
    title: ClassVar[str] = "placebo (random augmentation of the same size)"
    equation: ClassVar[str] = "y = ŷ + S·W·a (random mixtures of phase-randomized effect signatures S)"

    columns: tuple = field(default=(), compare=False, repr=False)
    weights: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), compare=False, repr=False)
    n_shared: int = 0
    n_local: int = 0

    @classmethod
    def build(cls, library: Sequence[np.ndarray], n_shared: int, n_local: int,
              rng: np.random.Generator, spectra: Sequence[np.ndarray] | None = None) -> "Placebo":
        """A placebo with ``n_shared`` + ``n_local`` random mixtures of surrogates of ``library``
        (``spectra``: the library's :func:`surrogate_spectrum` per capture, when already known)."""
        spectra = (None,) * len(library) if spectra is None else spectra
        lib = [_as_cols(np.asarray(L, float)) for L in library]
        phased = [_random_phases(surrogate_spectrum(L) if S is None else S, L.shape[0], rng)
                  for L, S in zip(lib, spectra)]
        q = lib[0].shape[1]
        W = rng.standard_normal((q, n_shared + n_local)) / math.sqrt(max(q, 1))
        # mixed before the inverse transform (it is linear): one transform per regressor, not per surrogate
        cols = tuple(np.fft.irfft(P @ W, n=L.shape[0], axis=0) if W.shape[1] else np.zeros((L.shape[0], 0))
                     for P, L in zip(phased, lib))
        return cls(columns=cols, weights=W, n_shared=int(n_shared), n_local=int(n_local))

    @staticmethod
    def skip(library: Sequence[np.ndarray], n_shared: int, n_local: int, rng: np.random.Generator) -> None:
        """Advance ``rng`` exactly as :meth:`build` would, without building (its random numbers
        only): a later build from a copy of ``rng`` taken before draws the same placebo."""
        shapes = [_as_cols(np.asarray(L)).shape for L in library]
        draws = sum((n // 2 + 1) * q for n, q in shapes)  # the phases of phase_surrogate
        if type(rng.bit_generator) is np.random.PCG64 and not rng.bit_generator.state["has_uint32"]:
            rng.bit_generator.advance(draws)  # a PCG64 double is one 64-bit draw: the same state, nothing made
        else:
            for n, q in shapes:
                rng.random((n // 2 + 1, q))
        rng.standard_normal((shapes[0][1], n_shared + n_local))

    def layout(self):
        return self.n_shared, self.n_local

    def regressors(self, yhat, view, phi):
        R = self.columns[view.index][: yhat.shape[0]]
        return R[:, : self.n_shared], R[:, self.n_shared:]

    def describe(self, phi, shared, local, views, sources=None):
        return {"n_shared": self.n_shared, "n_per_capture": self.n_local}


def __getattr__(name: str):
    """``EFFECTS``: the candidate effects of diagnose — every registered block that is a candidate
    (:attr:`hystfit.blocks.base.Block.candidate`; not ``lti``, which is identified, not fitted), in registration
    order (the order they are reported when tied), name → class."""
    if name == "EFFECTS":
        return {n: _blocks.get(n) for n in _blocks.names() if _blocks.get(n).candidate}
    raise AttributeError(name)


def make_effect(name: str) -> Effect:
    """A fresh (unconfigured) candidate effect — a registered block — by name; :class:`ConfigError`
    listing the valid names for an unknown one."""
    key = name.strip().lower()
    names = [n for n in _blocks.names() if _blocks.get(n).candidate]
    if key not in names:
        raise ConfigError(f"unknown effect {name!r}: choose from {', '.join(names)}")
    return _blocks.get(key)()
