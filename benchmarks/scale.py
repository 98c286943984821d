"""Issue 16 acceptance: executors, resuming and driver memory on a synthetic 200-capture campaign.

Run:  python benchmarks/scale.py [--actuators 20] [--pop 8] [--iters 8] [--jobs 2] [--skip dask,...]

The campaign: ``--actuators`` virtual actuators (:class:`hystfit.synth.Plant`, each with its own
PI weights, offset, creep and noise seed) × 10 conditions (raised cosine 0→A, A ∈ {20, 40, 60, 80,
100} V × f ∈ {10, 40} Hz, 2 cycles at 5 kHz), one CSV each. Every step runs

    hystfit compare CAPTURES --models pi,bw,pi2 --opts auto,pso --runs 3 --pop P --iters I
                    --jobs J --no-plots --quiet --json

in a fresh process group (PSO's budget is reduced with --pop/--iters so the whole benchmark takes
minutes on two loaded cores; every fit is still a real fit), and reports:

1. local pool vs Dask (a LocalCluster of J single-threaded workers): wall time, cells per second,
   and whether compare.csv is identical apart from its wall-time columns;
2. interrupted at about half way — SIGINT to the process group (Ctrl-C), and separately SIGKILL
   of the process group — then rerun with --resume: the rerun's wall time, cells reused, and
   whether compare.csv is identical to the uninterrupted run's;
3. the driver's peak RSS (``ru_maxrss`` of the hystfit process itself, not its workers) with a
   quarter of the captures vs all of them.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# SIGINT as on a terminal (a shell script's background jobs start with it ignored, and so would we)
CHILD = ("import resource, signal, sys\n"
         "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
         "from hystfit.cli import main\n"
         "try:\n    main(sys.argv[1:])\nexcept SystemExit as exc:\n    code = exc.code\nelse:\n    code = 0\n"
         "print('PEAK_KB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)\n"
         "sys.exit(code)\n")

AMPLITUDES_V = (20, 40, 60, 80, 100)
FREQUENCIES_HZ = (10, 40)


def make_campaign(out: Path, actuators: int) -> list[Path]:
    """``actuators`` × 10 captures; actuator a has its own plant (seeded by a), written as CSV."""
    import dataclasses

    import numpy as np

    from hystfit.synth import Plant, raised_cosine, simulate_plant, write_capture

    base = Plant.default()
    paths = []
    for a in range(actuators):
        rng = np.random.default_rng([16, a])
        w = np.asarray(base.weights_um_per_V) * rng.uniform(0.85, 1.15, len(base.weights_um_per_V))
        plant = dataclasses.replace(base, weights_um_per_V=tuple(w), offset_um=float(rng.uniform(-0.2, 0.2)))
        for k, (A, f) in enumerate((A, f) for A in AMPLITUDES_V for f in FREQUENCIES_HZ):
            t, u = raised_cosine(A, f, 2, 5000.0)
            y = simulate_plant(plant, t, u, seed=1000 * a + k)
            paths.append(write_capture(out / f"act{a:02d}_a{A:03d}V_f{f:02d}Hz.csv", t, u, y))
    return paths


def command(files, out: Path, args, executor: str = "local", resume: bool = False) -> list[str]:
    cmd = [sys.executable, "-c", CHILD, "compare", *map(str, files), "--models", "pi,bw,pi2", "--opts", "auto,pso",
           "--runs", "3", "--pop", str(args.pop), "--iters", str(args.iters), "--jobs", str(args.jobs),
           "--executor", executor, "--no-plots", "--quiet", "--json", "--out", str(out), "--seed", "16"]
    return cmd + (["--resume"] if resume else [])


def run(cmd) -> tuple[float, int, str, str]:
    """Wall time, exit code, stdout, stderr of one command in its own process group."""
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, start_new_session=True)
    return time.perf_counter() - t0, r.returncode, r.stdout, r.stderr


def peak_mb(stderr: str) -> float:
    return int(stderr.split("PEAK_KB")[1].split()[0]) / 1e3 if "PEAK_KB" in stderr else float("nan")


def cells_done(out: Path) -> int:
    d = out.parent / f"{out.name}.partial" / "cells"
    return len(list(d.glob("*.pkl"))) if d.is_dir() else 0


def interrupted(cmd, out: Path, at: int, sig: int, at_s: float | None = None) -> float:
    """Start ``cmd``, send ``sig`` to its process group once ``at_s`` seconds have passed (half the
    uninterrupted run's wall time: half of the work, whatever the cells cost) or, without it, once
    ``at`` cells are stored; its wall time."""
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    while p.poll() is None and (time.perf_counter() - t0 < at_s if at_s is not None else cells_done(out) < at):
        time.sleep(0.2)
    os.killpg(p.pid, sig)
    code = p.wait()
    assert code in (130, -signal.SIGKILL), f"the interrupted run ended with exit code {code}"
    return time.perf_counter() - t0


def same_numbers(a: Path, b: Path) -> bool:
    import pandas as pd

    x, y = pd.read_csv(a / "compare.csv"), pd.read_csv(b / "compare.csv")
    cols = [c for c in x.columns if "time" not in c]
    return list(x.columns) == list(y.columns) and x[cols].equals(y[cols])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--actuators", type=int, default=20)
    ap.add_argument("--pop", type=int, default=8)
    ap.add_argument("--iters", type=int, default=8)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1, help="local/dask pairs, alternated (the machine is shared)")
    ap.add_argument("--skip", default="", help="comma-separated steps to skip: dask, sigint, sigkill, memory")
    args = ap.parse_args()
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        files = make_campaign(tmp / "data", args.actuators)
        n_cells = len(AMPLITUDES_V) * len(FREQUENCIES_HZ) * 3 * 2
        print(f"campaign: {len(files)} captures ({args.actuators} actuators × 10 conditions), {n_cells} cells × 3 "
              f"runs; PSO --pop {args.pop} --iters {args.iters}; --jobs {args.jobs}; load average "
              f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores\n", flush=True)
        print("| step | wall time (s) | cells stage (s) | cells/s in it | reused | driver peak RSS (MB) | "
              "compare.csv = local |\n|---|---:|---:|---:|---:|---:|---|", flush=True)
        ref = tmp / "local"
        w_ref = None  # wall time of the uninterrupted local run (the reference)
        for k in range(args.repeat):
            for executor in ("local", "dask"):
                if executor == "dask" and "dask" in skip:
                    continue
                out = ref if executor == "local" and k == 0 else tmp / f"{executor}-{k}"
                w, code, so, se = run(command(files, out, args, executor))
                assert code == 0, se[-2000:]
                if out == ref:
                    w_ref = w
                stage = json.loads(so)["cell_counts"]["wall_time_s"]  # the cells alone: no start-up, loading, writing
                name = "local pool" if executor == "local" else f"dask LocalCluster ({args.jobs} workers)"
                same = "(reference)" if out == ref else "identical" if same_numbers(ref, out) else "DIFFERENT"
                print(f"| {name} | {w:.1f} | {stage:.1f} | {n_cells / stage:.2f} | 0 | {peak_mb(se):.0f} | {same} |",
                      flush=True)
        for name, sig in (("SIGINT", signal.SIGINT), ("SIGKILL", signal.SIGKILL)):
            if name.lower() in skip:
                continue
            out = tmp / name
            w1 = interrupted(command(files, out, args), out, n_cells // 2, sig,
                             None if w_ref is None else 0.5 * w_ref)
            kept = cells_done(out)
            w2, code, so, se = run(command(files, out, args, resume=True))
            assert code == 0, se[-2000:]
            reused = json.loads(so)["cell_counts"]["reused"]
            stage = json.loads(so)["cell_counts"]["wall_time_s"]
            share = "" if w_ref is None else f" ({w2 / w_ref:.0%} of the uninterrupted run)"
            print(f"| {name} after {w1:.1f} s ({kept} cells stored), then --resume | {w2:.1f}{share} | {stage:.1f} | "
                  f"{(n_cells - reused) / stage:.2f} | {reused} | {peak_mb(se):.0f} | "
                  f"{'identical' if same_numbers(ref, out) else 'DIFFERENT'} |", flush=True)
        if "memory" not in skip:
            quarter = [f for f in files if int(f.name[3:5]) < max(1, args.actuators // 4)]
            out = tmp / "quarter"
            w, code, so, se = run(command(quarter, out, args))
            assert code == 0, se[-2000:]
            stage = json.loads(so)["cell_counts"]["wall_time_s"]
            print(f"| local pool, {len(quarter)} captures | {w:.1f} | {stage:.1f} | {n_cells / stage:.2f} | 0 | "
                  f"{peak_mb(se):.0f} | (other data) |", flush=True)


if __name__ == "__main__":
    main()
