"""Milliseconds per call of the gPI population kernel at 1, 13 and 50 candidates.

Run:  python benchmarks/gpi_kernel.py [--other TREE]

A polish evaluates 1 and d + 1 = 13 candidates per call, `auto`'s search 50. Inputs: sample_data's
``a40V_f10Hz.csv`` (5,001 samples, 501 levels: the envelope table route; period repeat off) and
``a60V_f30Hz.csv`` (1,667 samples, all distinct: envelopes computed in blocks ahead of the time
loop). Each figure is the best of 7 batches of 15 calls, after one call that compiles or loads the
kernel. ``--other TREE`` measures another source tree too (e.g. ``git worktree add --detach
/tmp/old REV``), in a fresh process run from a directory of its own, in the same table. Seconds
move with a shared machine's load: compare the two trees within one run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CASES = (("a40V_f10Hz", "table"), ("a60V_f30Hz", "blocks"))
SIZES = (1, 13, 50)

CHILD = r"""
import json, sys, time
import numpy as np
from hystfit.io import load_captures
import hystfit.models.gpi as G
out = {}
for name, _ in json.loads(sys.argv[2]):
    u = load_captures([f"{sys.argv[1]}/{name}.csv"])[0].u
    lv = G.input_levels(u)
    for P in json.loads(sys.argv[3]):
        rng = np.random.default_rng(0)
        a = [np.full(P, v) + rng.uniform(0, 0.01, P) for v in (1.0, 0.02, 0.0, 0.0, 1.0, 0.02, 0.0, 0.0, 0.1, 0.5)]
        z = np.empty((u.size, P))
        args = (u, lv[0], lv[1], np.empty(0), *a, 10, z, 0, P, 0)
        G._gpi_block(*args)
        best = 1e9
        for _ in range(7):
            t = time.perf_counter()
            for _ in range(15):
                G._gpi_block(*args)
            best = min(best, (time.perf_counter() - t) / 15)
        out[f"{name} {P}"] = best * 1e3
print(json.dumps(out))
"""


def measure(tree: Path) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}
    with tempfile.TemporaryDirectory() as cwd:  # python -c puts the working directory first on sys.path
        r = subprocess.run([sys.executable, "-c", CHILD, str(ROOT / "sample_data"), json.dumps(CASES),
                            json.dumps(SIZES)], env=env, cwd=cwd, capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--other", type=Path, default=None, help="another tree to measure beside this one")
    ns = ap.parse_args()
    trees = [ROOT] + ([ns.other.resolve()] if ns.other else [])
    results = [measure(t) for t in trees]
    print("| capture (route) | candidates | " + " | ".join(f"{t} (ms)" for t in trees) + " |")
    print("|---|---:|" + "---:|" * len(trees))
    for name, route in CASES:
        for P in SIZES:
            cells = " | ".join(f"{r[f'{name} {P}']:.3f}" for r in results)
            print(f"| {name} ({route}) | {P} | {cells} |")


if __name__ == "__main__":
    main()
