"""What the first run after installing costs: numba compiling hystfit's kernels (nothing cached yet).

Run:  python benchmarks/first_run.py [--tree PATH] -- identify sample_data/a20V_f10Hz.csv --model bw --opt pso --no-plots
      python benchmarks/first_run.py -- compare sample_data/a20V_f10Hz.csv sample_data/a40V_f40Hz.csv \\
          --models all --opts auto --no-plots --jobs 1

The command runs once in a fresh process in ``--tree`` (default this checkout: its hystfit runs, and
relative paths are read there) with an empty numba cache directory, as on a machine where hystfit was
just installed or upgraded (numba keys its cache on the source files, so every upgrade is a first run).
Printed: the command's wall time, the seconds numba spent compiling each of hystfit's kernels (a
kernel compiled inside another is counted in the outer one only) and how many times each was
compiled — more than once means several argument types, e.g. read-only and writable arrays
(:func:`hystfit._jit.readonly`).

Only this process's compilations are seen: a command that spreads its cells over worker processes
compiles there, so give it ``--jobs 1``. ``--out`` is added (a temporary folder) for the commands
that write one, and ``--quiet``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

CHILD = r"""
import json, sys, time
from numba.core import event
t0 = time.perf_counter()
starts, depth, spent, count = {}, [0], {}, {}
class Compiles(event.Listener):
    def on_start(self, ev):
        depth[0] += 1
        starts[id(ev.data["dispatcher"]), str(ev.data["args"])] = (time.perf_counter(), depth[0])
    def on_end(self, ev):
        d = ev.data["dispatcher"].py_func
        t, level = starts.pop((id(ev.data["dispatcher"]), str(ev.data["args"])))
        depth[0] -= 1
        name = f"{d.__module__}.{d.__qualname__}"
        if name.startswith("hystfit") and level == 1:
            spent[name] = spent.get(name, 0.0) + time.perf_counter() - t
        if name.startswith("hystfit"):
            count[name] = count.get(name, 0) + 1
event.register("numba:compile", Compiles())
from hystfit.cli import main
sys.argv[0] = "hystfit"
try:
    main()  # as the console script runs it (it reads the captures aside, which a call with arguments does not)
except SystemExit as exc:
    code = exc.code
else:
    code = 0
print("FIRST_RUN " + json.dumps({"wall_s": time.perf_counter() - t0, "exit": code, "spent_s": spent,
                                  "compiled": count}), file=sys.stderr)
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", type=Path, default=ROOT, help="checkout whose hystfit runs (PYTHONPATH)")
    ap.add_argument("command", nargs=argparse.REMAINDER, help="-- then a hystfit command line")
    args = ap.parse_args()
    command = [a for a in args.command if a != "--"] if args.command[:1] == ["--"] else list(args.command)
    if not command:
        ap.error("give a hystfit command after --")
    with tempfile.TemporaryDirectory() as tmp:
        extra = ["--out", str(Path(tmp) / "out")] if command[0] in ("identify", "compare", "diagnose") else []
        env = {**os.environ, "NUMBA_CACHE_DIR": str(Path(tmp) / "numba"), "PYTHONPATH": str(args.tree.resolve())}
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        # in the tree: ``python -c`` puts its working directory first on sys.path, ahead of PYTHONPATH
        r = subprocess.run([sys.executable, "-c", CHILD, *command, *extra, "--quiet"], cwd=args.tree.resolve(), env=env,
                           capture_output=True, text=True)
    line = [ln for ln in r.stderr.splitlines() if ln.startswith("FIRST_RUN ")]
    if not line:
        sys.exit(f"the command did not finish:\n{r.stderr[-2000:]}")
    got = json.loads(line[-1][len("FIRST_RUN "):])
    print(f"tree {args.tree}: hystfit {' '.join(command)}")
    print(f"wall {got['wall_s']:.1f} s (exit {got['exit']}), compiling hystfit's kernels "
          f"{sum(got['spent_s'].values()):.1f} s")
    print("| kernel | compiled | seconds |\n|---|---:|---:|")
    for name, s in sorted(got["spent_s"].items(), key=lambda kv: -kv[1]):
        print(f"| {name} | {got['compiled'].get(name, 0)}× | {s:.1f} |")


if __name__ == "__main__":
    main()
