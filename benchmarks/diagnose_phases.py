"""Where the time of ``hystfit diagnose`` goes, phase by phase, and what the parallel parts cost.

Run:  python benchmarks/diagnose_phases.py [DATA] [--model pi] [--mode timeline|ahead|forks|figures|parallel] [--repeat 4]

- ``timeline`` (default): the command (``diagnose DATA --model M --out TMP --quiet``) run in this
  process once, with every phase's start and end in seconds since the start: loading, the base fits, the
  base's resolution, each selection step, each resolution check, the recommended model's fit and
  the writing of the outputs (which waits for the figures). The first base fit includes numba's
  first kernel load and the ``scipy.optimize`` import. Beside each phase, the machine's busy cores
  on average over it (``/proc/stat`` every 50 ms, read by a separate process: a thread in this
  one would change what is measured, since the command forks its figure server and reads its
  captures aside only while it runs no thread). On an otherwise idle 2-core machine, 2.0 means
  both cores worked throughout; less is time a core waited for a serial part.
- ``ahead``: the diagnosis in this process (no figures), alternately with and without the refit of
  a resolution check's next doubling computed ahead in a forked child (``diagnose._speculate``),
  ``--repeat`` times each: the seconds of the resolution checks and of the whole diagnosis.
- ``forks``: one ``fork_map`` round trip with a trivial item in this process after a diagnosis (its
  data, numba and scipy loaded): the fork, the child's start and reply, its exit and reaping.
- ``parallel``: the diagnosis in this process (no figures, warm: its kernels loaded, its imports
  done), alternately on one process and on every core, ``--repeat`` times each: wall seconds and
  CPU seconds (this process and its forked children). Serial CPU against parallel wall is how much
  the forks gain; parallel CPU against serial CPU is what they cost (copy-on-write faults, child
  start-up and the parent's waits are not in the serial run).
- ``figures``: the CPU seconds of each figure of the diagnosis, drawn twice in this process (the
  first as a freshly forked worker would, the second with its caches filled), and, in a fresh
  process, the figure server's matplotlib import and warm-up; then all of them ``--repeat`` times,
  alternately with the garbage collector walking every object of this process and with the
  objects imported so far frozen out of it (:func:`gc.freeze`), as the figure server does.

The machine is shared: compare numbers of one run, and alternate runs (``ahead`` does).
"""

from __future__ import annotations

import argparse
import gc
import importlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]

PHASES = [("hystfit.io", "load_captures"), ("hystfit.diagnose", "_all_base_fits"), ("hystfit.diagnose", "converge_resolution"),
          ("hystfit.diagnose", "_step_results"), ("hystfit.diagnose", "resolution_check_converged"),
          ("hystfit.diagnose", "diagnose"), ("hystfit.diagnose", "fit_recommended"),
          ("hystfit.report.diagnose_report", "write_diagnose_outputs")]


def _timed(module: str, name: str, log: list, t0: float) -> None:
    mod = importlib.import_module(module)
    fn = getattr(mod, name)

    def wrapper(*a, **k):
        t = time.perf_counter()
        try:
            return fn(*a, **k)
        finally:
            log.append((name, t - t0, time.perf_counter() - t0))

    setattr(mod, name, wrapper)


#: a separate process that prints the machine's busy cores every 50 ms (for :func:`timeline`)
_MONITOR = """
import sys, time
def stat():
    with open('/proc/stat') as f:
        v = [int(x) for x in f.readline().split()[1:]]
    return sum(v), v[3] + v[4]
prev = stat()
while True:
    time.sleep(0.05)
    cur = stat()
    total, busy = cur[0] - prev[0], (cur[0] - prev[0]) - (cur[1] - prev[1])
    prev = cur
    print(time.time(), {cores} * busy / total if total else 0.0, flush=True)
"""


def _busy_cores(samples: list[tuple[float, float]], a: float, b: float) -> str:
    inside = [c for t, c in samples if a <= t <= b]
    return f"{sum(inside) / len(inside):.2f}" if inside else "–"


def timeline(data: str, model: str) -> None:
    monitor = None
    if Path("/proc/stat").exists():
        out = tempfile.NamedTemporaryFile("w+", suffix=".busy", delete=False)
        monitor = subprocess.Popen([sys.executable, "-c", _MONITOR.format(cores=os.cpu_count() or 1)], stdout=out)
    wall0 = time.time()
    t0 = time.perf_counter()
    from hystfit.cli import main

    log: list = [("import hystfit.cli", 0.0, time.perf_counter() - t0)]
    for module, name in PHASES:
        _timed(module, name, log, t0)
    with tempfile.TemporaryDirectory() as tmp:
        sys.argv = ["hystfit", "diagnose", data, "--model", model, "--out", str(Path(tmp) / "out"), "--quiet"]
        try:
            main()
        except SystemExit as exc:
            if exc.code:
                raise
    end = time.perf_counter() - t0
    samples: list[tuple[float, float]] = []
    if monitor is not None:
        monitor.terminate()
        monitor.wait()
        out.seek(0)
        samples = [(float(t) - wall0, float(c)) for t, c in (ln.split() for ln in out if ln.strip())]
        out.close()
        os.unlink(out.name)
    print(f"`hystfit diagnose {data} --model {model}` in this process, {end:.2f} s\n")
    print("| phase | from (s) | to (s) | seconds | busy cores |\n|---|---:|---:|---:|---:|")
    for name, a, b in sorted(log, key=lambda r: r[1]):
        print(f"| {name} | {a:.2f} | {b:.2f} | {b - a:.2f} | {_busy_cores(samples, a, b)} |")


def _diagnose_once(caps, model, opt):
    import hystfit.diagnose as D

    t = time.perf_counter()
    D.diagnose(caps, model, opt, seed=0)
    return time.perf_counter() - t


def ahead(data: str, model_name: str, repeat: int) -> None:
    import hystfit.diagnose as D
    from hystfit.factory import make_model, make_optimizer
    from hystfit.io import LoadOptions, load_captures
    from hystfit.registry import optimizers

    caps = load_captures([Path(data)], LoadOptions())
    model, opt = make_model(model_name, {}), make_optimizer(optimizers.get("auto"), {})
    D.diagnose(caps, model, opt, seed=0)  # warm-up
    checks = {"s": 0.0}
    converged = D.resolution_check_converged

    def timed(*a, **k):
        t = time.perf_counter()
        try:
            return converged(*a, **k)
        finally:
            checks["s"] += time.perf_counter() - t

    D.resolution_check_converged = timed
    speculate = D._speculate
    rows = {True: [], False: []}
    for _ in range(repeat):
        for on in (True, False):
            D._speculate = speculate if on else (lambda *a, **k: None)
            checks["s"] = 0.0
            rows[on].append((_diagnose_once(caps, model, opt), checks["s"]))
    D._speculate = speculate
    print(f"diagnose {data} --model {model_name} in this process, no figures, {repeat} alternate runs each\n")
    print("| next doubling's refit | resolution checks, mean (s) | diagnosis, mean (s) | every run: diagnosis / checks (s) |")
    print("|---|---:|---:|---|")
    for on in (True, False):
        r = rows[on]
        print(f"| {'computed ahead' if on else 'after the check'} | {sum(c for _, c in r) / len(r):.2f} | "
              f"{sum(t for t, _ in r) / len(r):.2f} | {', '.join(f'{t:.2f} / {c:.2f}' for t, c in r)} |")


def forks(data: str, model_name: str, repeat: int) -> None:
    import multiprocessing as mp
    import resource

    import hystfit.diagnose as D
    import hystfit.parallel as P
    from hystfit.factory import make_model, make_optimizer
    from hystfit.io import LoadOptions, load_captures
    from hystfit.registry import optimizers

    caps = load_captures([Path(data)], LoadOptions())
    D.diagnose(caps, make_model(model_name, {}), make_optimizer(optimizers.get("auto"), {}), seed=0)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"after a diagnosis of {data}: {rss:.0f} MB resident at most\n")
    print("| run | fork_map, 2 trivial items (ms) | fork (ms) | child start + reply (ms) | exit + reap (ms) |")
    print("|---|---:|---:|---:|---:|")
    for i in range(repeat):
        t = time.perf_counter()
        P.fork_map(lambda k: k, 2, 2)
        whole = time.perf_counter() - t
        claim = mp.get_context("fork").Value("l", 0)
        t0 = time.perf_counter()
        pid, conn = P._fork_one(lambda k: k, 1, claim)
        t1 = time.perf_counter()
        conn.recv()
        t2 = time.perf_counter()
        os.waitpid(pid, 0)
        t3 = time.perf_counter()
        conn.close()
        print(f"| {i + 1} | {1e3 * whole:.1f} | {1e3 * (t1 - t0):.1f} | {1e3 * (t2 - t1):.1f} | {1e3 * (t3 - t2):.1f} |")


def figures(data: str, model_name: str, repeat: int) -> None:
    import hystfit.diagnose as D
    from hystfit.factory import make_model, make_optimizer
    from hystfit.io import LoadOptions, load_captures
    from hystfit.registry import optimizers
    from hystfit.report import diagnose_report, render

    probe = ("import time; t = time.perf_counter(); from hystfit.report import render; render._import_plotting(); "
             "t1 = time.perf_counter(); render._warm_up(); t2 = time.perf_counter(); "
             "print(f'{t1 - t:.2f} {t2 - t1:.2f}')")
    imp, warm = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True,
                               cwd=ROOT).stdout.split()
    print(f"figure server in a fresh process: matplotlib imported in {imp} s, warm-up {warm} s\n")
    caps = load_captures([Path(data)], LoadOptions())
    d = D.diagnose(caps, make_model(model_name, {}), make_optimizer(optimizers.get("auto"), {}), seed=0)
    render._import_plotting()
    render._warm_up()
    with tempfile.TemporaryDirectory() as tmp:
        jobs = diagnose_report.start_figures(d, Path(tmp) / "figures", n_jobs=1).stream.jobs
        print("| figure | first drawing, CPU (s) | second, CPU (s) |\n|---|---:|---:|")
        for job in jobs:
            cpu = []
            for _ in range(2):
                t = time.process_time()
                render._render(job)
                cpu.append(time.process_time() - t)
            print(f"| {job.function.rpartition(':')[2]} | {cpu[0]:.3f} | {cpu[1]:.3f} |")
        # the garbage collector walking every object of this process at a full collection, against
        # the objects imported so far frozen out of it as the figure server does (render._serve)
        total = {}
        for _ in range(repeat):
            for frozen in (False, True):
                gc.freeze() if frozen else gc.unfreeze()
                t = time.process_time()
                for job in jobs:
                    render._render(job)
                total.setdefault(frozen, []).append(time.process_time() - t)
        gc.unfreeze()
        print(f"\nevery figure, drawn {repeat} times each way alternately, CPU (s): collector walking every object "
              f"{statistics.median(total[False]):.2f} (median), its imports frozen out of it "
              f"{statistics.median(total[True]):.2f}")


def parallel(data: str, model_name: str, repeat: int) -> None:
    import resource

    import hystfit.diagnose as D
    import hystfit.parallel as P
    from hystfit.factory import make_model, make_optimizer
    from hystfit.io import LoadOptions, load_captures
    from hystfit.registry import optimizers

    def cpu() -> float:
        a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime

    caps = load_captures([Path(data)], LoadOptions())
    model, opt = make_model(model_name, {}), make_optimizer(optimizers.get("auto"), {})
    D.diagnose(caps, model, opt, seed=0)  # warm-up
    single = P._SINGLE_THREADED
    rows = {True: [], False: []}
    try:
        for _ in range(repeat):
            for serial in (True, False):
                P._SINGLE_THREADED = serial or single
                c, t = cpu(), time.perf_counter()
                D.diagnose(caps, model, opt, seed=0)
                rows[serial].append((time.perf_counter() - t, cpu() - c))
    finally:
        P._SINGLE_THREADED = single
    print(f"diagnose {data} --model {model_name} in this process, no figures, warm, {repeat} alternate runs each\n")
    print("| processes | wall, median (s) | CPU, median (s) | every run: wall / CPU (s) |\n|---|---:|---:|---|")
    for serial in (True, False):
        r = rows[serial]
        print(f"| {'one' if serial else 'every core'} | {statistics.median(w for w, _ in r):.2f} | "
              f"{statistics.median(c for _, c in r):.2f} | {', '.join(f'{w:.2f} / {c:.2f}' for w, c in r)} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=str(ROOT / "sample_data"))
    ap.add_argument("--model", default="pi")
    ap.add_argument("--mode", choices=["timeline", "ahead", "forks", "figures", "parallel"], default="timeline")
    ap.add_argument("--repeat", type=int, default=4)
    args = ap.parse_args()
    if args.mode == "timeline":
        timeline(args.data, args.model)
    elif args.mode == "ahead":
        ahead(args.data, args.model, args.repeat)
    elif args.mode == "forks":
        forks(args.data, args.model, args.repeat)
    elif args.mode == "parallel":
        parallel(args.data, args.model, args.repeat)
    else:
        figures(args.data, args.model, args.repeat)


if __name__ == "__main__":
    main()
