"""User-space instructions of single figures and of the figure server's matplotlib import.

Run:  python benchmarks/figure_work.py [--other TREE] [--skip-diagnose]

Each row is measured in fresh processes with ``perf stat -e instructions:u`` (about ±1 % where
seconds move by ±20 % on a shared machine): a process that imports, warms up and draws the figure
once, against one that then draws it three times more; the difference over three is the
instructions of one figure drawn warm; the first drawing against the import and warm-up alone
gives the figure drawn first in a process (layouts and texts made), as a command's figure workers
draw most kinds. Rows:

- ``convergence`` (a PSO-like history over three decades, log axis),
- ``boxplot`` (1 − R² of ten models × 24 conditions, log axis: ``compare``'s ``r2_distribution``),
- ``heatmap`` (10 × 24 cells, log colour scale, *new numbers at every draw*: each cell text is a
  string the process has not drawn yet, as in ``compare``'s four heat maps),
- ``where_conditions`` and ``where_bands`` (``diagnose``'s log-scaled where-figures of a diagnosis
  of sample_data with ``pi``, made once here, ≈ 10 s; ``--skip-diagnose`` leaves them out),
- ``server import``: the figure server's import of matplotlib (``render._import_plotting(lean=True)``)
  as it is, and without skipping the artists' generated ``set()`` signatures
  (``render._without_set_signatures``), each minus a bare interpreter with numpy.

With ``--other TREE`` every row is measured for that tree too (its directory first on
``PYTHONPATH``, e.g. a ``git worktree add --detach /tmp/old REV``), to compare two versions.
"""

from __future__ import annotations

import argparse
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: draws figure ``argv[1]`` ``1 + argv[2]`` times after the server's import and warm-up
DRAW = r"""
import io, pickle, sys
from dataclasses import replace
from pathlib import Path
import numpy as np
from hystfit.report import render, plots
from hystfit.report import diagnose_report  # noqa: F401 - what unpickling the where-figure jobs imports
render._import_plotting(lean=True)
render._warm_up()
kind, extra, jobs = sys.argv[1], int(sys.argv[2]), sys.argv[3]
rows = ["pi", "bw", "ch", "dahl", "lugre", "fp", "nt", "gpi", "pi2", "hammerstein"]
cols = [f"{a}V_{f}Hz" for a in (20, 40, 60) for f in range(10, 90, 10)]
rng = np.random.default_rng(0)
def draw(k):
    if kind == "none":  # the import and warm-up alone: subtracted from a first drawing
        return
    if kind == "convergence":
        it = np.arange(300)
        best = 1e-3 * (1 + 100 * np.exp(-it / 40.0))
        plots.convergence_figure(io.BytesIO(), best, best * (1 + 5 * np.exp(-it / 80.0)), title="pi – 60V_10Hz")
    elif kind == "boxplot":
        groups = {m: rng.lognormal(-4, 1.2, 24) for m in rows}
        plots.boxplot_figure(io.BytesIO(), groups, title="1 − R² per model, auto", ylabel="1 − R²", log=True)
    elif kind == "heatmap":
        m = np.random.default_rng(k).lognormal(-3, 1, (10, 24))  # new numbers every draw
        plots.heatmap_figure(io.BytesIO(), m, rows, cols, title="RMSE (µm), auto", log=True,
                             colorbar_label="RMSE (µm)")
    else:
        job = pickle.load(open(jobs, "rb"))[kind]
        render._render(replace(job, path=Path(jobs).parent / f"{kind}_{k}.png"))
for k in range(1 + extra):
    draw(k)
"""

#: the server's import, as it is or (argv[1] == "signatures") with the generated signatures
IMPORT = r"""
import sys
import numpy
from hystfit.report import render
if sys.argv[1] == "signatures":
    render._without_set_signatures = lambda: None
render._import_plotting(lean=True)
"""

#: a diagnosis of sample_data with pi; its where-figure jobs pickled to argv[1]
DIAGNOSE = r"""
import pickle, sys
from pathlib import Path
from hystfit.diagnose import diagnose
from hystfit.factory import make_model, make_optimizer
from hystfit.io import LoadOptions, load_captures
from hystfit.registry import optimizers
from hystfit.report import diagnose_report
caps = load_captures([sys.argv[2]], LoadOptions())
d = diagnose(caps, make_model("pi"), make_optimizer(optimizers.get("auto")))
jobs = diagnose_report._where_jobs(d.where_figure_data, Path(sys.argv[1]).parent)
pickle.dump({"where_conditions": jobs["conditions"], "where_bands": jobs["bands"]}, open(sys.argv[1], "wb"))
"""


def instructions(tree: Path, code: str, *args: str) -> float:
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    with tempfile.TemporaryDirectory() as tmp:  # python -c puts the working directory first on sys.path
        r = subprocess.run(["perf", "stat", "-x,", "-e", "instructions:u", sys.executable, "-c", code, *args],
                           capture_output=True, text=True, cwd=tmp, env=env)
    for line in r.stderr.splitlines():
        parts = line.split(",")
        if parts[2:3] == ["instructions:u"] and parts[0].isdigit():
            return float(parts[0])
    raise RuntimeError(f"perf stat gave no count (is perf available?): {r.stderr[-2000:]}")


def rows(tree: Path, jobs: Path | None) -> dict[str, float]:
    """Row → millions of instructions, for ``tree``."""
    kinds = ["convergence", "boxplot", "heatmap"] + (["where_conditions", "where_bands"] if jobs else [])
    out = {}
    instructions(tree, DRAW, "none", "0", str(jobs))  # writes the tree's bytecode cache: not counted
    base = instructions(tree, DRAW, "none", "0", str(jobs))
    for kind in kinds:
        once = instructions(tree, DRAW, kind, "0", str(jobs))
        four = instructions(tree, DRAW, kind, "3", str(jobs))
        out[kind] = (four - once) / 3 / 1e6
        out[f"{kind}, first of its kind"] = (once - base) / 1e6
    bare = instructions(tree, "import numpy")
    out["server import"] = (instructions(tree, IMPORT, "as-is") - bare) / 1e6
    out["server import, with set() signatures"] = (instructions(tree, IMPORT, "signatures") - bare) / 1e6
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--other", type=Path, default=None, help="another tree to measure beside this one")
    ap.add_argument("--skip-diagnose", action="store_true", help="leave out the where-figures (no diagnosis)")
    args = ap.parse_args()
    if shutil.which("perf") is None:
        sys.exit("perf is not installed: this benchmark counts instructions with perf stat")
    trees = [ROOT] + ([args.other.resolve()] if args.other else [])
    with tempfile.TemporaryDirectory() as tmp:
        jobs = None
        if not args.skip_diagnose:
            jobs = Path(tmp) / "jobs.pickle"
            env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
            subprocess.run([sys.executable, "-c", DIAGNOSE, str(jobs), str(ROOT / "sample_data")], check=True,
                           cwd=tmp, env=env)
        results = [rows(t, jobs) for t in trees]
    head = "| row | " + " | ".join(f"{t} (M instructions)" for t in trees) + " |"
    print(head)
    print("|---|" + "---:|" * len(trees))
    for key in results[0]:
        print(f"| {key} | " + " | ".join(f"{r.get(key, float('nan')):.0f}" for r in results) + " |")


if __name__ == "__main__":
    main()
