"""hystfit called from Python (the README's "Python API"): BLAS threads, time and numbers.

Run:  python benchmarks/library_threads.py [--repeat 2] [--calls identify,diagnose,compare,cli]

The command line sets ``OPENBLAS_NUM_THREADS`` (and its kin) to 1 before numpy loads. A program
that imports hystfit as a library does not: numpy's BLAS has a thread per core, unless the
library's entry points limit it (:func:`hystfit.parallel.one_blas_thread`). Each call is run in a
fresh process, three ways:

- ``library``: no BLAS thread variable set — what a user's script gets; the entry point limits BLAS
  to one thread for its duration;
- ``BLAS per core``: ``OPENBLAS_NUM_THREADS`` set to the number of cores — a user's explicit
  choice, which the entry point leaves alone: what every library call did before the limit;
- ``as the CLI``: ``OPENBLAS_NUM_THREADS=1`` before numpy loads, as ``hystfit`` sets it.

Printed per call and way: the best wall time of the repeats, that run's CPU seconds (this process
and its children), and whether the numbers equal those of ``as the CLI`` (a digest of the result).
The calls, on sample_data with seed 0: ``identify`` (pi, auto, each condition), ``diagnose`` (pi,
auto, global), ``compare`` (pi and bw × auto, each condition, no figures), and ``cli``: the command
line's ``diagnose sample_data --model pi --no-plots`` called through ``hystfit.cli.main`` by a
program that imported numpy first (a test suite's ``CliRunner``, a notebook), where the command
line's own ``OPENBLAS_NUM_THREADS=1`` comes too late and the library's limit must apply. The machine is shared:
compare rows within one run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
ROOT = Path(__file__).resolve().parents[1]

from bench_end_to_end import command_env  # noqa: E402

PROBE = r"""
import hashlib, json, resource, sys, time
t0, c0 = time.perf_counter(), time.process_time()
import numpy as np
from hystfit.io import load_captures
from hystfit.registry import models, optimizers
captures = load_captures(["sample_data"])
call = sys.argv[1]
if call == "identify":
    from hystfit.identify import identify
    r = identify(captures, models.get("pi")(), optimizers.get("auto")(), seed=0)
    numbers = [float(x) for f in r.fits for x in [*f.theta, f.metrics["rmse_um"]]]
elif call == "diagnose":
    from hystfit.diagnose import diagnose
    d = diagnose(captures, models.get("pi")(), optimizers.get("auto")(), seed=0)
    numbers = [repr(d.steps), d.explained_by, repr(d.resolution), repr(d.noise)]
elif call == "cli":  # the command line called from a program that imported numpy first
    import tempfile
    from hystfit.cli import main
    with tempfile.TemporaryDirectory() as tmp:
        try:
            main(["diagnose", "sample_data", "--model", "pi", "--out", tmp + "/d", "--no-plots", "--quiet"])
        except SystemExit as exc:  # typer ends the command so
            assert not exc.code, exc.code
        got = json.load(open(tmp + "/d/diagnosis.json"))
    got.pop("runtime_s", None)
    numbers = [json.dumps(got, sort_keys=True).replace(tmp, "")]
else:
    from hystfit.compare import compare
    r = compare(captures, ["pi", "bw"], ["auto"], seed=0, jobs=1)
    numbers = [(c.label, c.model, list(c.theta), [(m.fun, m.nfev) for m in c.runs]) for c in r.cells]
wall = time.perf_counter() - t0
ch = resource.getrusage(resource.RUSAGE_CHILDREN)
cpu = time.process_time() - c0 + ch.ru_utime + ch.ru_stime
digest = hashlib.sha256(repr(numbers).encode()).hexdigest()[:12]
print(json.dumps({"wall_s": wall, "cpu_s": cpu, "digest": digest}))
"""

BLAS_VARS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "OMP_NUM_THREADS")


def _env(way: str) -> dict[str, str]:
    env = {k: v for k, v in command_env().items() if k not in BLAS_VARS}
    if way == "BLAS per core":
        env["OPENBLAS_NUM_THREADS"] = str(len(os.sched_getaffinity(0)))
    elif way == "as the CLI":
        env.update({k: "1" for k in BLAS_VARS[:3]})
    return env


def _run(call: str, way: str) -> dict:
    proc = subprocess.run([sys.executable, "-c", PROBE, call], cwd=ROOT, env=_env(way), check=True,
                          stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--calls", default="identify,diagnose,compare")
    args = ap.parse_args()
    ways = ("as the CLI", "library", "BLAS per core")
    print(f"cores: {len(os.sched_getaffinity(0))}; load average at the start {os.getloadavg()[0]:.1f}\n")
    print("| call | way | wall (s) | CPU (s) | numbers as the CLI's |\n|---|---|---:|---:|---|")
    _run("identify", "as the CLI")  # warm-up: numba's cache, the bytecode cache
    for call in args.calls.split(","):
        best: dict[str, dict] = {}
        for _ in range(args.repeat):
            for way in ways:  # alternately, so that a slow phase of the machine hits every way
                got = _run(call, way)
                if way not in best or got["wall_s"] < best[way]["wall_s"]:
                    best[way] = got
        ref = best["as the CLI"]["digest"]
        for way in ways:
            b = best[way]
            same = "yes" if b["digest"] == ref else "**no**"
            print(f"| {call} | {way} | {b['wall_s']:.2f} | {b['cpu_s']:.2f} | {same} |", flush=True)
    print(f"\nload average at the end {os.getloadavg()[0]:.1f}; {time.strftime('%Y-%m-%d %H:%M')}")


if __name__ == "__main__":
    main()
