"""Bouc–Wen hysteresis model (paper 004 eq. 1–2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..params import DataScale, Param
from ..registry import models
from ._kernels import bouc_wen_moments, bouc_wen_output, bouc_wen_population, bouc_wen_sse, bouc_wen_step
from ._kernels_extra import bouc_wen_n_population, bouc_wen_n_step
from .base import Model


@models.register
@dataclass(frozen=True)
class BoucWen(Model):
    r"""Bouc–Wen model with exponent n = 1.

    .. math::

        y = K_v\,u + h + y_0,\qquad
        \dot h = \alpha\,\dot u - \beta\,|\dot u|\,h - \gamma\,\mathrm{sgn}(\alpha)\,\dot u\,|h|,
        \qquad h(0) = 0

    (paper 004 eq. 1–2 with n = 1, as ``shared/papers/README.md`` adopts, with paper 004's γ
    written γ·sgn(α): see "Sign convention" below). The output offset y0 is ours: real captures
    carry a sensor offset. This is the equation simulated *and* the one printed in ``params.json``
    (:attr:`equation`) for the stored values: ``tests/unit/test_bw_printed_equation.py`` integrates
    the printed equation with the printed values independently and matches hystfit.

    Parameters (θ)
    --------------
    Kv : linear gain, output unit per V.
    alpha : hysteresis input gain, output unit per V.
    beta, gamma : shape parameters, 1/V; β + γ sets how fast h saturates along the input,
        β − γ the other branch; h saturates at α/(β+γ).
    y0 : output offset, output unit.

    Integration. Bouc–Wen is rate independent, so h is integrated in the input along each
    sample's straight input segment. For n = 1 and fixed signs of u̇ and h the equation is
    linear in h and is solved exactly (with the zero crossing of h located exactly), see
    :func:`hystfit.models._kernels.bouc_wen_population`: no sub-steps, stable at any sample
    rate, exact for piecewise-linear inputs.

    Sign convention of γ. θ stores γ such that paper 004's γ is γ·sgn(α) (identical for α ≥ 0,
    the case paper 004 bounds to; on real captures α often comes out negative, and then the
    textbook γ is −γ). Then h = α·g exactly, with g the solution of
    ġ = u̇ − β|u̇|g − γu̇|g| for *either* sign of α: the output is linear in (Kv, α, y0) and the
    ``auto`` optimizer solves them exactly, searching only (β, γ). Without this convention the
    split would be wrong for α < 0 (|h| = |α||g|), and loops of both orientations (clockwise and
    counter-clockwise) must be representable.

    Free exponent (structure ``free_exponent=True``, paper 004 eq. 2 with n free):
    ḣ = α u̇ − β |u̇| |h|^{n−1} h − γ u̇ |h|^n, integrated with stable sub-steps
    (:func:`hystfit.models._kernels_extra.bouc_wen_n_population`); θ gains ``n`` ∈ [1, 4]. Since
    the units of β, γ depend on n, they are searched normalised: β_phys = β·h_ref^{1−n} with
    h_ref = the output range of the identification data (saved in the structure), so at n = 1
    they mean exactly what they mean in the default model.

    Bounds scale with the data: Kv, α in [−3, 3]·gain (gain = output range / input range),
    β in [0, 50]/ΔU, γ in [−50, 50]/ΔU with ΔU the input range; paper 004 uses [0.1, 10] on
    its own scale.
    """

    name = "bw"
    title = "Bouc–Wen"
    reference = "paper 004 eq. 1–2"
    #: the equation simulated, in the stored θ (γ multiplies sgn(α): paper 004's γ is γ·sgn(α));
    #: with ``free_exponent`` h becomes |h|^(n−1)·h and |h|^n, β and γ scaled by h_ref^(1−n)
    equation = "y = Kv·u + h + y0,  dh/dt = α·du/dt − β·|du/dt|·h − γ·sgn(α)·du/dt·|h|"
    rate_dependent = False

    free_exponent: bool = False
    h_ref: float | None = None

    def adapt(self, scale: DataScale) -> "BoucWen":
        if self.free_exponent and self.h_ref is None:
            return BoucWen(free_exponent=True, h_ref=float(scale.y_range))
        return self

    @property
    def d(self) -> int:
        return 6 if self.free_exponent else 5

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        g, du = scale.gain, scale.u_range
        span = scale.y_range
        ps = (
            Param("Kv", "out/V", -3 * g, 3 * g, g, "linear gain"),
            Param("alpha", "out/V", -3 * g, 3 * g, 0.1 * g, "hysteresis input gain α"),
            Param("beta", "1/V", 0.0, 50.0 / du, 2.0 / du, "shape parameter β (normalised by h_ref^(1−n) when n is free)"),
            Param("gamma", "1/V", -50.0 / du, 50.0 / du, 0.0, "shape parameter γ, multiplies sgn(α)·u̇·|h| (paper 004's γ = γ·sgn(α); normalised by h_ref^(1−n) when n is free)"),
            Param("y0", "out", scale.y_min - span, scale.y_max + span, 0.0, "output offset"),
        )
        if self.free_exponent:
            ps += (Param("n", "1", 1.0, 4.0, 1.0, "Bouc–Wen exponent n"),)
        return ps

    def _physical(self, theta: np.ndarray):
        """(Kv, α, β, γ, y0, n) of paper 004's equation: γ_paper = γ·sgn(α), and with a free
        exponent β, γ de-normalised by h_ref^(1−n)."""
        kv, a, b, g, y0 = (np.ascontiguousarray(theta[:, i]) for i in range(5))
        g = np.ascontiguousarray(g * np.where(a < 0, -1.0, 1.0))  # γ_paper = γ·sgn(α), see the class docstring
        if not self.free_exponent:
            return kv, a, b, g, y0, None
        n = np.ascontiguousarray(theta[:, 5])
        f = float(self.h_ref or 1.0) ** (1.0 - n)
        return kv, a, np.ascontiguousarray(b * f), np.ascontiguousarray(g * f), y0, n

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        theta = self.check_theta(theta, self.d)
        u = np.ascontiguousarray(u, dtype=np.float64)
        kv, a, b, g, y0, n = self._physical(theta)
        if n is None:
            return bouc_wen_output(u, kv, a, b, g, y0).T  # (P, N) view of the kernel's (N, P); exact for n = 1
        h = bouc_wen_n_population(u, a, b, g, n).T
        return kv[:, None] * u[None, :] + h + y0[:, None]

    def sse_evaluator(self, u, dt, y):
        """Σ(ŷ − y)² from the fused kernel :func:`~hystfit.models._kernels.bouc_wen_sse` (n = 1):
        the (P, N) outputs are never stored. With a free exponent: None (simulate)."""
        if self.free_exponent:
            return None
        u = np.ascontiguousarray(u, dtype=np.float64)
        y = np.ascontiguousarray(y, dtype=np.float64)

        def sse(theta):
            theta = self.check_theta(theta, self.d)
            kv, a, b, g, y0, _ = self._physical(theta)
            return bouc_wen_sse(u, y, kv, a, b, g, y0)

        return sse

    def separable(self):
        """Kv, α and y0 enter linearly (n = 1): with h = α·g, g solves the same equation with α = 1
        (ġ = u̇ − β|u̇|g − γu̇|g|), so y = Kv·u + α·g(β, γ) + y0. Only β and γ are searched.

        The normal equations of (Kv, α, y0) come straight from the fused kernel
        :func:`~hystfit.models._kernels.bouc_wen_moments` (Σg², Σg·u, Σg, Σg·y per candidate),
        so a search never stores g."""
        from ..separable import Separable

        if self.free_exponent:
            return None  # with a free n, α no longer scales h: no exact split

        def gram_factory(u, dt, y):
            u = np.ascontiguousarray(u, dtype=np.float64)
            y = np.ascontiguousarray(y, dtype=np.float64)
            su, suu, suy, sy, yy, n = u.sum(), u @ u, u @ y, y.sum(), float(y @ y), float(u.shape[0])

            def gram(theta_nl):
                M = bouc_wen_moments(u, y, theta_nl[:, 0], theta_nl[:, 1])  # Σg², Σgu, Σg, Σgy
                P = M.shape[0]
                G = np.empty((P, 3, 3))
                G[:, 0, 0] = suu
                G[:, 0, 1] = G[:, 1, 0] = M[:, 1]
                G[:, 0, 2] = G[:, 2, 0] = su
                G[:, 1, 1] = M[:, 0]
                G[:, 1, 2] = G[:, 2, 1] = M[:, 2]
                G[:, 2, 2] = n
                c = np.empty((P, 3))
                c[:, 0] = suy
                c[:, 1] = M[:, 3]
                c[:, 2] = sy
                return G, c, yy

            return gram

        def factory(u, dt):
            u = np.ascontiguousarray(u, dtype=np.float64)

            def basis(theta_nl):
                P = theta_nl.shape[0]
                g = bouc_wen_population(u, np.ones(P), np.ascontiguousarray(theta_nl[:, 0]),
                                        np.ascontiguousarray(theta_nl[:, 1])).T
                B = np.empty((P, u.shape[0], 3))
                B[:, :, 0] = u[None, :]
                B[:, :, 1] = g
                B[:, :, 2] = 1.0
                return B

            return basis

        return Separable((0, 1, 4), (2, 3), factory, gram_factory, gram_fused=True)

    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        return np.zeros(1)

    def step(self, theta, state, u_prev, u_new, dt):
        kv, a, b, g, y0, n = (float(v[0]) if v is not None else None
                              for v in self._physical(np.atleast_2d(np.asarray(theta, float))))
        u_new = np.ascontiguousarray(u_new, dtype=np.float64)
        if n is None:
            h = bouc_wen_step(float(state[0]), float(u_prev), u_new, a, b, g)
        else:
            h = bouc_wen_n_step(float(state[0]), float(u_prev), u_new, a, b, g, n)
        return kv * u_new + h + y0, h[:, None]
