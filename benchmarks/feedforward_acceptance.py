"""Acceptance of issue 6: open-loop feedforward from `hystfit invert` on hystfit's virtual actuator.

Run:  python benchmarks/feedforward_acceptance.py [--models pi,bw,pi2,hammerstein] [--global-pi]
                                                   [--seed 0] [--keep DIR]

1. `hystfit identify sample_data --model M` (per-condition look-up table, optimizer `auto`) for
   each model M that is registered (`pi` always; `bw`, and the dynamic models `pi2` and
   `hammerstein`, when registered); with `--global-pi` also `pi --global` as a reference row.
2. For 10 µm peak-to-peak sines (paper 002 eq. 16, 5 cycles) at 1, 2, 5, 10 Hz and 50, 60, 70,
   80 Hz: `hystfit invert PARAMS --sine 10,F,5 [--offset O] --out v.csv` (defaults otherwise:
   bilinear table interpolation, iterated amplitude, default voltage limits), for three offsets:
   0. no --offset (the command's default, O = 0): the sine 0 → 10 µm of the issue ("starts at
      0"); the stage rests at 0.25 µm at 0 V, so the voltage starts at ≈ −1.2 V, inside the
      default limits (identification range 0…60 V ± 10 %);
   A. O = the stage's rest position at 0 V (the median first displacement sample of the
      captures, 0.25 µm): the sine 0.25 → 10.25 µm starts where the stage rests at 0 V, as paper
      002's eq. 16 starts at its actuator's zero;
   B. O = 2 µm (2 → 12 µm): the stage first rests at 2 µm (≈ 7 V).
3. The voltage file is fed into the plant that generated `sample_data/`
   (`hystfit.synth.simulate_plant(Plant.default(), t, u, seed)`: PI hysteresis + creep +
   1.2 kHz stage dynamics + 8 nm noise + 1 nm quantization) — not into the identified model —
   and the tracking error e = y − y_d is measured: RMSE and max |e| in % of the 10 µm stroke.

Targets of the issue: RMSE ≤ 1 % of stroke at 1–10 Hz; ≤ 2 % at 50–80 Hz with a dynamic model.
For comparison, paper 002 measures 0.227 µm RMSE (2.27 %) for its best feedforward (Table 4) and,
at 0.5 Hz, 2.48 % feedforward / 1.13 % feedforward + PID (Table 5).

Diagnostic columns: the predicted RMSE (`hystfit invert`'s preview from the identified model),
the mean error, and the RMSE on the same plant with its creep switched off (same voltages), which
shows how much of the error is creep that a rate-independent model identified on 0.1–0.5 s
captures cannot represent. In case B the stage has crept while resting at 2 µm (≈ 4 % of the
rest displacement with the plant's 1 %/decade creep), an offset no model identified on captures
starting at 0 V can know.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hystfit.cli import main as hystfit_main  # noqa: E402
from hystfit.registry import models  # noqa: E402
from hystfit.synth import Plant, simulate_plant  # noqa: E402

FREQS_LOW = (1.0, 2.0, 5.0, 10.0)
FREQS_HIGH = (50.0, 60.0, 70.0, 80.0)
AMP_UM, OFFSET_B_UM, CYCLES = 10.0, 2.0, 5
DYNAMIC = ("pi2", "hammerstein")


def cli(*args) -> None:
    """Run a hystfit command in this process (the same code path as the console script)."""
    try:
        hystfit_main([str(a) for a in args])
    except SystemExit as exc:
        if exc.code not in (0, None):
            raise RuntimeError(f"hystfit {' '.join(map(str, args))} exited with {exc.code}") from None


def rms_pct(e: np.ndarray) -> float:
    return float(100.0 * np.sqrt(np.mean(e * e)) / AMP_UM)


def measure(params: Path, freq: float, offset: float, work: Path, seed: int, plant: Plant,
            plant_nocreep: Plant) -> dict:
    out = work / f"v_{params.parent.name}_{freq:g}Hz_{offset:g}.csv"
    cli("invert", params, "--sine", f"{AMP_UM:g},{freq:g},{CYCLES}", *(["--offset", f"{offset:g}"] if offset else []),
        "--out", out, "--quiet", "--no-plots", "--force")
    df = pd.read_csv(out)
    rep = json.loads((work / f"{out.stem}_report" / "report.json").read_text())
    t, u, y_pred = df["time_s"].to_numpy(), df["voltage_V"].to_numpy(), df.iloc[:, 2].to_numpy()
    y_d = offset + 0.5 * AMP_UM * (1.0 - np.cos(2 * np.pi * freq * t))
    y = simulate_plant(plant, t, u, seed=seed)
    y0 = simulate_plant(plant_nocreep, t, u, seed=seed)
    e = y - y_d
    cells = " + ".join(f"{lab}×{w:.2f}" for lab, w in rep["cells_used"])
    return {"freq": freq, "offset": offset, "rmse_pct": rms_pct(e), "max_pct": float(100 * np.max(np.abs(e)) / AMP_UM),
            "mean_um": float(np.mean(e)), "pred_pct": rms_pct(y_pred - y_d), "nocreep_pct": rms_pct(y0 - y_d),
            "cells": cells, "clipped": rep["clipping"]["samples"], "vmin": float(u.min()), "vmax": float(u.max())}


def rest_position() -> float:
    """The stage's displacement at rest at 0 V: median first sample of the sample captures (µm)."""
    from hystfit.io import load_captures

    return round(float(np.median([c.y[0] for c in load_captures([ROOT / "sample_data"])])), 2)


def table(rows: list[dict], title: str) -> None:
    print(f"\n{title}\n")
    print("| model | f (Hz) | table cells | RMSE % of stroke | max % | target | met | voltage (V) | predicted RMSE % | "
          "mean error (µm) | RMSE % without creep |")
    print("|---|---:|---|---:|---:|---:|---|---|---:|---:|---:|")
    for r in rows:
        low = r["freq"] <= 10
        target = 1.0 if low else 2.0
        applies = low or r["dynamic"]
        met = ("yes" if r["rmse_pct"] <= target else "**no**") if applies else "(needs a dynamic model)"
        print(f"| {r['model']} | {r['freq']:g} | {r['cells']} | {r['rmse_pct']:.2f} | {r['max_pct']:.2f} | "
              f"≤ {target:g} | {met} | {r['vmin']:.1f} … {r['vmax']:.1f} | {r['pred_pct']:.3f} | {r['mean_um']:+.3f} | "
              f"{r['nocreep_pct']:.2f} |")
    print()
    for model in dict.fromkeys(r["model"] for r in rows):
        mine = [r for r in rows if r["model"] == model]
        lo = [r for r in mine if r["freq"] <= 10]
        hi = [r for r in mine if r["freq"] > 10]
        print(f"- {model}: 1–10 Hz RMSE {min(r['rmse_pct'] for r in lo):.2f}–{max(r['rmse_pct'] for r in lo):.2f} % "
              f"(≤ 1 % at {sum(r['rmse_pct'] <= 1 for r in lo)}/{len(lo)}); 50–80 Hz "
              f"{min(r['rmse_pct'] for r in hi):.2f}–{max(r['rmse_pct'] for r in hi):.2f} % "
              f"(≤ 2 % at {sum(r['rmse_pct'] <= 2 for r in hi)}/{len(hi)}); identification "
              f"{mine[0]['t_identify']:.1f} s, inversion {np.mean([r['t_invert'] for r in mine]):.1f} s per target")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default="pi,bw,pi2,hammerstein",
                    help="comma list; unregistered models are skipped (pi is always run)")
    ap.add_argument("--global-pi", action="store_true", help="also a global (one-cell) PI fit as a reference row")
    ap.add_argument("--seed", type=int, default=0, help="seed of the virtual actuator's sensor noise")
    ap.add_argument("--keep", type=Path, default=None, help="keep the parameter and voltage files in this directory")
    args = ap.parse_args()
    wanted = [m.strip() for m in args.models.split(",") if m.strip()]
    if "pi" not in wanted:
        wanted.insert(0, "pi")
    names = [m for m in wanted if m in models]
    skipped = [m for m in wanted if m not in models]
    plant = Plant.default()
    plant_nocreep = plant.with_effects(dataclasses.replace(plant.effects, creep=False))
    command = "python benchmarks/feedforward_acceptance.py " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    work_ctx = tempfile.TemporaryDirectory() if args.keep is None else None
    work = Path(work_ctx.name) if work_ctx else args.keep
    work.mkdir(parents=True, exist_ok=True)
    rows, notes = [], []
    offset_a = rest_position()
    offsets = (0.0, offset_a, OFFSET_B_UM)
    runs = [(m, False) for m in names] + ([("pi", True)] if args.global_pi else [])
    for model, global_fit in runs:
        label = f"{model} (global fit)" if global_fit else model
        pdir = work / (f"{model}-global" if global_fit else model)
        t0 = time.perf_counter()
        try:
            cli("identify", ROOT / "sample_data", "--model", model, "--out", pdir, "--no-plots", "--quiet",
                "--force", *(["--global"] if global_fit else []))
        except Exception as exc:  # a model that cannot be identified here is reported, not fatal
            notes.append(f"{label}: identification failed ({exc})")
            continue
        t_id = time.perf_counter() - t0
        for offset in offsets:
            for f in FREQS_LOW + FREQS_HIGH:
                t1 = time.perf_counter()
                try:
                    r = measure(pdir / "params.json", f, offset, work, args.seed, plant, plant_nocreep)
                except Exception as exc:
                    notes.append(f"{label} at {f:g} Hz, offset {offset:g} µm: {exc}")
                    continue
                r.update(model=label, dynamic=model in DYNAMIC, t_invert=time.perf_counter() - t1, t_identify=t_id)
                rows.append(r)
        print(f"{label}: identified in {t_id:.1f} s", file=sys.stderr)
    if work_ctx:
        work_ctx.cleanup()

    print(f"Command: `{command.strip()}`\n")
    print(f"Per model M: `hystfit identify sample_data --model M --out M`; per frequency F and offset O: "
          f"`hystfit invert M/params.json --sine {AMP_UM:g},F,{CYCLES} [--offset O] --out v.csv`; the voltages "
          f"go into `simulate_plant(Plant.default(), t, u, seed={args.seed})`. Errors in % of the 10 µm stroke.")
    table([r for r in rows if r["offset"] == 0.0],
          f"0. The command's default (no --offset): 0 → {AMP_UM:g} µm")
    table([r for r in rows if r["offset"] == offset_a],
          f"A. Sine from the stage's rest position at 0 V: {offset_a:g} → {offset_a + AMP_UM:g} µm")
    table([r for r in rows if r["offset"] == OFFSET_B_UM],
          f"B. Sine from a 2 µm rest position: {OFFSET_B_UM:g} → {OFFSET_B_UM + AMP_UM:g} µm")
    for n in notes:
        print(f"- note: {n}")
    if skipped:
        print(f"- not registered, skipped: {', '.join(skipped)}")


if __name__ == "__main__":
    main()
