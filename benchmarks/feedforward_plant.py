"""Feedforward voltages of `hystfit invert` fed to the virtual plant they were identified on.

Two cases a blind test found, rerun end to end with the command line:

1. **A target up the stroke** (the look-up table's cells). A creep plant's campaign
   (`hystfit synth campaign --effects creep,noise`: 24 captures from 0 V at 20/40/60 V × 10…80 Hz)
   is identified per condition with `pi+creep` and with `pi`; `hystfit invert PARAMS --sine 8,10,5
   --offset 5` asks for 10…40 V. The cells used, and the plant's tracking RMSE (noise off) against
   the target, are printed, beside the same target from the bottom of the stroke (no `--offset`).
2. **A creep model's start** (the pre-roll). Rising-amplitude sines at 3 / 40 / 120 Hz of a plant
   with creep ×2 are diagnosed (`hystfit diagnose DIR --model pi`); its `params.json` is inverted for
   `--sine 12,30,10 --offset 1.5`, and the voltages drive the plant, which starts at rest at their
   first sample (settled there).

    python benchmarks/feedforward_plant.py [--keep DIR]

Prints one Markdown table; RMSE in µm: the plant's tracking error, invert's own predicted error (the
model following its inverse) and the cells' fit RMSE on their identification data (invert's
``cells_fit_rmse_um``, the order it gives for a measured error).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from hystfit import synth
from hystfit.invert import sine_target


def _hystfit(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hystfit", *map(str, args)], check=True, capture_output=True,
                          text=True)


def _plant(effects: str, strength: float = 1.0) -> synth.Plant:
    """The virtual actuator with ``effects``, noise and quantization off (the tracking is the model's)."""
    eff = synth.Effects.from_names(effects.split(","), strength)
    return synth.Plant.default().with_effects(replace(eff, noise=False, quantization=False))


def _track(params: Path, plant: synth.Plant, sine: str, offset: float | None, work: Path) -> tuple:
    """Plant tracking RMSE (µm) of the voltages ``invert`` gives for ``--sine SINE [--offset OFFSET]``,
    the cells it used, invert's predicted RMSE and the cells' fit RMSE on their identification data."""
    out = work / f"v_{abs(hash((str(params), sine, offset)))}.csv"
    extra = [] if offset is None else ["--offset", offset]
    _hystfit("invert", params, "--sine", sine, *extra, "--out", out, "--no-plots", "--quiet", "--force")
    v = pd.read_csv(out)
    t, u = v["time_s"].to_numpy(), v["voltage_V"].to_numpy()
    amp, freq, cycles = (float(x) for x in sine.split(","))
    target = sine_target(amp, freq, cycles, 1.0 / (t[1] - t[0]), offset=offset or 0.0).y
    y = synth.simulate_plant(plant, t, u)
    report = json.loads((out.parent / (out.stem + "_report") / "report.json").read_text())
    cells = "; ".join("+".join(c["label"] for c in seg["cells"]) for seg in report.get("segments", [])) or "–"
    return (float(np.sqrt(np.mean((y - target) ** 2))), cells, report["predicted_tracking"]["rmse_um"],
            report["cells_fit_rmse_um"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keep", type=Path, default=None, help="keep the data and outputs here")
    a = ap.parse_args()
    work = a.keep or Path(tempfile.mkdtemp(prefix="hystfit-ffplant-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    try:
        camp = work / "campaign_creep"
        _hystfit("synth", "campaign", "--out", camp, "--effects", "creep,noise", "--seed", "0", "--force")
        plant = _plant("creep")
        for model in ("pi+creep", "pi"):
            ident = work / f"id_{model}"
            _hystfit("identify", camp, "--model", model, "--out", ident, "--no-plots", "--quiet", "--force")
            for offset in (5.0, None):
                rms, cells, pred, fit = _track(ident / "params.json", plant, "8,10,5", offset, work)
                where = "5 → 13 µm (up the stroke)" if offset else "0.25 → 8.25 µm (from the bottom)"
                rows.append((f"campaign, creep; {model} per condition", where, cells, rms, pred, fit))
        rising = work / "rising_creep2"
        rising.mkdir(exist_ok=True)
        for i, f in enumerate((3, 40, 120)):
            _hystfit("synth", "capture", rising / f"rs_{f}Hz.csv", "-a", "60", "-e", "rising-sine", "-f", f,
                     "--cycles", "20", "--effects", "creep,noise", "--strength", "2", "--noise", "0.008",
                     "--seed", f, "--force")
        diag = work / "diag"
        _hystfit("diagnose", rising, "--model", "pi", "--out", diag, "--no-plots", "--quiet", "--force")
        rms, cells, pred, fit = _track(diag / "params.json", _plant("creep", 2.0), "12,30,10", 1.5, work)
        rows.append(("rising sines, creep ×2; diagnose's params.json", "1.5 → 13.5 µm", cells, rms, pred, fit))
    finally:
        if a.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    print("| data; model | target | cells used | plant tracking RMSE (µm) | invert's predicted RMSE (µm) | "
          "cells' fit RMSE (µm) |\n|---|---|---|---:|---:|---:|")
    for data, where, cells, rms, pred, fit in rows:
        print(f"| {data} | {where} | {cells} | {rms:.4f} | {pred:.2g} | {fit:.4f} |")


if __name__ == "__main__":
    main()
