"""Classical Prandtl–Ishlinskii model (paper 003 eq. 1–3, inverse eq. 17–20)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from .._jit import readonly
from ..errors import ConfigError
from ..params import DataScale, Param
from ..registry import models
from ._kernels import play_matrix, play_matrix_from
from .base import Model
from .separable import linear_in_all

THRESHOLD_PLACEMENTS = ("uniform", "quadratic")
#: the histories :attr:`PI.history` assumes before a capture's first sample
HISTORIES = ("ramp", "relaxed")


#: the largest design matrix (samples × parameters) :meth:`PI.head_simulator` keeps (32 MB): a
#: diagnosis keeps one per capture and resolution; a longer capture is simulated at each call
HEAD_SIMULATOR_MAX = 4_000_000


@dataclass(frozen=True)
class PlayOperators:
    """The structure fields of a classical PI's play operators, defined once for :class:`PI` and
    the static part of the Hammerstein model: how many, how their thresholds are placed (or the
    thresholds themselves, in V) and whether the weights are kept ≥ 0."""

    n_operators: int = 10
    placement: str = "uniform"
    thresholds_V: tuple[float, ...] | None = None
    nonnegative: bool = True


@models.register
@dataclass(frozen=True)
class PI(Model, PlayOperators):
    r"""Classical Prandtl–Ishlinskii hysteresis: a weighted sum of play operators.

    .. math::

        F_r[u](k) = \max(u_k - r,\ \min(u_k + r,\ F_r[u](k-1))),\qquad
        F_r[u](0) = \max(u_0 - r,\ \min(u_0 + r,\ 0))

        y(k) = \sum_{j=0}^{n-1} w_j\,F_{r_j}[u](k) + y_0

    (paper 003 eq. 1–3; ``shared/papers/README.md``). ``r_0 = 0`` makes the first operator
    the identity, i.e. the linear term.

    Structure
    ---------
    n_operators : number of play operators n (including the linear one), default 10.
    placement : ``"uniform"`` r_j = j·max|u|/n (the README's default) or ``"quadratic"``
        r_j = (j/n)²·max|u| (denser at small thresholds, where loops of small amplitude live).
    thresholds_V : the thresholds r_j in V; filled from the identification data by
        :meth:`adapt` and saved with the fit so predictions use the same operators.
    history : the history assumed before a capture's first sample u₀. ``"ramp"`` (default,
        paper 003 eq. 1–2): brought monotonically from 0 V to u₀, F_r[u](0) = max(u₀ − r, min(u₀ + r, 0)).
        ``"relaxed"``: every play at u₀, F_r[u](0) = u₀ — an actuator that settled at u₀ after a
        decaying oscillation about it, or any history whose loops closed there; the ramp model
        translated to u₀ (play operators commute with a shift of input and state), so the inverse is
        the ramp model's with its plays at the output's first value. A capture that starts at
        mid-stroke under the other history fits far worse than the data allow
        (``python benchmarks/pi_history.py``: 0.77–2.50 µm against 0.02 µm, noise 0.02 µm).
    nonnegative : constrain the weights to one sign (the physically sensible, invertible case):
        w_j ≥ 0 when the output rises with the input, w_j ≤ 0 when it falls (an inverted sensor;
        the sign is that of the data's input–output covariance, :attr:`DataScale.sign`).

    Parameters (θ)
    --------------
    w0 … w{n−1} : operator weights, output unit per V (e.g. µm/V). With nonnegative weights and
        w0 > 0 the model is invertible.
    y0 : output offset, output unit.

    The output is linear in θ: for fixed thresholds the least-squares optimum is exact
    (non-negative least squares), see :meth:`design_matrix`.

    Inverse (paper 003 eq. 17–20): another PI with weights w'_0 = 1/w_0,
    w'_i = −w_i / ((Σ_{j≤i} w_j)(Σ_{j≤i−1} w_j)) and thresholds r'_i = Σ_{j≤i} w_j (r_i − r_j),
    applied to y − y0.
    """

    name = "pi"
    title = "Prandtl–Ishlinskii (classical)"
    reference = "paper 003 eq. 1–3 (forward), eq. 17–20 (analytic inverse)"
    equation = "y = Σ_j w_j·F_{r_j}[u] + y0,  F_r[u](k) = max(u_k − r, min(u_k + r, F_r[u](k−1)))"
    rate_dependent = False
    first_sample_is_a_ramp = True  # initial_state: the play states after u0 from the virgin state
    resolution_option = "n_operators"
    history: str = "ramp"


    def __post_init__(self) -> None:
        if not isinstance(self.n_operators, int) or not 1 <= self.n_operators <= 200:
            raise ConfigError(f"pi: n_operators must be an integer in [1, 200], got {self.n_operators!r}")
        if self.placement not in THRESHOLD_PLACEMENTS:
            raise ConfigError(f"pi: placement must be one of {THRESHOLD_PLACEMENTS}, got {self.placement!r}")
        if self.history not in HISTORIES:
            raise ConfigError(f"pi: history must be one of {', '.join(HISTORIES)}, got {self.history!r}")
        if self.thresholds_V is not None:
            r = np.asarray(self.thresholds_V, float)
            if r.shape != (self.n_operators,) or np.any(r < 0) or np.any(np.diff(r) <= 0):
                raise ConfigError(
                    f"pi: thresholds_V must be {self.n_operators} increasing non-negative values, got {self.thresholds_V!r}"
                )

    # ------------------------------------------------------------------ structure
    def adapt(self, scale: DataScale) -> "PI":
        if self.thresholds_V is not None:
            return self
        n = self.n_operators
        j = np.arange(n, dtype=float)
        # paper 003's r_j = j·max|u|/n for an input from or about 0 V, less the input's bias
        # (DataScale.input_bias_V) for a biased one: on a ±30 V sine about 100 V, thresholds up to
        # max|u| = 130 V leave every operator with r ≥ 30 V still after the first rise, 7 of 10
        # (tests/integration/test_recovery.py); up to 130 − 70 = 60 V they spread as on a drive from 0 V. The
        # same r_j as the paper's wherever the input reaches 0 V.
        umax = scale.u_abs_max - scale.input_bias_V
        r = j * umax / n if self.placement == "uniform" else (j / n) ** 2 * umax
        return replace(self, thresholds_V=tuple(float(x) for x in r))

    @property
    def r(self) -> np.ndarray:
        if self.thresholds_V is None:
            raise ConfigError("pi: thresholds are not set; call adapt(scale) with the identification data first")
        return np.asarray(self.thresholds_V, dtype=np.float64)

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        g = scale.gain
        s = -1.0 if scale.sign < 0 else 1.0  # an output that falls with the input: all weights ≤ 0
        lo, hi = (0.0, 3.0 * g) if self.nonnegative else (-3.0 * g, 3.0 * g)
        if s < 0 and self.nonnegative:
            lo, hi = -hi, -lo
        ps = [Param(f"w{j}", "out/V", lo, hi, s * (g / self.n_operators if j else g / 2),
                    f"weight of the play operator with threshold r{j}") for j in range(self.n_operators)]
        mid = 0.5 * (scale.y_min + scale.y_max) if scale.y_min > 0 or scale.y_max < 0 else 0.0
        ps.append(Param("y0", "out", *scale.offset_bounds(), mid, "output offset"))
        return tuple(ps)

    # ------------------------------------------------------------------ simulation
    def design_matrix(self, u: np.ndarray, dt: float) -> np.ndarray:
        """Regressors (N, n + 1): the play-operator outputs and a column of ones (offset).

        y = Φ θ exactly, so θ follows from (non-negative) least squares.
        """
        u = readonly(u)
        return np.hstack([self._plays(u), np.ones((u.shape[0], 1))])

    def _plays(self, u: np.ndarray) -> np.ndarray:
        """The play operators' outputs (N, n) from the state :attr:`history` assumes."""
        if self.history == "relaxed" and u.shape[0]:
            return play_matrix_from(u, self.r, np.full(self.n_operators, float(u[0])))
        return play_matrix(u, self.r)

    @property
    def starts_at_rest(self) -> bool:
        return self.history == "relaxed"

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        theta = self.check_theta(theta, self.n_operators + 1)
        return theta @ self.design_matrix(u, dt).T

    def head_simulator(self, u: np.ndarray, dt: float) -> Callable[[np.ndarray, int], np.ndarray]:
        """:meth:`simulate_one` over the first n samples with the design matrix of the whole input
        made once: its first n rows are ``design_matrix(u[:n])`` (the play operators are causal),
        C-contiguous as that is, so ``θ @ D[:n].T`` is the same product, bit for bit."""
        if (type(self).simulate is not PI.simulate  # a subclass that simulates otherwise
                or np.shape(u)[0] * (self.n_operators + 1) > HEAD_SIMULATOR_MAX):
            return super().head_simulator(u, dt)
        D = self.design_matrix(np.asarray(u, float), dt)
        d = self.n_operators + 1
        return lambda theta, n: (self.check_theta(np.atleast_2d(np.asarray(theta, float)), d) @ D[:n].T)[0]

    def simulator(self, u: np.ndarray, dt: float) -> Callable[[np.ndarray], np.ndarray]:
        u = readonly(u)
        F = self._plays(u)
        phi_t = np.empty((self.n_operators + 1, u.shape[0]))  # (n+1, N), computed once, no extra copy
        phi_t[:-1] = F.T
        phi_t[-1] = 1.0
        del F
        d = self.n_operators + 1
        return lambda theta: self.check_theta(theta, d) @ phi_t

    def separable(self):
        """Every parameter is linear (thresholds fixed): the optimum is one bounded least-squares solve."""
        return linear_in_all(self.design_matrix, self.n_operators + 1)

    # ------------------------------------------------------------------ inverse
    @staticmethod
    def output_sign(theta: np.ndarray) -> float:
        """+1 for a PI whose output rises with the input (w0 > 0), −1 for a falling one (w0 < 0)."""
        return -1.0 if float(np.asarray(theta, float).ravel()[0]) < 0 else 1.0

    def inverse_operator(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weights and thresholds of the inverse PI (paper 003 eq. 17–20) of s·Σ w_j F_{r_j}, s =
        :meth:`output_sign` (a falling output is inverted as the rising PI of −w applied to −y)."""
        w = self.output_sign(theta) * np.asarray(theta[: self.n_operators], float)
        r = self.r
        csum = np.cumsum(w)
        if w[0] <= 0 or np.any(csum <= 0):
            raise ConfigError(
                "pi: the inverse needs w0 ≠ 0 and partial sums of the weights of one sign; refit with "
                "non-negative weights (--model-option nonnegative=true)"
            )
        w_inv = np.empty_like(w)
        w_inv[0] = 1.0 / w[0]
        w_inv[1:] = -w[1:] / (csum[1:] * csum[:-1])
        r_inv = np.array([np.sum(w[: i + 1] * (r[i] - r[: i + 1])) for i in range(len(w))])
        return w_inv, r_inv

    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        """The play-operator states (n,) after the first sample u0: from the virgin state 0, or every
        one at u0 (:attr:`history` ``"relaxed"``)."""
        r = self.r
        if self.history == "relaxed":
            return np.full(r.shape[0], float(u0))
        return np.maximum(u0 - r, np.minimum(u0 + r, 0.0))

    def step(self, theta, state, u_prev, u_new, dt):
        """One sample for candidate inputs u_new (C,): outputs (C,) and play states (C, n)."""
        t = np.asarray(theta, dtype=np.float64).ravel()
        n = self.n_operators
        u_new = np.atleast_1d(np.asarray(u_new, dtype=np.float64))
        r = self.r
        plays = np.maximum(u_new[:, None] - r[None, :], np.minimum(u_new[:, None] + r[None, :],
                                                                     np.asarray(state)[None, :n]))
        return plays @ t[:n] + t[n], plays

    def invert(self, theta: np.ndarray, y_target: np.ndarray, dt: float,
               u_range: tuple[float, float] | None = None) -> np.ndarray:
        """The analytic inverse (paper 003 eq. 17–20); ``u_range`` is accepted for the common
        signature and not needed (the inverse is exact)."""
        theta = np.asarray(theta, float).ravel()
        w_inv, r_inv = self.inverse_operator(theta)
        v = np.ascontiguousarray(self.output_sign(theta) * (np.asarray(y_target, float) - theta[-1]))
        # initial inverse-operator states consistent with the forward state: virgin, or (relaxed) every
        # play at the first value, the virgin case translated
        state0 = (np.full(r_inv.shape[0], v[0]) if self.history == "relaxed" and v.size
                  else np.maximum(v[0] - r_inv, np.minimum(v[0] + r_inv, 0.0)))
        return play_matrix_from(v, r_inv, state0) @ w_inv
