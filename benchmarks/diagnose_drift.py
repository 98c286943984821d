"""diagnose on rising-amplitude sines with and without a drift: the capture split's verdicts.

Three rising-amplitude sines (0…60 V over 30 cycles) at 10 / 40 / 120 Hz, 10 kHz, 10 nm noise, from
the virtual actuator with the effects of each case switched on (`hystfit synth capture … -e
rising-sine --effects E,noise --strength S --noise 0.01 --seed K`, K = 1, 2, 3; `drift ×2` uses
K = 11, 12, 13). `hystfit diagnose DIR --model pi` holds out the 40 Hz capture (the capture split);
printed per case: the truth, what was named, the split, whether drift was tested, and step 1's
three best reductions.

    python benchmarks/diagnose_drift.py [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

#: case → (effects, strength, first seed)
CASES = {"drift ×5": ("drift", 5, 1), "drift ×2": ("drift", 2, 11), "asymmetry + drift": ("drift,asymmetry", 3, 1),
         "creep + drift": ("drift,creep", 3, 1), "none": ("", 1, 1), "creep ×2": ("creep", 2, 1),
         "asymmetry ×2": ("asymmetry", 2, 1), "delay ×1.5": ("delay", 1.5, 1)}


def _hystfit(*args) -> None:
    subprocess.run([sys.executable, "-m", "hystfit", *map(str, args)], check=True, capture_output=True, text=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keep", type=Path, default=None, help="keep the captures and outputs here")
    a = ap.parse_args()
    work = a.keep or Path(tempfile.mkdtemp(prefix="hystfit-drift-"))
    print("| case | named | split | drift tested | step 1 (three best reductions) |\n|---|---|---|---|---|")
    try:
        for name, (effects, strength, seed) in CASES.items():
            data = work / name.replace(" ", "_").replace("×", "x").replace("+", "and")
            data.mkdir(parents=True, exist_ok=True)
            for k, f in enumerate((10, 40, 120)):
                _hystfit("synth", "capture", data / f"rs_{f}Hz.csv", "-a", 60, "-e", "rising-sine", "-f", f,
                         "--cycles", 30, "--effects", ",".join(x for x in (effects, "noise") if x), "--strength",
                         strength, "--noise", 0.01, "--seed", seed + k, "--force")
            out = data.parent / (data.name + "_out")
            _hystfit("diagnose", data, "--model", "pi", "--out", out, "--no-plots", "--quiet", "--force")
            d = json.loads((out / "diagnosis.json").read_text())
            step1 = ", ".join(f"{e['effect']} {e['reduction']:.2f}" for e in d["steps"][0]["effects"][:3])
            tested = "no" if "drift" in d["split"].get("not_tested", ()) else "yes"
            print(f"| {name} | {', '.join(d['explained_by']) or 'none'} | {d['split']['kind']} | {tested} | {step1} |")
    finally:
        if a.keep is None:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
