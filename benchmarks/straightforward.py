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


# ----------------------------------------------------------------------------------------------
# Figures the straightforward way: one figure after another, constrained layout, every k-th sample,
# default PNG compression (what hystfit did before the figure work of the speed issue).

SF_MAX_POINTS = 20_000


def _sf_save(fig, path):
    fig.savefig(path, format="png", dpi=110)


def _sf_figure(w, h):
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), layout="constrained")


def sf_loop(path, us, ys, yps, title=""):
    fig = _sf_figure(6.4, 4.8)
    ax = fig.add_subplot()
    for i, (u, y, yp) in enumerate(zip(us, ys, yps)):
        k = max(1, -(-len(u) // SF_MAX_POINTS))
        ax.plot(u[::k], y[::k], color="0.15", lw=0.8, label="measured" if i == 0 else None)
        ax.plot(u[::k], yp[::k], color="tab:red", lw=1.1, label="model" if i == 0 else None)
    ax.set_xlabel("Voltage (V)")
    ax.set_ylabel("Displacement (um)")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best")
    _sf_save(fig, path)


def sf_timeseries(path, t, y, yp, title=""):
    fig = _sf_figure(8.0, 5.6)
    ax, axr = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [2.2, 1.0]})
    k = max(1, -(-len(t) // SF_MAX_POINTS))
    ax.plot(t[::k], y[::k], color="0.15", lw=0.8, label="measured")
    ax.plot(t[::k], yp[::k], color="tab:red", lw=1.1, label="model")
    ax.legend(loc="upper right")
    ax.set_title(title)
    r = yp - y
    axr.plot(t[::k], r[::k], lw=0.7)
    axr.set_xlabel("Time (s)")
    _sf_save(fig, path)


def sf_convergence(path, best, mean, title=""):
    fig = _sf_figure(6.4, 4.2)
    ax = fig.add_subplot()
    ax.plot(np.arange(len(best)), best, marker="o" if len(best) == 1 else None, lw=1.8, label="best so far")
    ax.plot(np.arange(len(mean)), mean, ls="--", lw=1.0, label="population mean")
    if np.all(np.asarray(best) > 0):
        ax.set_yscale("log")
    ax.legend(loc="best")
    ax.set_title(title)
    _sf_save(fig, path)


def sf_overview(path, panels, title=""):
    import math

    n = len(panels)
    cols = math.ceil(math.sqrt(n * 1.5))
    rows = math.ceil(n / cols)
    fig = _sf_figure(2.6 * cols, 2.25 * rows + 0.75)
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    for ax, p in zip(axes, panels):
        for u, y, yp in zip(p["u"], p["y_meas"], p["y_model"]):
            k = max(1, -(-len(u) // (SF_MAX_POINTS // 4)))
            ax.plot(u[::k], y[::k], color="0.15", lw=0.6)
            ax.plot(u[::k], yp[::k], color="tab:red", lw=0.9)
        ax.set_title(p["title"], fontsize=7.5)
        ax.tick_params(labelsize=6.5)
    fig.suptitle(title)
    _sf_save(fig, path)
