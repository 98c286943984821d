"""What the interpreter's exit costs a command, with and without the console script's ``gc.freeze()``.

Run:  python benchmarks/exit_time.py [--repeat 5] [COMMAND WORDS…]   (default: diagnose sample_data --model pi)

``hystfit.cli.main()`` (the console script, no arguments) freezes every object out of the garbage
collector as the command ends; ``main(argv)`` called from Python does not. Both are run here in a
fresh process each, alternately, with the same command: the time from the command's return (an
``atexit`` hook registered first runs last) to the process's end is the exit's cost. Prints, per
way, that exit time and the whole wall time, best of ``--repeat``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_end_to_end import command_env  # noqa: E402

#: runs the command as the console script (``main()``) or as a library call (``main(argv)``) and
#: prints, from an atexit hook that runs after every other, when the command returned
CHILD = """
import atexit, json, sys, time
atexit.register(lambda: print(json.dumps({"returned": time.time()}), file=sys.stderr, flush=True))
from hystfit.cli import main
way, words = sys.argv[1], sys.argv[2:]
if way == "console":
    sys.argv = ["hystfit", *words]
    main()
else:
    main(words)
"""


def run(way: str, words: list[str]) -> tuple[float, float]:
    """(exit time, wall time) in seconds of one run."""
    env = command_env()  # as an installed hystfit runs
    t0 = time.time()
    r = subprocess.run([sys.executable, "-c", CHILD, way, *words], cwd=ROOT, env=env, capture_output=True, text=True)
    end = time.time()
    if r.returncode != 0:
        raise SystemExit(f"the command failed: {r.stderr.strip()[-400:]}")
    returned = json.loads(r.stderr.strip().splitlines()[-1])["returned"]
    return end - returned, end - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("words", nargs="*", default=["diagnose", "sample_data", "--model", "pi"])
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        words = [*a.words, "--quiet", "--force", "--out", str(Path(tmp) / "out")]
        run("console", words)  # warm numba's on-disk cache
        got: dict[str, list[tuple[float, float]]] = {"console": [], "library": []}
        for _ in range(a.repeat):
            for way in got:
                got[way].append(run(way, words))
    print(f"`hystfit {' '.join(a.words)}`, best of {a.repeat}, alternately\n")
    print("| way | exit (s) | wall (s) | every exit (s) |\n|---|---:|---:|---|")
    for way, label in (("console", "console script: main(), objects frozen"),
                       ("library", "main(argv): not frozen")):
        exits = [e for e, _ in got[way]]
        print(f"| {label} | {min(exits):.3f} | {min(w for _, w in got[way]):.2f} | "
              f"{', '.join(f'{e:.2f}' for e in exits)} |")


if __name__ == "__main__":
    main()
