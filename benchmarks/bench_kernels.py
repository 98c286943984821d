"""Population-evaluation speed: straightforward vs NumPy-vectorized vs hystfit's kernels.

Run:  python benchmarks/bench_kernels.py [--pop 200] [--samples 5000] [--markdown]

Measures, in one run and on the same capture (raised cosine 0→60 V, 10 Hz, 10 kHz) and the same
population, for the models ``pi`` (10 operators) and ``bw``:
(a) the straightforward implementation (Python loop over time for each candidate; measured on a
    few candidates and scaled, since a whole population takes minutes),
(b) NumPy vectorized over the population (time loop in Python),
(c) hystfit's path as the optimizers call it (``model.simulator(u, dt)`` then θ (P, d) → y (P, N)).
Prints evaluations/s, sample-steps/s (candidates × samples per second) and the ratios.
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pop", type=int, default=200)
    ap.add_argument("--samples", type=int, default=5000)
    ap.add_argument("--markdown", action="store_true", help="print a Markdown table")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    P, N = args.pop, args.samples
    fs = 10_000.0
    t = np.arange(N) / fs
    u = 30.0 * (1 - np.cos(2 * np.pi * 10 * t))
    rng = np.random.default_rng(args.seed)
    scale = DataScale.from_arrays([u], [0.3 * u], [1 / fs])
    rows = []

    pi = PI(10).adapt(scale)
    ps = pi.params(scale)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    theta = lo + rng.random((P, len(ps))) * (hi - lo)
    r = pi.r
    sim = pi.simulator(u, 1 / fs)
    sim(theta)  # compile / warm up
    k = 3
    t_sf = best_time(lambda: [sf.pi_one(th, u, r) for th in theta[:k]], repeat=1, min_time=0.0) / k * P
    t_np = best_time(lambda: sf.pi_numpy(theta, u, r), repeat=2, min_time=0.0)
    t_hf = best_time(lambda: sim(theta))
    np.testing.assert_allclose(sim(theta[:3]), sf.pi_numpy(theta[:3], u, r), rtol=1e-9, atol=1e-9)
    rows.append(("pi (10 operators)", t_sf, t_np, t_hf))

    bw = BoucWen()
    ps = bw.params(scale)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    theta = lo + rng.random((P, len(ps))) * (hi - lo)
    simb = bw.simulator(u, 1 / fs)
    simb(theta)
    t_sf = best_time(lambda: [sf.bw_one(th, u) for th in theta[:k]], repeat=1, min_time=0.0) / k * P
    t_np = best_time(lambda: sf.bw_numpy(theta, u), repeat=2, min_time=0.0)
    t_hf = best_time(lambda: simb(theta))
    rows.append(("bw", t_sf, t_np, t_hf))

    print(f"population P = {P}, capture N = {N} samples; time per population evaluation, evaluations/s, "
          f"sample-steps/s = P·N/time")
    hdr = ("model", "straightforward evals/s", "numpy evals/s", "hystfit evals/s", "hystfit sample-steps/s",
           "hystfit / straightforward", "hystfit / numpy")
    lines = []
    for name, a, b, c in rows:
        lines.append((name, f"{P / a:,.0f}", f"{P / b:,.0f}", f"{P / c:,.0f}", f"{P * N / c / 1e9:.2f} G",
                      f"{a / c:,.0f}×", f"{b / c:,.0f}×"))
    if args.markdown:
        print("| " + " | ".join(hdr) + " |")
        print("|" + "---|" * len(hdr))
        for ln in lines:
            print("| " + " | ".join(ln) + " |")
    else:
        widths = [max(len(h), *(len(ln[i]) for ln in lines)) for i, h in enumerate(hdr)]
        print("  ".join(h.rjust(w) for h, w in zip(hdr, widths)))
        for ln in lines:
            print("  ".join(v.rjust(w) for v, w in zip(ln, widths)))


if __name__ == "__main__":
    main()
