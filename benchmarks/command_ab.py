"""Any hystfit command from this tree against another tree (e.g. a worktree of an older commit), alternately.

Run:  git worktree add --detach /tmp/old REV
      python benchmarks/command_ab.py --other /tmp/old [--repeat 4] -- compare sample_data --models all --opts auto

Each run is a fresh process (``python -c "from hystfit.cli import main; main()" ARGS --out TMP --quiet``;
with ``--as-typed`` without ``--quiet``, its output to pipes, as a user's script runs it)
with the tree's directory first on ``PYTHONPATH`` and the bytecode cache on (as an installed hystfit
has it); it runs from a temporary directory, so that neither tree's checkout shadows the other
through the current directory, and relative data paths are taken from this tree. The first run of
each tree is a warm-up (numba compiles a tree's kernels once: its cache is keyed by the source
path) and is not counted; which tree runs first in a pair alternates. Printed: every run's wall time and CPU seconds (of every process the
command started, its pools' fork server and figure server included: they are adopted and reaped
here), the best and median wall time and the median CPU time of each tree. Both trees are measured
at the same moments of a shared machine, so their ratio is what to read; the CPU time moves less
with the load than the wall time.

Where ``perf stat`` can count (``perf stat -e instructions:u true`` works), every run also counts
the user-space instructions of the command and of every process it started, orphans included (a
wrapper adopts and waits for them inside ``perf stat``), and the table gives each tree's median
and the median ratio of the pairs. On this project's shared virtual machine the instruction count
of a command repeats to about ±1 % (this tree against itself, the Quickstart, three pairs: 1.004;
one process alone, ±0.5 %) where its wall time moves by ±20 %: it says whether a change does less
work, not whether the machine's scheduling of that work got better (``--no-instructions`` turns
it off). Its CPU cycles are counted beside them: a change that removes BLAS products removes
many instructions and few cycles (they retire several per cycle), so judge such a change by its
cycles.
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


#: runs its arguments as a command, adopts the processes that command leaves behind and waits for
#: them: run under ``perf stat``, their instructions are counted too
ADOPT_AND_WAIT = ("import ctypes, os, subprocess, sys\n"
                  "ctypes.CDLL(None).prctl(36, 1, 0, 0, 0)  # PR_SET_CHILD_SUBREAPER\n"
                  "code = subprocess.run(sys.argv[1:]).returncode\n"
                  "while True:\n"
                  "    try:\n"
                  "        os.waitpid(-1, 0)\n"
                  "    except ChildProcessError:\n"
                  "        break\n"
                  "sys.exit(code)\n")


def perf_counts() -> bool:
    """Whether ``perf stat`` counts user-space instructions here."""
    try:
        out = subprocess.run(["perf", "stat", "-x,", "-e", "instructions:u", "true"], capture_output=True, text=True,
                             timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return out.returncode == 0 and any(line.split(",")[0].isdigit() for line in out.stderr.splitlines())


def run(tree: Path, args: list[str], instructions: bool = False, as_typed: bool = False,
        out_name: str = "out") -> tuple[float, float, int | None, int | None]:
    """Wall time, CPU seconds (every process of the command: :func:`bench_end_to_end.adopt_orphans`)
    and, with ``instructions``, the user-space instructions and CPU cycles of them all (``perf
    stat``; cycles: what the instructions cost on this machine — BLAS products retire several
    instructions per cycle, Python's interpreter less than one).
    ``as_typed``: without ``--quiet``, its progress lines and tables printed to pipes, as a user's
    script runs it (``--quiet`` skips the progress line, and with it what that line changes)."""
    env = {**e2e.command_env(), "PYTHONPATH": str(tree)}
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-c", "from hystfit.cli import main; main()", *args, "--out", str(Path(tmp) / out_name),
               *(() if as_typed else ("--quiet",))]
        counts = Path(tmp) / "perf.csv"
        if instructions:
            cmd = ["perf", "stat", "-x,", "-e", "instructions:u,cycles:u", "-o", str(counts), "--",
                   sys.executable, "-c", ADOPT_AND_WAIT, *cmd]
        cpu0, t0 = _children_cpu_s(), time.perf_counter()
        subprocess.run(cmd, cwd=tmp, env=env, check=True, stdout=subprocess.PIPE if as_typed else subprocess.DEVNULL,
                       stderr=subprocess.PIPE if as_typed else None)
        wall = time.perf_counter() - t0
        n = c = None
        if instructions:
            rows = [line.split(",") for line in counts.read_text().splitlines()]
            n, c = (next((int(f[0]) for f in rows if len(f) > 2 and what in f[2] and f[0].isdigit()), None)
                    for what in ("instructions", "cycles"))
        return wall, _children_cpu_s() - cpu0, n, c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--other", type=Path, required=True, help="the other tree (its directory holds hystfit/)")
    ap.add_argument("--repeat", type=int, default=4)
    ap.add_argument("--no-instructions", action="store_true", help="do not count instructions with perf stat")
    ap.add_argument("--out-name", default="out",
                    help="name of the --out path in the run's temporary directory (a file for invert: v.csv)")
    ap.add_argument("--as-typed", action="store_true",
                    help="run without --quiet, output to pipes (as a user's script; default: --quiet)")
    ap.add_argument("args", nargs=argparse.REMAINDER, help="-- then the command and its arguments")
    ns = ap.parse_args()
    count = not ns.no_instructions and perf_counts()
    args = ns.args[1:] if ns.args[:1] == ["--"] else ns.args
    # data paths relative to this tree (the runs start in a temporary directory)
    args = [str(ROOT / a) if (ROOT / a).exists() and not a.startswith("-") else a for a in args]
    trees = {"this tree": ROOT, "other": ns.other.resolve()}
    e2e.adopt_orphans()
    for tree in trees.values():
        run(tree, args, as_typed=ns.as_typed, out_name=ns.out_name)  # warm-up: bytecode and numba caches
    walls: dict[str, list[tuple[float, float, int | None, int | None]]] = {name: [] for name in trees}
    for i in range(ns.repeat):
        # which tree runs first alternates (AB BA AB …): a drift of the machine, or a cache the first
        # run of a pair warms, does not favour one tree
        for name in (list(trees) if i % 2 == 0 else list(trees)[::-1]):
            walls[name].append(run(trees[name], args, count, as_typed=ns.as_typed, out_name=ns.out_name))
    how = "as typed (no --quiet, output to pipes)" if ns.as_typed else "with --quiet"
    print(f"`hystfit {' '.join(args)}`, {how}, {ns.repeat} runs each, alternately (the first of each pair alternates)\n")
    print("| tree | best wall (s) | median wall (s) | median CPU (s) | median instructions (G) | median cycles (G) "
          "| every run: wall / CPU (s) |")
    print("|---|---:|---:|---:|---:|---:|---|")
    for name, tree in trees.items():
        w = [r[0] for r in walls[name]]
        c = [r[1] for r in walls[name]]
        n = [r[2] for r in walls[name] if r[2] is not None]
        cyc = [r[3] for r in walls[name] if r[3] is not None]
        ins = f"{statistics.median(n) / 1e9:.3f}" if n else "–"
        cy = f"{statistics.median(cyc) / 1e9:.3f}" if cyc else "–"
        runs = ", ".join(f"{r[0]:.2f} / {r[1]:.1f}" for r in walls[name])
        print(f"| {name} ({tree}) | {min(w):.2f} | {statistics.median(w):.2f} | {statistics.median(c):.1f} | {ins} | {cy} "
              f"| {runs} |")
    this, other = walls["this tree"], walls["other"]
    ratios = [a[0] / b[0] for a, b in zip(this, other)]
    line = f"\nmedian ratio of the pairs (this tree / other): wall {statistics.median(ratios):.3f}"
    if count and all(a[2] and b[2] for a, b in zip(this, other)):
        line += f", instructions {statistics.median(a[2] / b[2] for a, b in zip(this, other)):.4f}"
    if count and all(a[3] and b[3] for a, b in zip(this, other)):
        line += f", cycles {statistics.median(a[3] / b[3] for a, b in zip(this, other)):.4f}"
    print(line)


if __name__ == "__main__":
    main()
