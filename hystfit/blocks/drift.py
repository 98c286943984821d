"""Slow output drift, per capture: y_c(t) = x_c(t) + d₀,c + v_c·t."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..effects import EffectParam
from ..params import DataScale, Param
from ..registry import blocks
from .base import Block


def drift_basis(n: int, dt: float) -> np.ndarray:
    """The per-capture drift regressors (n, 2): a constant and the time from the first sample (s)."""
    t = np.arange(n, dtype=np.float64) * dt
    return np.column_stack([np.ones(n), t])


@blocks.register
@dataclass(frozen=True)
class Drift(Block):
    r"""Slow output drift not driven by the input: an offset and a rate per capture.

    .. math:: y_c(t) = x_c(t) + d_{0,c} + v_c\,t

    Why this form: thermal drift of the sensor or the mechanics, and a sensor re-zeroed between
    recordings, change from one capture to the next (captures are taken at different times), so
    each capture gets its own offset d₀ (out) and rate v (out/s); over one capture (seconds) a
    thermal drift is close to linear, and a higher-order polynomial would extrapolate wildly.
    Independent of the input: the same rate at every amplitude, which separates it from creep.

    In a composite model the drift is a *nuisance*: it has no entry in θ. The identification
    objective projects each capture's residual onto the complement of span{1, t} (the exact
    least-squares offset and rate of every capture, for every candidate θ), and the fitted
    per-capture values are reported beside the metrics. A prediction of a new capture has no
    drift unless its measurement is given (``simulate`` then fits and reports it); a feedforward
    cannot cancel a drift it cannot know, so :meth:`invert` is the identity.
    """

    name: ClassVar[str] = "drift"
    title: ClassVar[str] = "slow output drift (per capture)"
    equation: ClassVar[str] = "y_c = x_c + d0_c + v_c·t"
    reference: ClassVar[str] = "thermal drift and sensor re-zeroing between captures"
    nuisance: ClassVar[bool] = True

    # ------------------------------------------------------------------ structure
    def params(self, scale: DataScale) -> tuple[Param, ...]:
        return ()

    # ------------------------------------------------------------------ diagnose interface
    def param_table(self):
        return (EffectParam("offset", "out", "per-capture", "output offset of the capture"),
                EffectParam("rate", "out/s", "per-capture", "drift rate of the capture"))

    def layout(self):
        return 0, 2

    def regressors(self, yhat, view, phi):
        t = view.t[: yhat.shape[0]] - view.t[0]
        return np.zeros((t.shape[0], 0)), np.column_stack([np.ones_like(t), t])

    def describe(self, phi, shared, local, views, sources=None):
        local = np.asarray(local, float).reshape(-1, 2)
        names = list(sources) if sources is not None else [f"capture{i}" for i in range(local.shape[0])]
        rates = local[:, 1]
        return {"per_capture": [{"source": s, "offset_out": float(o), "rate_out_per_s": float(r)}
                                for s, (o, r) in zip(names, local)],
                "median_abs_rate_out_per_s": float(np.median(np.abs(rates))) if rates.size else 0.0,
                "mean_rate_out_per_s": float(np.mean(rates)) if rates.size else 0.0}

    # ------------------------------------------------------------------ composite interface
    def nuisance_basis(self, n, dt):
        return drift_basis(n, dt)

    def apply_population(self, x, theta, dt):
        return np.array(np.atleast_2d(x), dtype=np.float64, copy=True)

    def invert(self, theta, y, dt):
        return np.array(y, dtype=np.float64, copy=True)
