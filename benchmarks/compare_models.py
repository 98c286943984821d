"""CPU seconds per model of `hystfit compare DATA --models M --opts auto`, one process, one thread.

Runs the comparison's cells in this process (``--jobs 1``) with one BLAS and one numba thread, as
a pool worker runs them, after a warm-up on the shortest capture (so numba compilation is not
counted), and prints per model the CPU seconds of its cells (user + system of this process), the
evaluations per cell and the mean RMSE. CPU seconds, not wall time: on a shared machine the wall
time grows with the load, the CPU time much less. Models sharing a structure identified once for
all captures (pi2's stage) pay it here too, as the driver does.

With ``--reference OLD/compare.csv`` (a `hystfit compare` output with the same models and seed) it
also says per model whether every condition's objective, RMSE and evaluation count are identical,
and the worst ratio of a condition's RMSE to the reference's.

    python benchmarks/compare_models.py [--data sample_data] [--models pi2,fp,lugre,dahl,ch]
                                        [--reference OLD/compare.csv]

Run it from the checkout to measure (``PYTHONPATH=.``) and run two checkouts back to back to
compare them: the thread settings below must be in force before numpy and numba are imported.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from hystfit.compare import compare  # noqa: E402
from hystfit.io import expand_paths, load_captures  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="sample_data")
    ap.add_argument("--models", default="pi2,fp,lugre,dahl,ch")
    ap.add_argument("--reference", default=None, help="a compare.csv to check the numbers against")
    args = ap.parse_args()
    caps = load_captures(expand_paths([args.data]))
    shortest = min(caps, key=lambda c: c.u.shape[0])
    names = [m.strip() for m in args.models.split(",") if m.strip()]
    ref = None
    if args.reference:
        import pandas as pd

        ref = pd.read_csv(Path(args.reference))
    print("| model | CPU s (cells) | evaluations / cell | mean RMSE | identical to reference | worst RMSE ratio |")
    print("|---|---:|---:|---:|---|---:|")
    for name in names:
        compare([shortest], [name], ["auto"], jobs=1)  # warm-up: compiles (or loads) the kernels
        t0 = time.process_time()
        res = compare(caps, [name], ["auto"], jobs=1)
        cpu = time.process_time() - t0
        runs = {c.label: c.best for c in res.cells if c.ok}
        evals = np.mean([r.nfev for r in runs.values()])
        key = next(k for k in next(iter(runs.values())).metrics if k.startswith("rmse_"))  # rmse_<unit>
        rmse = {lab: r.metrics[key] for lab, r in runs.items()}
        same, worst = "–", float("nan")
        if ref is not None:
            old = ref[ref.model == name].set_index("condition")
            same = "yes" if all(lab in old.index and old.loc[lab, key] == v
                                and old.loc[lab, "evaluations"] == runs[lab].nfev
                                and old.loc[lab, "objective_mse"] == runs[lab].fun for lab, v in rmse.items()) else "no"
            worst = max(v / old.loc[lab, key] for lab, v in rmse.items() if lab in old.index)
        print(f"| {name} | {cpu:.1f} | {evals:.0f} | {np.mean(list(rmse.values())):.6g} | {same} | {worst:.6f} |",
              flush=True)


if __name__ == "__main__":
    main()
