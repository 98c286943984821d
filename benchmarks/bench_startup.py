"""What a command pays before it computes anything: imports, numba's context, each cached kernel.

Run:  python benchmarks/bench_startup.py [--repeat 5]

Each step is timed in a fresh process (best of the repeats; its own wall and CPU time), in the order
a fitting command meets them:

- ``numpy``, the command line (typer builds pydantic validators for the options it parses),
  hystfit's registries (every model, optimizer and block class; no numba),
- ``import numba`` — done by the first kernel that runs (:mod:`hystfit._jit`),
- numba's context (its typing and lowering registries, which import ``scipy.linalg``) — loaded by
  the first cached kernel a process calls, before it can load that kernel's machine code,
- a cached kernel's index and data files (``play_matrix``), and a second one
  (``play_matrix_from``), which is all a further kernel costs,
- pandas and matplotlib, for comparison (a report table, the figure process).

Then the figure server's own import (:func:`hystfit.report.render._import_plotting`: matplotlib's
figure and Agg canvas, hystfit's plots, the default font), after numpy, whole and ``lean`` (without
the 3-D toolkit, as the server imports it), alternately. The difference (≈ 0.05 s) is within the
wall-time noise of a shared machine; the last column counts it steadily where ``perf stat`` can:
the user-space instructions of the whole process (Python's start and numpy's import included).

A first run warms numba's on-disk cache. The machine is shared: compare rows within one run.
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_end_to_end import command_env  # noqa: E402

PROBE = r"""
import json, time
marks = []
def mark(name):
    marks.append((name, time.perf_counter(), time.process_time()))
mark("start")
import numpy as np
mark("import numpy")
import hystfit.cli
mark("import hystfit.cli (typer, the commands)")
try:  # typer versions that build pydantic validators import them here; others have no such module
    import typer._adapters
except ImportError:
    pass
mark("typer's pydantic validators (where typer has them)")
from hystfit.registry import blocks, models, optimizers
models.names(), optimizers.names(), blocks.names()
mark("hystfit registries (models, optimizers, blocks)")
import hystfit._jit as jit
jit._load_numba()
mark("import numba")
from hystfit.models import _kernels as K
from hystfit.blocks import delay as D
u = np.sin(np.linspace(0.0, 20.0, 5001)); r = np.linspace(0.0, 1.0, 10)
K._play_recurrence.dispatcher().targetctx.refresh()
mark("numba context (registries, scipy.linalg)")
K._play_recurrence(u, r, np.zeros(10))
mark("first cached kernel: the play recurrence (index + data)")
D._delay_rows(np.ones((100, 3)), 2, 0.5)
mark("second cached kernel: the delay's row shift")
import pandas
mark("import pandas (report tables)")
import matplotlib.pyplot
mark("import matplotlib.pyplot (figure process)")
print(json.dumps([(n, t, c) for n, t, c in marks]))
"""


def probe() -> list[tuple[str, float, float]]:
    """One fresh process: (step, wall s, CPU s) of each step."""
    # the bytecode cache on, as an installed hystfit has it
    env = {**command_env(), "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    out = subprocess.run([sys.executable, "-c", PROBE], cwd=ROOT, env=env, check=True, capture_output=True,
                         text=True).stdout
    marks = json.loads(out.strip().splitlines()[-1])
    return [(name, t - marks[i][1], c - marks[i][2]) for i, (name, t, c) in enumerate(marks[1:])]


def measure(repeat: int = 5) -> list[dict]:
    probe()  # warm numba's cache
    runs = [probe() for _ in range(repeat)]
    return [{"step": name, "wall_s": min(r[i][1] for r in runs), "cpu_s": min(r[i][2] for r in runs)}
            for i, (name, _, _) in enumerate(runs[0])]


FIGURE_PROBE = r"""
import json, sys, time
import numpy
t, c = time.perf_counter(), time.process_time()
from hystfit.report.render import _import_plotting
_import_plotting(lean=sys.argv[1] == "lean")
print(json.dumps([time.perf_counter() - t, time.process_time() - c]))
"""


def figure_imports(repeat: int = 5) -> dict[str, tuple[float, float, float | None]]:
    """Best (wall s, CPU s) of the figure server's import, ``whole`` and ``lean``, fresh processes,
    and the median user-space instructions of the whole process (numpy's import and Python's start
    included; None where ``perf stat`` cannot count)."""
    from command_ab import perf_counts

    count = perf_counts()
    env = {**command_env(), "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    runs: dict[str, list] = {"whole": [], "lean": []}
    for _ in range(repeat + 1):  # the first pair warms the bytecode cache
        for way in runs:
            with tempfile.TemporaryDirectory() as tmp:
                cmd = [sys.executable, "-c", FIGURE_PROBE, way]
                if count:
                    cmd = ["perf", "stat", "-x,", "-e", "instructions:u", "-o", f"{tmp}/perf.csv", "--", *cmd]
                out = subprocess.run(cmd, cwd=ROOT, env=env, check=True, capture_output=True, text=True).stdout
                wall, cpu = json.loads(out.strip().splitlines()[-1])
                n = None
                if count:
                    rows = [r.split(",") for r in Path(f"{tmp}/perf.csv").read_text().splitlines() if "instructions" in r]
                    n = float(rows[0][0]) if rows and rows[0][0].isdigit() else None
            runs[way].append((wall, cpu, n))
    out: dict[str, tuple[float, float, float | None]] = {}
    for way, r in runs.items():
        ns = [n for _, _, n in r[1:] if n is not None]
        out[way] = (min(w for w, _, _ in r[1:]), min(c for _, c, _ in r[1:]), statistics.median(ns) if ns else None)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print(f"Load average at the start {os.getloadavg()[0]:.1f}; best of {args.repeat} fresh processes\n")
    print("| step | wall (s) | CPU (s) |\n|---|---:|---:|")
    for row in measure(args.repeat):
        print(f"| {row['step']} | {row['wall_s']:.3f} | {row['cpu_s']:.3f} |")
    print("\n| the figure server's import | wall (s) | CPU (s) | instructions of the process (G, median) |")
    print("|---|---:|---:|---:|")
    for way, (wall, cpu, n) in figure_imports(args.repeat).items():
        print(f"| {way} | {wall:.3f} | {cpu:.3f} | {'–' if n is None else f'{n / 1e9:.3f}'} |")


if __name__ == "__main__":
    main()
