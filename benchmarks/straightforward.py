"""The straightforward implementations (a Python loop over time for each candidate).

Kept here, not in the package, as the baseline the benchmark measures hystfit against.
"""

from __future__ import annotations

import numpy as np


def pi_one(theta, u, r):
    """Classical PI for one parameter vector: Python loop over time and operators."""
    n = len(r)
    state = [max(u[0] - rj, min(u[0] + rj, 0.0)) for rj in r]
    y = np.empty(len(u))
    for k in range(len(u)):
        uk = u[k]
        acc = theta[n]
        for j in range(n):
            s = max(uk - r[j], min(uk + r[j], state[j]))
            state[j] = s
            acc += theta[j] * s
        y[k] = acc
    return y


def bw_one(theta, u, substeps=1):
    """Bouc-Wen (n = 1) for one parameter vector: explicit Euler in the input, Python loop."""
    kv, a, b, g, y0 = theta
    h = 0.0
    y = np.empty(len(u))
    y[0] = kv * u[0] + y0
    for k in range(1, len(u)):
        du = (u[k] - u[k - 1]) / substeps
        for _ in range(substeps):
            h += a * du - b * abs(du) * h - g * du * abs(h)
        y[k] = kv * u[k] + h + y0
    return y


def pi_numpy(theta, u, r):
    """Classical PI vectorized over the population with NumPy (time loop in Python)."""
    P, n = theta.shape[0], len(r)
    F = np.maximum(u[0] - r, np.minimum(u[0] + r, 0.0))[None, :].repeat(P, axis=0)
    y = np.empty((P, len(u)))
    w, y0 = theta[:, :n], theta[:, n]
    for k in range(len(u)):
        F = np.maximum(u[k] - r, np.minimum(u[k] + r, F))
        y[:, k] = np.einsum("pj,pj->p", w, F) + y0
    return y


def bw_numpy(theta, u):
    """Bouc-Wen (n = 1, explicit Euler per sample) vectorized over the population with NumPy."""
    kv, a, b, g, y0 = (theta[:, i] for i in range(5))
    h = np.zeros(theta.shape[0])
    y = np.empty((theta.shape[0], len(u)))
    y[:, 0] = kv * u[0] + y0
    for k in range(1, len(u)):
        du = u[k] - u[k - 1]
        h = h + a * du - b * abs(du) * h - g * du * np.abs(h)
        y[:, k] = kv * u[k] + h + y0
    return y
