"""Where the wall time of ``hystfit diagnose sample_data --model pi`` goes: main process against its children.

Run:  python benchmarks/diagnose_speed.py [--repeat 3] [--other PYTHONPATH_OF_ANOTHER_TREE] [--blas-threads N]

Each run is a fresh process (imports included). Printed per run and as the best of ``--repeat``:
the wall time, the CPU seconds of the main process and of its children (the forked processes that
refit the candidates of a selection step, the figure workers). On a shared machine the wall time
follows the load; the main process's CPU time does not, and on an idle machine with one core per
process it is close to the wall time (the children run beside it). With ``--other``, the same
command is run from that tree too, alternately, so both are measured at the same moment. With
``--blas-threads N`` every run gets ``OPENBLAS_NUM_THREADS=N`` (and ``OMP_NUM_THREADS=N``): the
diagnosis' normal equations are small matrix products (hundreds of rows by 20–85 columns, per
capture and candidate) that OpenBLAS threads slow down when the forked selection workers already
use both cores; compare ``--blas-threads 1`` with the default (OpenBLAS's own choice). Beside
each run, the CPU seconds the machine's other processes took meanwhile (``/proc/stat``, Linux): a
run beside other work (another benchmark, a test suite) measures the machine, not the tree.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_end_to_end import command_env  # noqa: E402

#: runs the command and prints its own and its children's CPU seconds and its wall time as JSON
CHILD = """
import atexit, json, resource, sys, time
t0 = time.perf_counter()
def report():
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    print(json.dumps({"wall_s": time.perf_counter() - t0, "main_cpu_s": s.ru_utime + s.ru_stime,
                      "children_cpu_s": c.ru_utime + c.ru_stime}), file=sys.stderr)
atexit.register(report)
from hystfit.cli import main
sys.argv = ["hystfit", "diagnose", sys.argv[2], "--model", "pi", "--quiet", "--out", sys.argv[1]]
main()
"""


def _busy_cpu_s() -> float | None:
    """CPU seconds the whole machine has been busy so far (``/proc/stat``; None elsewhere)."""
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:]]
    except OSError:
        return None
    return (sum(v) - v[3] - v[4]) / os.sysconf("SC_CLK_TCK")


def run_once(tree: Path, blas_threads: int | None = None) -> dict:
    busy0 = _busy_cpu_s()
    with tempfile.TemporaryDirectory() as tmp:
        # the bytecode cache on, as an installed hystfit has it
        env = {**command_env(), "PYTHONPATH": str(Path(tree).resolve())}
        if blas_threads is not None:
            env.update(OPENBLAS_NUM_THREADS=str(blas_threads), OMP_NUM_THREADS=str(blas_threads))
        # run from the temporary directory: ``python -c`` puts the working directory first on sys.path
        r = subprocess.run([sys.executable, "-c", CHILD, str(Path(tmp) / "out"), str(ROOT / "sample_data")], cwd=tmp,
                           env=env, capture_output=True, text=True, check=True)
    m = json.loads(r.stderr.strip().splitlines()[-1])
    busy1 = _busy_cpu_s()
    # the CPU the machine's other processes took meanwhile: a run beside other work is not this tree's speed
    m["others_cpu_s"] = None if busy0 is None else max(busy1 - busy0 - m["main_cpu_s"] - m["children_cpu_s"], 0.0)
    return m


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--other", type=Path, default=None, help="PYTHONPATH of another tree to measure alternately")
    ap.add_argument("--blas-threads", type=int, default=None, help="OPENBLAS_NUM_THREADS of every run (default: unset)")
    args = ap.parse_args()
    trees = {"this": ROOT, **({"other": args.other} if args.other else {})}
    runs: dict[str, list[dict]] = {k: [] for k in trees}
    print(f"OPENBLAS_NUM_THREADS: {args.blas_threads if args.blas_threads is not None else 'unset'}; "
          f"load average before: {os.getloadavg()[0]:.1f}\n")
    print("| tree | run | wall (s) | main CPU (s) | children CPU (s) | others' CPU (s) | load |\n|---|---|---|---|---|---|---|")
    for i in range(args.repeat):
        for name, tree in trees.items():
            m = run_once(tree, args.blas_threads)
            runs[name].append(m)
            others = "–" if m["others_cpu_s"] is None else f"{m['others_cpu_s']:.2f}"
            print(f"| {name} | {i + 1} | {m['wall_s']:.2f} | {m['main_cpu_s']:.2f} | {m['children_cpu_s']:.2f} | "
                  f"{others} | {os.getloadavg()[0]:.1f} |", flush=True)
    for name, ms in runs.items():
        print(f"\n{name}: median wall {statistics.median(m['wall_s'] for m in ms):.2f} s, best wall {min(m['wall_s'] for m in ms):.2f} s, best main CPU "
              f"{min(m['main_cpu_s'] for m in ms):.2f} s, best children CPU {min(m['children_cpu_s'] for m in ms):.2f} s")


if __name__ == "__main__":
    main()
