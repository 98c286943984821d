"""Do two trees write the same figures and numbers? Byte by byte, on shipped and blind data.

Run:  git worktree add --detach /tmp/old REV
      python benchmarks/figure_bytes.py --other /tmp/old [--skip-compare]

Each tree runs, in a fresh process from a scratch directory (so that ``PYTHONPATH`` decides which
hystfit is imported, checked):

- ``identify sample_data`` (the Quickstart, pi);
- ``compare sample_data --models pi,bw --opts auto`` (``--skip-compare`` leaves it out, ≈ 30 s);
- ``diagnose sample_data --model pi``;
- on a blind set written here by ``hystfit synth capture`` (the virtual plant; none of it fitted or
  tuned on): a 7 Hz triangle with creep and delay, a 35 Hz sine with dynamics on a 40 V offset, a
  250 Hz sine of 16,000 samples and a PRBS with asymmetry, ``identify --model bw`` and ``diagnose
  --model pi``.

Printed per command: the PNG files, how many differ in their pixels, and whether every JSON output
(``params.json``, ``diagnosis.json``) is the same once its timing fields (any key with ``time``)
are left out. A change meant to leave the outputs alone must print 0 and "same" everywhere.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

BLIND = [  # synth capture arguments: name, excitation options, effects
    ("tri_7Hz.csv", ["-e", "triangle", "-a", "50", "-f", "7", "--cycles", "4", "--seed", "11"], "creep,delay"),
    ("sine_35Hz.csv", ["-e", "sine", "-a", "30", "-f", "35", "--cycles", "6", "--offset", "40", "--seed", "12"],
     "dynamics"),
    ("sine_250Hz.csv", ["-e", "sine", "-a", "25", "-f", "250", "--cycles", "400", "--offset", "40", "--seed", "13"],
     None),
    ("prbs.csv", ["-e", "prbs", "-a", "60", "-f", "200", "--duration", "1.5", "--seed", "14"], "asymmetry"),
]


def _hystfit(tree: Path, args: list[str], cwd: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}
    code = "import hystfit, sys; assert hystfit.__file__.startswith(sys.argv[1]), hystfit.__file__; " \
           "sys.argv = ['hystfit', *sys.argv[2:]]; from hystfit.cli import main; main()"
    subprocess.run([sys.executable, "-c", code, str(tree), *args], env=env, cwd=cwd, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _without_times(value):
    if isinstance(value, dict):
        return {k: _without_times(v) for k, v in value.items() if "time" not in k}
    if isinstance(value, list):
        return [_without_times(v) for v in value]
    return value


def _compare(a: Path, b: Path) -> tuple[int, int, bool]:
    """(PNG files, how many differ in pixels, JSON outputs the same without timings)."""
    from PIL import Image  # matplotlib's own dependency

    pngs = sorted(p.relative_to(a) for p in a.rglob("*.png"))
    differ = 0
    for rel in pngs:
        other = b / rel
        if not other.exists() or not np.array_equal(np.asarray(Image.open(a / rel)), np.asarray(Image.open(other))):
            differ += 1
    same = all(_without_times(json.loads((a / rel).read_text())) == _without_times(json.loads((b / rel).read_text()))
               for rel in (p.relative_to(a) for p in a.rglob("*.json")))
    return len(pngs), differ, same


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--other", required=True, help="the other tree (a worktree's directory)")
    ap.add_argument("--skip-compare", action="store_true")
    a = ap.parse_args()
    trees = {"this": ROOT, "other": Path(a.other).resolve()}
    sample = str(ROOT / "sample_data")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        blind = tmp / "blind"
        for name, options, effects in BLIND:
            _hystfit(ROOT, ["synth", "capture", str(blind / name), *options,
                            *(["--effects", effects] if effects else [])], tmp)
        runs = [("identify sample_data", ["identify", sample]),
                ("diagnose sample_data --model pi", ["diagnose", sample, "--model", "pi"]),
                ("blind: identify --model bw", ["identify", str(blind), "--model", "bw"]),
                ("blind: diagnose --model pi", ["diagnose", str(blind), "--model", "pi"])]
        if not a.skip_compare:
            runs.insert(1, ("compare sample_data --models pi,bw --opts auto",
                            ["compare", sample, "--models", "pi,bw", "--opts", "auto"]))
        print("| command | figures | differing | JSON the same (timings aside) |\n|---|---:|---:|---|")
        for i, (title, args) in enumerate(runs):
            outs = {}
            for tag, tree in trees.items():
                outs[tag] = tmp / f"{tag}{i}"
                _hystfit(tree, [*args, "--out", str(outs[tag]), "--quiet"], tmp)
            n, differ, same = _compare(outs["this"], outs["other"])
            print(f"| {title} | {n} | {differ} | {'same' if same else '**differs**'} |")


if __name__ == "__main__":
    main()
