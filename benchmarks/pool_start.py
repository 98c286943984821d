"""What starting a local process pool costs: workers forked from the fork server against spawned ones.

Run:  python benchmarks/pool_start.py [--repeat 5]

Each measurement is a fresh Python process (as a command is) that runs two cells on a
:class:`hystfit.parallel.LocalExecutor` of two workers: each cell identifies ``bw`` with ``auto``
on one capture of ``sample_data`` (compiled kernels, the least-squares polish). Printed per start
method, best of ``--repeat``: the wall time from the pool's creation until both cells are back,
and the CPU seconds of every process involved (the workers, the fork server, and this process's
share), counted by stopping the fork server and reaping it so its children's time is included.
``spawn`` is the start method hystfit used before (each worker a fresh interpreter that imports
numpy, scipy, numba and hystfit and sets numba up at its first kernel); ``forkserver`` is
:func:`hystfit.parallel.pool_context` (the server does that once, then forks each worker).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_end_to_end import command_env  # noqa: E402

def _cell(shared, job):
    """One cell: ``bw`` identified with ``auto`` on capture ``job`` (compiled kernels, the least-squares
    polish); its RMSE (µm)."""
    from hystfit.identify import identify
    from hystfit.registry import models, optimizers

    res = identify([shared[job]], models.get("bw")(), optimizers.get("auto")(), seed=0, jobs=1)
    return res.fits[0].metrics["rmse_um"]


def _cpu_s(who) -> float:
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def child(method: str) -> None:
    """One measurement in this (fresh) process: prints wall, CPU and the cells' RMSE as JSON."""
    import multiprocessing as mp

    import hystfit.cli  # noqa: F401 - the command line's thread settings, as a command has them
    from hystfit import parallel
    from hystfit.io import load_captures

    if method == "spawn":
        parallel.pool_context = lambda: mp.get_context("spawn")
    caps = load_captures([ROOT / "sample_data"])[:2]
    cpu0 = _cpu_s(resource.RUSAGE_SELF) + _cpu_s(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = parallel.run_cells(_cell, [0, 1], shared=tuple(caps), executor=parallel.LocalExecutor(2))
    wall = time.perf_counter() - t0
    if method == "forkserver":
        from multiprocessing import forkserver

        forkserver._forkserver._stop()  # the server exits and is reaped: its workers' CPU is counted
    used = _cpu_s(resource.RUSAGE_SELF) + _cpu_s(resource.RUSAGE_CHILDREN) - cpu0
    print(json.dumps({"wall_s": wall, "cpu_s": used, "rmse_um": out}))


def run_once(method: str) -> dict:
    env = {**command_env(), "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, __file__, "--child", method], cwd=ROOT, env=env,
                       capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--child", choices=("spawn", "forkserver"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(args.child)
    methods = ("spawn", "forkserver")
    run_once("forkserver")  # numba's on-disk cache warm
    runs: dict[str, list[dict]] = {m: [] for m in methods}
    for _ in range(args.repeat):
        for m in methods:  # alternately: both see the same moment of a shared machine
            runs[m].append(run_once(m))
    print(f"Two cells (bw, auto, one capture each) on a pool of two workers; best of {args.repeat}, alternately\n")
    print("| start method | wall (s) | CPU (s) | every wall (s) | RMSE of the cells (µm) |")
    print("|---|---:|---:|---|---|")
    for m in methods:
        best = min(runs[m], key=lambda r: r["wall_s"])
        walls = ", ".join(f"{r['wall_s']:.2f}" for r in runs[m])
        rmse = ", ".join(f"{v:.6f}" for v in best["rmse_um"])
        cpu = min(r["cpu_s"] for r in runs[m])
        print(f"| {m} | {best['wall_s']:.2f} | {cpu:.2f} | {walls} | {rmse} |")


if __name__ == "__main__":
    main()
