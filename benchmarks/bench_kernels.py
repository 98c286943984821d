"""Population-evaluation speed: straightforward vs NumPy-vectorized vs hystfit's kernels.

Run:  python benchmarks/bench_kernels.py [--pop 200] [--samples 5000] [--markdown]
(or ``python benchmarks/speed.py``, which adds the end-to-end timings and checks the targets)

Measures, in one run and on the same capture (raised cosine 0→60 V, 10 Hz, 10 kHz) and the same
population of random parameter vectors inside the default bounds, for the models ``pi``
(10 operators) and ``bw``:

(a) the straightforward implementation (``benchmarks/straightforward.py``: a Python loop over
    time for each candidate; measured on a few candidates and scaled, a population takes minutes),
(b) NumPy vectorized over the population (time loop in Python),
(c) hystfit's simulation, as ``hystfit simulate`` and the Jacobians call it
    (``model.simulator(u, dt)``, then θ (P, d) → y (P, N)),
(d) hystfit's objective, as every optimizer calls it (:class:`hystfit.objective.Objective`:
    θ (P, d) → mean squared error (P,)). For ``bw`` that is the fused kernel that accumulates
    the squared error in the time loop; for ``pi`` with fixed thresholds the exact quadratic
    form of the linear model (no time loop at all per candidate: structure, not speed).

Plus ``pi2`` (paper 000's generalized PI followed by a second-order stage, joint route: f_n and
ζ searched with the hysteresis; one fused kernel for plays, stage and error) on (c) and (d). Prints evaluations/s, sample-steps/s
(candidates × samples per second) and the ratios. The results agree with the reference
implementations (checked on three candidates before timing).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import straightforward as sf  # noqa: E402

from hystfit.models.bw import BoucWen  # noqa: E402
from hystfit.models.pi import PI  # noqa: E402
from hystfit.models.pi2 import PI2  # noqa: E402
from hystfit.objective import Objective, Series  # noqa: E402
from hystfit.params import DataScale  # noqa: E402


def best_time(fn, repeat: int = 5, min_time: float = 0.2) -> float:
    """Best wall time of fn() over `repeat` rounds (each round at least min_time, averaged)."""
    best = np.inf
    for _ in range(repeat):
        n, t0 = 0, time.perf_counter()
        while True:
            fn()
            n += 1
            el = time.perf_counter() - t0
            if el >= min_time:
                break
        best = min(best, el / n)
    return best


def capture(N: int, fs: float = 10_000.0):
    t = np.arange(N) / fs
    return 30.0 * (1 - np.cos(2 * np.pi * 10 * t)), 1 / fs


def _population(model, scale, P, rng):
    ps = model.params(scale)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    return lo + rng.random((P, len(ps))) * (hi - lo), np.array([p.default for p in ps])


def measure(P: int = 200, N: int = 5000, seed: int = 0) -> list[dict]:
    """Seconds per population evaluation of each approach, per model (NaN: not measured)."""
    u, dt = capture(N)
    rng = np.random.default_rng(seed)
    scale = DataScale.from_arrays([u], [0.3 * u], [dt])
    rows = []
    k = 3  # candidates of the straightforward loop (scaled to P)

    pi = PI(10).adapt(scale)
    theta, default = _population(pi, scale, P, rng)
    y = pi.simulate_one(default, u, dt)
    sim, obj = pi.simulator(u, dt), Objective(pi, [Series(u, y, dt)])
    sim(theta), obj(theta)  # compile / warm up
    np.testing.assert_allclose(sim(theta[:3]), sf.pi_numpy(theta[:3], u, pi.r), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(sf.pi_one(theta[0], u, pi.r), sf.pi_numpy(theta[:1], u, pi.r)[0], rtol=1e-12)
    rows.append({"model": "pi (10 operators)",
                 "straightforward": best_time(lambda: [sf.pi_one(th, u, pi.r) for th in theta[:k]], 1, 0.0) / k * P,
                 "numpy": best_time(lambda: sf.pi_numpy(theta, u, pi.r), 2, 0.0),
                 "simulate": best_time(lambda: sim(theta)), "objective": best_time(lambda: obj(theta))})

    bw = BoucWen()
    theta, default = _population(bw, scale, P, rng)
    y = bw.simulate_one(default, u, dt)
    sim, obj = bw.simulator(u, dt), Objective(bw, [Series(u, y, dt)])
    sim(theta), obj(theta)
    # at the defaults, the straightforward explicit Euler and hystfit's exact integration agree to
    # the Euler error (random candidates can make Euler diverge where the exact solution does not)
    np.testing.assert_allclose(sim(default[None, :])[0], sf.bw_numpy(default[None, :], u)[0], rtol=0,
                               atol=1e-3 * np.ptp(y))
    rows.append({"model": "bw",
                 "straightforward": best_time(lambda: [sf.bw_one(th, u) for th in theta[:k]], 1, 0.0) / k * P,
                 "numpy": best_time(lambda: sf.bw_numpy(theta, u), 2, 0.0),
                 "simulate": best_time(lambda: sim(theta)), "objective": best_time(lambda: obj(theta))})

    pi2 = PI2(10, identification="joint").adapt(scale)
    theta, default = _population(pi2, scale, P, rng)
    y = pi2.simulate_one(default, u, dt)
    sim, obj = pi2.simulator(u, dt), Objective(pi2, [Series(u, y, dt)])
    sim(theta), obj(theta)
    rows.append({"model": "pi2 (generalized PI + 2nd-order stage)", "straightforward": np.nan, "numpy": np.nan,
                 "simulate": best_time(lambda: sim(theta)), "objective": best_time(lambda: obj(theta))})
    for r in rows:
        r.update(P=P, N=N)
    return rows


def _fmt(x: float, spec: str) -> str:
    return "–" if not np.isfinite(x) else format(x, spec)


def table(rows: list[dict], markdown: bool) -> str:
    hdr = ("model", "straightforward evals/s", "numpy evals/s", "hystfit simulate evals/s",
           "hystfit objective evals/s", "objective sample-steps/s", "objective / straightforward",
           "objective / numpy")
    lines = []
    for r in rows:
        P, N = r["P"], r["N"]
        lines.append((r["model"], _fmt(P / r["straightforward"], ",.0f"), _fmt(P / r["numpy"], ",.0f"),
                      f"{P / r['simulate']:,.0f}", f"{P / r['objective']:,.0f}",
                      f"{P * N / r['objective'] / 1e9:.2f} G",
                      _fmt(r["straightforward"] / r["objective"], ",.0f") + "×",
                      _fmt(r["numpy"] / r["objective"], ",.0f") + "×"))
    if markdown:
        out = ["| " + " | ".join(hdr) + " |", "|---|" + "---:|" * (len(hdr) - 1)]
        out += ["| " + " | ".join(ln) + " |" for ln in lines]
    else:
        widths = [max(len(h), *(len(ln[i]) for ln in lines)) for i, h in enumerate(hdr)]
        out = ["  ".join(h.rjust(w) for h, w in zip(hdr, widths))]
        out += ["  ".join(v.rjust(w) for v, w in zip(ln, widths)) for ln in lines]
    return "\n".join(out).replace("–×", "–")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pop", type=int, default=200)
    ap.add_argument("--samples", type=int, default=5000)
    ap.add_argument("--markdown", action="store_true", help="print a Markdown table")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rows = measure(args.pop, args.samples, args.seed)
    print(f"population P = {args.pop}, capture N = {args.samples} samples; evaluations/s = P / time per "
          f"population evaluation; sample-steps/s = P·N / time")
    print(table(rows, args.markdown))


if __name__ == "__main__":
    main()
