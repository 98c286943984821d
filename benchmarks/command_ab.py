"""Any hystfit command from this tree against another tree (e.g. a worktree of an older commit), alternately.

Run:  git worktree add --detach /tmp/old REV
      python benchmarks/command_ab.py --other /tmp/old [--repeat 4] -- compare sample_data --models all --opts auto

Each run is a fresh process (``python -c "from hystfit.cli import main; main()" ARGS --out TMP --quiet``)
with the tree's directory first on ``PYTHONPATH`` and the bytecode cache on (as an installed hystfit
has it); it runs from a temporary directory, so that neither tree's checkout shadows the other
through the current directory, and relative data paths are taken from this tree. The first run of
each tree is a warm-up (numba compiles a tree's kernels once: its cache is keyed by the source
path) and is not counted. Printed: every run's wall time and CPU seconds (of every process the
command started, its pools' fork server and figure server included: they are adopted and reaped
here), the best and median wall time and the median CPU time of each tree. Both trees are measured
at the same moments of a shared machine, so their ratio is what to read; the CPU time moves less
with the load than the wall time.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_end_to_end as e2e  # noqa: E402


def _children_cpu_s() -> float:
    e2e.reap_orphans()
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run(tree: Path, args: list[str]) -> tuple[float, float]:
    """Wall time and CPU seconds (every process of the command: :func:`bench_end_to_end.adopt_orphans`)."""
    env = {**e2e.command_env(), "PYTHONPATH": str(tree)}
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-c", "from hystfit.cli import main; main()", *args, "--out", str(Path(tmp) / "out"),
               "--quiet"]
        cpu0, t0 = _children_cpu_s(), time.perf_counter()
        subprocess.run(cmd, cwd=tmp, env=env, check=True, stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        return wall, _children_cpu_s() - cpu0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--other", type=Path, required=True, help="the other tree (its directory holds hystfit/)")
    ap.add_argument("--repeat", type=int, default=4)
    ap.add_argument("args", nargs=argparse.REMAINDER, help="-- then the command and its arguments")
    ns = ap.parse_args()
    args = ns.args[1:] if ns.args[:1] == ["--"] else ns.args
    # data paths relative to this tree (the runs start in a temporary directory)
    args = [str(ROOT / a) if (ROOT / a).exists() and not a.startswith("-") else a for a in args]
    trees = {"this tree": ROOT, "other": ns.other.resolve()}
    e2e.adopt_orphans()
    for tree in trees.values():
        run(tree, args)  # warm-up: bytecode and numba caches
    walls: dict[str, list[tuple[float, float]]] = {name: [] for name in trees}
    for _ in range(ns.repeat):
        for name, tree in trees.items():
            walls[name].append(run(tree, args))
    print(f"`hystfit {' '.join(args)}`, {ns.repeat} runs each, alternately\n")
    print("| tree | best wall (s) | median wall (s) | median CPU (s) | every run: wall / CPU (s) |")
    print("|---|---:|---:|---:|---|")
    for name, tree in trees.items():
        w = [x for x, _ in walls[name]]
        c = [y for _, y in walls[name]]
        runs = ", ".join(f"{x:.2f} / {y:.1f}" for x, y in walls[name])
        print(f"| {name} ({tree}) | {min(w):.2f} | {statistics.median(w):.2f} | {statistics.median(c):.1f} | {runs} |")


if __name__ == "__main__":
    main()
