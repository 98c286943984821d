"""Bouc–Wen hysteresis model (paper 004 eq. 1–2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..params import DataScale, Param
from ..registry import models
from ._kernels import bouc_wen_h, bouc_wen_step
from .base import Model


@models.register
@dataclass(frozen=True)
class BoucWen(Model):
    r"""Bouc–Wen model with exponent n = 1.

    .. math::

        y = K_v\,u + h + y_0,\qquad
        \dot h = \alpha\,\dot u - \beta\,|\dot u|\,h - \gamma\,\dot u\,|h|,\qquad h(0) = 0

    (paper 004 eq. 1–2 with n = 1, as ``shared/papers/README.md`` adopts). The output offset
    y0 is ours: real captures carry a sensor offset.

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

    Bounds scale with the data: Kv, α in [−3, 3]·gain (gain = output range / input range),
    β in [0, 50]/ΔU, γ in [−50, 50]/ΔU with ΔU the input range; paper 004 uses [0.1, 10] on
    its own scale.
    """

    name = "bw"
    title = "Bouc–Wen"
    reference = "paper 004 eq. 1–2"
    equation = "y = Kv·u + h + y0,  dh/dt = α·du/dt − β·|du/dt|·h − γ·du/dt·|h|"
    rate_dependent = False

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        g, du = scale.gain, scale.u_range
        span = scale.y_range
        return (
            Param("Kv", "out/V", -3 * g, 3 * g, g, "linear gain"),
            Param("alpha", "out/V", -3 * g, 3 * g, 0.1 * g, "hysteresis input gain α"),
            Param("beta", "1/V", 0.0, 50.0 / du, 2.0 / du, "shape parameter β"),
            Param("gamma", "1/V", -50.0 / du, 50.0 / du, 0.0, "shape parameter γ"),
            Param("y0", "out", scale.y_min - span, scale.y_max + span, 0.0, "output offset"),
        )

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        theta = self.check_theta(theta, 5)
        u = np.ascontiguousarray(u, dtype=np.float64)
        kv, a, b, g, y0 = (np.ascontiguousarray(theta[:, i]) for i in range(5))
        h = bouc_wen_h(u, a, b, g).T  # (P, N)
        y = kv[:, None] * u[None, :] + h + y0[:, None]
        return y

    def separable(self):
        """Kv, α and y0 enter linearly: with h = α·g, g solves the same equation with α = 1
        (ġ = u̇ − β|u̇|g − γu̇|g|), so y = Kv·u + α·g(β, γ) + y0. Only β and γ are searched."""
        from ..separable import Separable

        def factory(u, dt):
            u = np.ascontiguousarray(u, dtype=np.float64)

            def basis(theta_nl):
                P = theta_nl.shape[0]
                g = bouc_wen_h(u, np.ones(P), np.ascontiguousarray(theta_nl[:, 0]),
                                        np.ascontiguousarray(theta_nl[:, 1])).T
                B = np.empty((P, u.shape[0], 3))
                B[:, :, 0] = u[None, :]
                B[:, :, 1] = g
                B[:, :, 2] = 1.0
                return B

            return basis

        return Separable((0, 1, 4), (2, 3), factory)

    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        return np.zeros(1)

    def step(self, theta, state, u_prev, u_new, dt):
        kv, a, b, g, y0 = (float(v) for v in np.asarray(theta, float).ravel())
        u_new = np.ascontiguousarray(u_new, dtype=np.float64)
        h = bouc_wen_step(float(state[0]), float(u_prev), u_new, a, b, g)
        return kv * u_new + h + y0, h[:, None]
