"""creep's population kernel (``blocks.creep.creep_rows``, rows side by side) against the row-by-row
loop it replaced: the same bits, and the time of each.

Run:  python benchmarks/creep_lanes.py [--repeat 50]

The reference is the row-by-row loop (``creep_rows_one_by_one`` over every row: what
``creep_rows`` was before it ran :data:`hystfit.blocks.creep.CREEP_LANES` rows together; it still
runs its last few rows). Shapes: a finite-difference
Jacobian's population of an 80-operator ``pi+creep`` (85 rows) over captures of 700 and 1,700
samples, a PSO population (200 × 5,000), and one row. Both kernels are run alternately, best of
``--repeat`` calls each; printed as Markdown, with whether the outputs are bit for bit equal.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from hystfit.blocks.creep import CREEP_LANES, creep_rows, creep_rows_one_by_one


def rows_one_by_one(x, p, c):
    """The former ``creep_rows``: one row's recursion after the other."""
    out = x.copy()
    if x.shape[1]:
        creep_rows_one_by_one(x, p, c, out, 0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=50)
    args = ap.parse_args()
    rng = np.random.default_rng(1)
    p = np.array([math.exp(-1e-4 / tau) for tau in (0.01, 0.1, 1.0)])
    print(f"CREEP_LANES = {CREEP_LANES}, best of {args.repeat} calls each, run alternately\n")
    print("| rows × samples | one by one (ms) | side by side (ms) | speed-up | same bits |\n|---|---:|---:|---:|---|")
    for P, N in [(85, 700), (85, 1700), (200, 5000), (1, 5000)]:
        x = rng.standard_normal((P, N)).cumsum(axis=1)
        c = rng.random((P, 3)) * 0.05
        same = np.array_equal(rows_one_by_one(x, p, c).view(np.int64), creep_rows(x, p, c).view(np.int64))
        best = {rows_one_by_one: math.inf, creep_rows: math.inf}
        for _ in range(args.repeat):
            for fn in best:
                t0 = time.perf_counter()
                fn(x, p, c)
                best[fn] = min(best[fn], time.perf_counter() - t0)
        old, new = best[rows_one_by_one] * 1e3, best[creep_rows] * 1e3
        print(f"| {P} × {N:,} | {old:.3f} | {new:.3f} | {old / new:.2f}× | {'yes' if same else '**no**'} |")


if __name__ == "__main__":
    main()
