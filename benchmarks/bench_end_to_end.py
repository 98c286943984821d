"""End-to-end wall time of hystfit commands on the shipped sample data.

Run:  python benchmarks/bench_end_to_end.py [--markdown]

Each command runs once to warm numba's on-disk cache, then `--repeat` times; the best time is
reported (the machine is shared: compare rows within one run). Measured:
- `hystfit models` (start-up of a second CLI call: imports + cached kernels),
- `hystfit identify` of one condition (N = 5,001) with PSO 200 × 300 for `pi` and `bw`
  (the papers' budget: 60,000 evaluations, plus the least-squares polish),
- `hystfit identify` of one condition with `--opt auto` for `pi` and `bw`,
- `hystfit compare sample_data --models all --opts auto` (24 conditions × 10 models).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ONE = "sample_data/a60V_f10Hz.csv"

COMMANDS = [
    ("second CLI call (`hystfit models --json`)", ["models", "--json"]),
    ("identify pi, PSO 200 × 300, 1 condition", ["identify", ONE, "--model", "pi", "--opt", "pso", "--pop", "200",
                                                 "--iters", "300", "--no-plots", "--quiet", "--jobs", "1"]),
    ("identify bw, PSO 200 × 300, 1 condition", ["identify", ONE, "--model", "bw", "--opt", "pso", "--pop", "200",
                                                 "--iters", "300", "--no-plots", "--quiet", "--jobs", "1"]),
    ("identify pi, auto, 1 condition", ["identify", ONE, "--model", "pi", "--no-plots", "--quiet", "--jobs", "1"]),
    ("identify bw, auto, 1 condition", ["identify", ONE, "--model", "bw", "--no-plots", "--quiet", "--jobs", "1"]),
    ("compare sample_data, all 10 models, auto, 2 processes", ["compare", "sample_data", "--models", "all", "--opts",
                                                               "auto", "--no-figures", "--quiet"]),
]


def run(args: list[str], out: Path) -> float:
    cmd = [sys.executable, "-c", "from hystfit.cli import main; main()", *args]
    if args[0] in ("identify", "compare"):
        cmd += ["--out", str(out), "--force"]
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=ROOT, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--markdown", action="store_true")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, cmd in COMMANDS:
            out = Path(tmp) / "out"
            run(cmd, out)  # warm the JIT cache
            rep = 1 if cmd[0] == "compare" else args.repeat
            rows.append((label, min(run(cmd, out) for _ in range(rep))))
    if args.markdown:
        print("| command | wall time (s) |\n|---|---:|")
        for label, t in rows:
            print(f"| {label} | {t:.2f} |")
    else:
        for label, t in rows:
            print(f"{label:60s} {t:8.2f} s")


if __name__ == "__main__":
    main()
