"""The least-squares polish's two routes against each other: scipy's trust region and the normal equations.

Run:  python benchmarks/polish_routes.py [--models gpi,pi2,lugre] [--data 'sample_data/a*.csv'] [--seed 0]

``auto`` polishes with scipy's trust-region reflective solver below
:data:`hystfit.optimizers.lsq.NORMAL_EQUATIONS_ABOVE` Jacobian elements and
:data:`~hystfit.optimizers.lsq.NORMAL_EQUATIONS_FROM_PARAMS` parameters, with the bounded
Levenberg–Marquardt on the normal equations above. This fits every capture with every model both
ways (the threshold set to 0 for the second), alternately per cell, on one BLAS thread as the
command line runs (a program with a BLAS thread per core pays ≈ 20× for each SVD on a busy 2-core
machine), and prints per cell the CPU seconds and the RMSE of each route, then per model the total
CPU and the geometric mean, best and worst of RMSE(normal equations) / RMSE(scipy).

Measured 2026-11-28 on sample_data (24 conditions, seed 0, a loaded machine): gpi 18.8 → 15.0 s,
ratio 1.059 (0.81 … 9.66: a20V_f20Hz, where the search's start lay in a poor basin and only scipy's
path left it); pi2 29.8 → 22.8 s, ratio 0.989 (0.87 … 1.006); lugre 5.9 → 5.5 s, 1.000. The default
was kept (the issue-15 note).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy: the command line's one BLAS thread

import argparse  # noqa: E402
import glob  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default="gpi,pi2,lugre")
    ap.add_argument("--data", default=str(ROOT / "sample_data" / "a*.csv"))
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    import hystfit.optimizers.lsq as lsq
    from hystfit.identify import fit_captures
    from hystfit.io import load_captures
    from hystfit.registry import models, optimizers

    files = sorted(glob.glob(args.data))
    names = args.models.split(",")
    default = lsq.NORMAL_EQUATIONS_ABOVE
    routes = (("scipy", default), ("normal equations", 0))

    def fit(caps, name, threshold):
        lsq.NORMAL_EQUATIONS_ABOVE = threshold
        try:
            t = time.process_time()
            r = fit_captures(caps, models.get(name)(), optimizers.get("auto")(), seed=args.seed)
            return time.process_time() - t, float(r.metrics["rmse_um"])
        finally:
            lsq.NORMAL_EQUATIONS_ABOVE = default

    for name in names:  # compile and load every kernel first
        for _, threshold in routes:
            fit(load_captures([files[0]]), name, threshold)
    print("| capture | model | CPU s scipy | CPU s normal eq. | RMSE scipy (µm) | RMSE normal eq. (µm) | ratio |")
    print("|---|---|---:|---:|---:|---:|---:|")
    per: dict[str, list[tuple[float, float, float]]] = {n: [] for n in names}
    for k, f in enumerate(files):
        caps = load_captures([f])
        for name in names:
            order = routes if k % 2 == 0 else routes[::-1]  # alternately: the machine drifts
            res = {label: fit(caps, name, threshold) for label, threshold in order}
            (c0, r0), (c1, r1) = res["scipy"], res["normal equations"]
            per[name].append((c0, c1, r1 / r0))
            print(f"| {Path(f).name} | {name} | {c0:.2f} | {c1:.2f} | {r0:.6f} | {r1:.6f} | {r1 / r0:.4f} |", flush=True)
    print("\n| model | CPU s scipy → normal eq. | RMSE ratio, geometric mean | best | worst |")
    print("|---|---|---:|---:|---:|")
    for name, rows in per.items():
        ratios = [r for _, _, r in rows]
        geo = math.exp(sum(math.log(r) for r in ratios) / len(ratios))
        print(f"| {name} | {sum(r[0] for r in rows):.1f} → {sum(r[1] for r in rows):.1f} | {geo:.4f} | "
              f"{min(ratios):.3f} | {max(ratios):.3f} |")


if __name__ == "__main__":
    main()
