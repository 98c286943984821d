"""End-to-end wall time of hystfit commands on the shipped sample data.

Run:  python benchmarks/bench_end_to_end.py [--repeat 3] [--markdown]
(or ``python benchmarks/speed.py``, which adds the kernel measurements and checks the targets)

Each command runs once to warm numba's on-disk cache and Python's bytecode cache (as an installed
hystfit has it: :func:`command_env`), then ``--repeat`` times; the best time is reported (the machine is shared: compare rows within one run). A command's wall time includes
starting Python and its imports: numpy, typer (with pydantic) and hystfit's registries always; numba
and its context (which imports ``scipy.linalg``) once a kernel runs; pandas once a report table is
written (``bench_startup.py`` times each step). The time of the fit itself is the ``runtime_s`` that
``hystfit identify --json`` reports, given alongside: the search and polish, after the optimizer's
libraries are imported (``Optimizer.libraries``: scipy.optimize, ≈ 0.3 s once per process, which the
wall time includes).
Measured:

- ``hystfit models --json`` (start-up of a second CLI call: imports + cached kernels),
- the Quickstart ``hystfit identify sample_data`` with every figure and with ``--no-plots``,
  run as typed (:data:`AS_TYPED`: progress lines and the result table printed, to pipes), as are
  ``diagnose`` and ``compare`` (before 2026-11-27 they ran with ``--quiet``, which hid that the
  progress line's thread kept a user's run from reading its captures aside: CHANGELOG),
- ``hystfit identify`` of one condition with PSO 200 × 300 ``--no-polish``, with and without
  figures, and ``hystfit diagnose sample_data --model pi``,
- ``hystfit identify`` of one condition (N = 5,001) with PSO 200 × 300 for ``pi`` and ``bw``
  (the papers' budget: 60,000 evaluations, plus the least-squares polish),
- ``hystfit identify`` of one condition with ``--opt auto`` for ``pi`` and ``bw``, and ``auto``
  against the best of 15 PSO 200 × 300 runs (with and without the polish) for ``pi``,
- ``hystfit compare sample_data --models all --opts auto`` (24 conditions × 10 models), with and
  without figures.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ONE = "sample_data/a60V_f10Hz.csv"
PSO = ["--opt", "pso", "--pop", "200", "--iters", "300"]
FAST = ["--no-plots", "--quiet", "--jobs", "1"]

COMMANDS = [
    ("second CLI call (`hystfit models --json`)", ["models", "--json"]),
    ("Quickstart: identify sample_data (24 conditions), every figure", ["identify", "sample_data"]),
    ("Quickstart: identify sample_data (24 conditions), --no-plots", ["identify", "sample_data", "--no-plots"]),
    ("identify pi, PSO 200 × 300, --no-polish, 1 condition, with figures",
     ["identify", ONE, "--model", "pi", *PSO, "--no-polish", "--quiet"]),
    ("identify pi, PSO 200 × 300, --no-polish, 1 condition, --no-plots",
     ["identify", ONE, "--model", "pi", *PSO, "--no-polish", "--quiet", "--no-plots"]),
    ("diagnose sample_data --model pi", ["diagnose", "sample_data", "--model", "pi"]),
    ("identify pi, PSO 200 × 300, 1 condition", ["identify", ONE, "--model", "pi", *PSO, *FAST]),
    ("identify bw, PSO 200 × 300, 1 condition", ["identify", ONE, "--model", "bw", *PSO, *FAST]),
    ("identify pi, auto, 1 condition", ["identify", ONE, "--model", "pi", *FAST]),
    ("identify bw, auto, 1 condition", ["identify", ONE, "--model", "bw", *FAST]),
    ("identify pi, PSO 200 × 300 × 15 runs, no polish, 1 condition",
     ["identify", ONE, "--model", "pi", *PSO, "--runs", "15", "--no-polish", *FAST]),
    ("identify pi, PSO 200 × 300 × 15 runs + polish, 1 condition",
     ["identify", ONE, "--model", "pi", *PSO, "--runs", "15", *FAST]),
    ("compare sample_data, all 10 models, auto, no figures", ["compare", "sample_data", "--models", "all", "--opts",
                                                              "auto", "--no-plots"]),
    ("compare sample_data, all 10 models, auto, with figures", ["compare", "sample_data", "--models", "all",
                                                                "--opts", "auto"]),
]


def adopt_orphans() -> bool:
    """Become the reaper of this process's orphaned descendants (Linux ``PR_SET_CHILD_SUBREAPER``).

    A command leaves processes that end just after it: its figure server and its pools' fork
    server (whose children, the workers, it reaped). Nobody waits for them, so their CPU time
    would be counted nowhere; adopted here and reaped by :func:`reap_orphans`, it is counted in
    the command's CPU seconds. False where the call is not available (then it is not counted)."""
    try:
        import ctypes

        return ctypes.CDLL(None, use_errno=True).prctl(36, 1, 0, 0, 0) == 0  # PR_SET_CHILD_SUBREAPER
    except (OSError, AttributeError):
        return False


def reap_orphans() -> None:
    """Wait for every child left (the adopted orphans end when the command that left them has)."""
    while True:
        try:
            os.waitpid(-1, 0)
        except ChildProcessError:
            return


def command_env() -> dict[str, str]:
    """The environment of a measured command: this one with Python's bytecode cache on.

    An installed hystfit (``pip install .``, the Quickstart) imports its modules from the ``.pyc``
    files pip compiled. Run from a checkout with ``PYTHONDONTWRITEBYTECODE=1`` (this machine's
    shells set it), Python compiles every hystfit module again at every start: ≈ 0.35 s of the
    imports of ``hystfit diagnose`` (``python -X importtime``, hystfit's own modules 0.44 s without
    the cache, 0.08 s with it). The measured commands are run as installed: the variable is dropped,
    so the first (warm-up) run writes ``__pycache__`` (git ignores it) and later runs read it.
    """
    return {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


#: identify commands run as a user types them (the README's Quickstart): progress lines and result
#: table printed, to pipes as a script captures them; the other identify commands print their JSON
#: summary instead, for the fit's own time. (diagnose and compare always run as typed.)
AS_TYPED = {("identify", "sample_data")}


def run(args: list[str], out: Path) -> tuple[float, dict | None]:
    """Wall time of one command (with the bytecode cache on: :func:`command_env`) and, for
    identify not run :data:`AS_TYPED`, its JSON summary."""
    cmd = [sys.executable, "-c", "from hystfit.cli import main; main()", *args]
    if args[0] in ("identify", "compare", "diagnose"):
        cmd += ["--out", str(out), "--force"]
    summary = args[0] == "identify" and tuple(args[:2]) not in AS_TYPED
    if summary:
        cmd += ["--json"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, env=command_env(), check=True, stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    return wall, (json.loads(proc.stdout) if summary else None)


def measure(repeat: int = 3) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, cmd in COMMANDS:
            out = Path(tmp) / "out"
            run(cmd, out)  # warm the JIT cache
            # compare (≈ 25 s a run) and the 15-run fits once; diagnose (≈ 6 s, ±15 % run to run) as the rest
            rep = 1 if (cmd[0] == "compare" or "runs" in " ".join(cmd)) else repeat
            best = min((run(cmd, out) for _ in range(rep)), key=lambda r: r[0])
            row = {"label": label, "wall_s": best[0], "fit_s": None, "rmse_um": None, "evaluations": None}
            if best[1] is not None:
                c = best[1]["conditions"][0]
                row.update(fit_s=c["runtime_s"], rmse_um=c["metrics"]["rmse_um"], evaluations=c["evaluations"])
            rows.append(row)
    return rows


def table(rows: list[dict], markdown: bool) -> str:
    def cell(v, spec):
        return "–" if v is None else format(v, spec)

    if markdown:
        out = ["| command | wall time (s) | fit time (s) | evaluations | RMSE (µm) |", "|---|---:|---:|---:|---:|"]
        out += [f"| {r['label']} | {r['wall_s']:.2f} | {cell(r['fit_s'], '.3f')} | {cell(r['evaluations'], ',')} | "
                f"{cell(r['rmse_um'], '.6f')} |" for r in rows]
    else:
        out = [f"{r['label']:62s} {r['wall_s']:8.2f} s   fit {cell(r['fit_s'], '.3f'):>7}   "
               f"rmse {cell(r['rmse_um'], '.6f')}" for r in rows]
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--markdown", action="store_true")
    args = ap.parse_args()
    print(table(measure(args.repeat), args.markdown))


if __name__ == "__main__":
    main()
