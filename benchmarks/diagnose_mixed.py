"""diagnose on rising-amplitude sines recorded together with a PRBS and a step pattern, per effect.

The set a rig records: rising-amplitude sines (crest 0…60 V over 50 cycles) at 20 / 40 / 100 Hz,
a 3-s PRBS (0/60 V, 2.5 kHz clock) and a 7.7-s step pattern at 60 V, 10 kHz, white sensor noise
σ = 0.01 µm, from the virtual actuator with one effect switched on (or none). The broadband
captures' "frequencies" (their strongest spectral lines, ≈ 470 Hz and ≈ 0.32 Hz) lie outside the
sines': the capture split must hold out the 40 Hz sine only and split the broadband captures in
time (before 2026-11-28 it held out every sine, and creep went unnamed).

    python benchmarks/diagnose_mixed.py [--effects none,creep,delay,dynamics,asymmetry] [--model pi] [--keep DIR]

Prints per effect: the split, the captures held out whole, those split in time, what was named,
the held-out RMSE before and with the named effects, and the noise floor (µm).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from hystfit import synth


def make(d: Path, effect: str, seed: int = 0) -> None:
    d.mkdir(parents=True, exist_ok=True)
    flags = {} if effect == "none" else {effect: True}
    plant = synth.Plant.default().with_effects(synth.Effects(noise=True, noise_sigma_um=0.01, **flags))
    for i, f in enumerate((20.0, 40.0, 100.0)):
        t, u = synth.rising_sine(60.0, f, 50, 10_000)
        synth.write_capture(d / f"rising_{int(f)}Hz.csv", t, u, synth.simulate_plant(plant, t, u, seed=seed + i), "um")
    t, u = synth.prbs(60.0, 10_000, 3.0, 2500.0, seed=seed + 5)
    synth.write_capture(d / "prbs.csv", t, u, synth.simulate_plant(plant, t, u, seed=seed + 7), "um")
    t, u = synth.step_pattern(60.0, 7.7, 10_000)
    synth.write_capture(d / "steps.csv", t, u, synth.simulate_plant(plant, t, u, seed=seed + 8), "um")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effects", default="none,creep,delay,dynamics,asymmetry")
    ap.add_argument("--model", default="pi")
    ap.add_argument("--keep", type=Path, default=None, help="keep the captures and outputs here")
    args = ap.parse_args()
    root = Path(tempfile.mkdtemp(prefix="hystfit-mixed-")) if args.keep is None else args.keep
    exe = [sys.executable, "-c", "from hystfit.cli import main; main()"]
    print("| effect on | split | held out whole | split in time | named | held-out RMSE before → with named (µm) "
          "| noise floor (µm) |")
    print("|---|---|---|---|---|---|---:|")
    try:
        for effect in args.effects.split(","):
            data, out = root / effect, root / f"{effect}_out"
            if not data.exists():
                make(data, effect)
            subprocess.run([*exe, "diagnose", str(data), "--model", args.model, "--out", str(out), "--force",
                            "--quiet", "--no-figures"], check=True, capture_output=True, text=True)
            d = json.loads((out / "diagnosis.json").read_text())
            s = d["split"]

            def names(key):
                return ", ".join(Path(p).name for p in s.get(key, [])) or "–"

            named = ", ".join(d["explained_by"]) or "none"
            after = d["heldout_rmse_with_named_effects_um"]
            print(f"| {effect} | {s['kind']} | {names('heldout_captures')} | {names('split_in_time_captures')} "
                  f"| {named} | {d['gap']['heldout_rmse_um']:.4g} → {after:.4g} | {d['noise_floor_um']:.4g} |")
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
