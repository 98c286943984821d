"""How ``auto``'s ``restarts`` trade fitting time against RMSE, on data nobody tuned it on.

Run:  python benchmarks/restarts.py [--models gpi,pi2,lugre,dahl,ch] [--restarts 1,2,3] [--seeds 0,1]
                                    [--jobs 2] [--data DIR ...] [--work DIR] [--other TREE]

Without ``--data`` the data sets are: the shipped ``sample_data`` (24 conditions), two synthetic
campaigns written by ``hystfit synth campaign`` (seed 7, every effect at 1.5× strength; seed 3,
asymmetry + dynamics + noise), the shipped real capture (150 V, 1 Hz, 50,000 samples) and four
rising-amplitude sines (5, 20, 50, 100 Hz, 80 V, 6 cycles at 10 kHz, ``hystfit synth capture -e
rising-sine``). Every (model, data set, restarts, seed) is one ``identify`` (one fit per condition,
``--opt auto``) in a fresh process (one BLAS thread); ``--jobs`` of them run at once.

Printed per model and ``restarts``: the CPU seconds of the fits over all data sets, and the RMSE of
each condition against the best RMSE any run of this benchmark reached on that condition (the
geometric mean of that ratio, its median and 90th percentile, the worst, and the share of
conditions within 1 % of the best). A smaller ratio is a better fit; 1.000 everywhere means every
run found the same optimum.

``--other TREE`` runs every fit also with the hystfit of another source tree (e.g. a worktree of an
earlier commit: ``git worktree add --detach ../old 31ab6fe``, whose ``auto`` ran two searches for
m > 2 and polished the better one), in the same table (rows marked ``other``) and against the same
best RMSE; then, per ``restarts``, the geometric mean over conditions of RMSE(other) / RMSE(this)
and the CPU ratio.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

#: one identify in a fresh process; prints its CPU seconds and per-condition RMSE as JSON
CHILD = """
import json, sys, time
from pathlib import Path
from hystfit.factory import make_model, make_optimizer
from hystfit.identify import identify
from hystfit.io import load_captures
from hystfit.registry import optimizers
model, data, restarts, seed = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
caps = load_captures(sorted(Path(data).glob('*.csv')))
c0 = time.process_time()
res = identify(caps, make_model(model, {}), make_optimizer(optimizers.get('auto'), {'restarts': restarts}),
               seed=seed, jobs=1)
import hystfit
print(json.dumps({'tree': str(Path(hystfit.__file__).parent.parent), 'cpu_s': time.process_time() - c0,
                  'rmse': [next(v for k, v in f.metrics.items() if k.startswith('rmse_')) for f in res.fits],
                  'labels': [f.label for f in res.fits]}))
"""


def _hystfit(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "hystfit", *args], check=True, capture_output=True, text=True)


def default_data(work: Path) -> list[Path]:
    """The data sets of the module docstring, written under ``work`` (reused when already there)."""
    sets = [ROOT / "sample_data"]
    for name, args in (("campaign_s7_all", ["--seed", "7", "--effects", "all", "--strength", "1.5"]),
                       ("campaign_s3_asym", ["--seed", "3", "--effects", "asymmetry,dynamics,noise"])):
        d = work / name
        if not d.exists():
            _hystfit("synth", "campaign", "--out", str(d), *args)
        sets.append(d)
    real = work / "real"
    if not real.exists():
        real.mkdir(parents=True)
        for f in (ROOT / "sample_data" / "real").glob("hysteresis_v_150_1hz.csv*"):
            (real / f.name).write_bytes(f.read_bytes())
    sets.append(real)
    rising = work / "rising_sines"
    if not rising.exists():
        rising.mkdir(parents=True)
        for f in (5, 20, 50, 100):
            _hystfit("synth", "capture", str(rising / f"rs_{f}Hz.csv"), "-e", "rising-sine", "-f", str(f), "-a", "80",
                     "--cycles", "6", "--seed", str(f))
    sets.append(rising)
    return sets


def run_one(model: str, data: Path, restarts: int, seed: int, tree: Path = ROOT) -> dict:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "PYTHONPATH": str(tree)}
    # from a directory of its own: ``python -c`` puts the working directory first on sys.path, and a
    # checkout there (this one, run from its root) would shadow ``tree``
    with tempfile.TemporaryDirectory() as cwd:
        r = subprocess.run([sys.executable, "-c", CHILD, model, str(Path(data).resolve()), str(restarts), str(seed)],
                           env=env, capture_output=True, text=True, check=True, cwd=cwd)
    out = json.loads(r.stdout.strip().splitlines()[-1])
    if Path(out["tree"]).resolve() != Path(tree).resolve():
        raise RuntimeError(f"the fit imported hystfit from {out['tree']}, not from {tree}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default="gpi,pi2,lugre,dahl,ch")
    ap.add_argument("--restarts", default="1,2,3")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--data", type=Path, nargs="*", default=None, help="data folders (default: see the docstring)")
    ap.add_argument("--work", type=Path, default=None, help="where the synthetic data sets are written (kept)")
    ap.add_argument("--other", type=Path, default=None, help="another hystfit source tree to run every fit with too")
    a = ap.parse_args()
    models = a.models.split(",")
    restarts = [int(x) for x in a.restarts.split(",")]
    seeds = [int(x) for x in a.seeds.split(",")]
    trees = {"this": ROOT, **({"other": a.other.resolve()} if a.other else {})}
    work = None if a.data else (a.work or Path(tempfile.mkdtemp(prefix="hystfit-restarts-")))
    data = a.data or default_data(work)
    jobs = [(m, d, r, s, t) for m in models for d in data for r in restarts for s in seeds for t in trees]
    print(f"{len(jobs)} fits of {len(data)} data sets ({', '.join(d.name for d in data)})"
          + (f"; synthetic data in {work}" if work else ""), flush=True)
    with ThreadPoolExecutor(max(1, a.jobs)) as pool:
        results = dict(zip(jobs, pool.map(lambda j: run_one(*j[:4], trees[j[4]]), jobs)))
    for m in models:
        best: dict = {}
        for (mm, d, r, s, t), res in results.items():
            if mm == m:
                for i, v in enumerate(res["rmse"]):
                    best[(d, i)] = min(best.get((d, i), np.inf), v)
        print(f"\n{m}: RMSE / best RMSE of any run, per condition ({len(best)} conditions × {len(seeds)} seeds)")
        print(f"{'tree':>5} {'restarts':>8} {'CPU s':>8} {'gmean':>7} {'median':>7} {'p90':>7} {'worst':>7} {'within 1 %':>10}")
        for t in trees:
            for r in restarts:
                ratio = np.array([v / best[(d, i)] for (mm, d, rr, s, tt), res in results.items()
                                  if mm == m and rr == r and tt == t for i, v in enumerate(res["rmse"])])
                cpu = sum(res["cpu_s"] for (mm, d, rr, s, tt), res in results.items() if mm == m and rr == r and tt == t)
                print(f"{t:>5} {r:>8} {cpu:>8.1f} {np.exp(np.mean(np.log(ratio))):>7.3f} {np.median(ratio):>7.3f} "
                      f"{np.quantile(ratio, 0.9):>7.3f} {ratio.max():>7.3f} {np.mean(ratio < 1.01):>10.2f}")
        if "other" in trees:
            for r in restarts:
                pairs = [(results[(m, d, r, s, "other")], results[(m, d, r, s, "this")]) for d in data for s in seeds]
                q = np.concatenate([np.asarray(o["rmse"]) / np.asarray(h["rmse"]) for o, h in pairs])
                cpu = sum(o["cpu_s"] for o, _ in pairs) / sum(h["cpu_s"] for _, h in pairs)
                print(f"restarts {r}: RMSE other / this, geometric mean {np.exp(np.mean(np.log(q))):.4f} "
                      f"(worse by > 1 %: {np.sum(q > 1.01)}, better by > 1 %: {np.sum(q < 0.99)} of {q.size}); "
                      f"CPU other / this {cpu:.2f}")


if __name__ == "__main__":
    main()
