"""The work of ``hystfit diagnose`` in one process: user-space instructions and cycles, this tree against another.

Run:  git worktree add --detach /tmp/old REV
      python benchmarks/diagnose_instructions.py --other /tmp/old [--repeat 2] [DATA] [--model pi]

Each run is a fresh process under ``perf stat -e instructions:u,cycles:u`` that runs the command
(``diagnose DATA --model M --no-plots --quiet --jobs 1``) with forked processes switched off
(``hystfit.parallel``'s one-process mode, as inside a pool worker): every fit, refit, placebo and
check of the diagnosis, one after the other, and nothing else — no figures, no process start-up, no
work split over processes differently from run to run. Its instruction count repeats to about
±0.05 % on this project's shared machine (``command_ab.py``'s, of the command as typed, to ±1 %):
what to read for a change that removes a little work. The trees alternate; the first run of each
is a warm-up (numba compiles a tree's kernels once) and is not counted. The numbers do not depend
on the number of processes, so ``diagnosis.json`` is the one of the command.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

RUN = r"""
import sys, tempfile
import hystfit.parallel as parallel
parallel._SINGLE_THREADED = True  # fork_map and fork_call compute in this process
from hystfit.cli import main
out = tempfile.mkdtemp()
sys.argv = ["hystfit", "diagnose", *sys.argv[1:], "--no-plots", "--quiet", "--jobs", "1", "--force", "--out", out + "/o"]
try:
    main()
except SystemExit as exc:
    if exc.code:
        raise
"""


def count(tree: Path, args: list[str]) -> tuple[float, float]:
    """(instructions, cycles) in G of one run of the diagnosis with ``tree``'s code."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env.update(PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1")
    with tempfile.TemporaryDirectory() as cwd:
        out = subprocess.run(["perf", "stat", "-x,", "-e", "instructions:u,cycles:u", sys.executable, "-c", RUN, *args],
                             cwd=cwd, env=env, capture_output=True, text=True)
    if out.returncode:
        raise SystemExit(f"{tree}: the run failed:\n{out.stderr[-2000:]}")
    got = {}
    for line in out.stderr.splitlines():
        parts = line.split(",")
        if len(parts) > 2 and parts[0].isdigit():
            got[parts[2].split(":")[0]] = int(parts[0]) / 1e9
    return got["instructions"], got["cycles"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=str(ROOT / "sample_data"))
    ap.add_argument("--model", default="pi")
    ap.add_argument("--other", type=Path, help="another tree (e.g. a git worktree of an older commit)")
    ap.add_argument("--repeat", type=int, default=2)
    a = ap.parse_args()
    args = [str(Path(a.data).resolve()), "--model", a.model]
    trees = [("this tree", ROOT)] + ([("other", a.other.resolve())] if a.other else [])
    for _, tree in trees:
        count(tree, args)  # warm-up
    runs: dict[str, list[tuple[float, float]]] = {name: [] for name, _ in trees}
    for r in range(a.repeat):
        for name, tree in (trees if r % 2 == 0 else trees[::-1]):
            runs[name].append(count(tree, args))
            print(f"{name}: {runs[name][-1][0]:.3f} G instructions, {runs[name][-1][1]:.3f} G cycles", flush=True)
    print("\n| tree | median instructions (G) | median cycles (G) |\n|---|---:|---:|")
    med = {}
    for name, tree in trees:
        med[name] = (statistics.median(i for i, _ in runs[name]), statistics.median(c for _, c in runs[name]))
        print(f"| {name} ({tree}) | {med[name][0]:.3f} | {med[name][1]:.3f} |")
    if a.other:
        print(f"\nthis tree / other: instructions {med['this tree'][0] / med['other'][0]:.4f}, "
              f"cycles {med['this tree'][1] / med['other'][1]:.4f}")


if __name__ == "__main__":
    main()
