"""diagnose on rising-amplitude sines: which hold-out decides, and what it names.

Three captures of the virtual actuator driven by rising-amplitude sines (crest rising over 50
cycles, 0…60 V) at 20 / 40 / 100 Hz, 10 kHz, 10 nm noise: once with asymmetry, creep
(1 %/decade) and a 0.3 ms delay switched on, once with nothing. Runs ``hystfit diagnose DIR
--model pi`` on each and prints the hold-out scheme, the captures held out, the effects named,
the other scheme's verdict and every step-1 reduction — in global mode (three captures, the 40 Hz
one held out whole) and in per-condition mode (one capture per condition: the middle cycles held
out), which should agree.

    python benchmarks/diagnose_rising.py [--keep DIR]
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

CASES = {
    "asymmetry+creep+delay": dict(asymmetry=True, creep=True, delay=True, delay_s=3e-4),
    "none": {},
}


def make(d: Path, eff: synth.Effects, seed: int = 0) -> None:
    d.mkdir(parents=True, exist_ok=True)
    plant = synth.Plant.default().with_effects(eff)
    for i, f in enumerate((20.0, 40.0, 100.0)):
        t, u = synth.rising_sine(60.0, f, 50, 10_000)
        synth.write_capture(d / f"rising_{int(f)}Hz.csv", t, u, synth.simulate_plant(plant, t, u, seed=seed + i), "um")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keep", type=Path, default=None)
    args = ap.parse_args()
    root = Path(tempfile.mkdtemp(prefix="hystfit-rising-")) if args.keep is None else args.keep
    exe = [sys.executable, "-c", "from hystfit.cli import main; main()"]
    try:
        for (name, flags), mode in ((c, m) for c in CASES.items() for m in ("global", "per-condition")):
            data = root / name.replace("+", "_")
            if not data.exists():
                make(data, synth.Effects(noise=True, noise_sigma_um=0.01, **flags))
            extra = ["--per-condition"] if mode == "per-condition" else []
            r = subprocess.run(exe + ["diagnose", str(data), "--model", "pi", *extra,
                                      "--out", str(root / f"d_{data.name}_{mode}"), "--force", "--no-plots", "--json"],
                               capture_output=True, text=True)
            if r.returncode:
                sys.exit(r.stderr.strip().splitlines()[-1])
            d = json.loads(r.stdout)
            held = [Path(x).name for x in d["split"].get("heldout_captures", [])]
            other = d["split"].get("other_scheme", {})
            held_out = ", ".join(held) or ("the middle cycles" if d["split"]["kind"] == "cycles" else "-")
            print(f"truth {name}, {mode}: split {d['split']['kind']} (held out {held_out}); named "
                  f"{', '.join(d['explained_by']) or 'none'}; other scheme names "
                  f"{', '.join(other.get('explained_by', [])) or 'none'} (agrees: {other.get('agrees')}); step-1 "
                  "reductions " + ", ".join(f"{e['effect']} {e['reduction']:.2f}" for e in d["effects"]))
            first = d.get("resolution_before_effects")
            if first is not None:
                print("  resolution before the effects: " + "; ".join(
                    f"{x['from']} → {x['to']}: held-out {x['heldout_rmse_before_um']:.4f} → {x['heldout_rmse_after_um']:.4f} µm "
                    f"({100 * x['reduction_mean_square']:.0f} % of the excess mean square, "
                    f"{'adopted' if x['adopted'] else 'kept'})" for x in first["steps"]))
            for c in d.get("resolution_during_selection", []):
                print(f"  resolution during the selection, after {' + '.join(c['effects'])}: {c['from']} → {c['to']}: "
                      f"held-out {c['heldout_rmse_before_um']:.4f} → {c['heldout_rmse_after_um']:.4f} µm "
                      f"({100 * c['reduction_mean_square']:.0f} %, adopted: {c['adopted']})")
            r = d.get("resolution")
            if r is not None:
                print(f"  resolution check after the selection: {r['option']} {r['from']} → {r['to']} with {' + '.join(r['effects']) or 'no effect'}: "
                      f"held-out {r['heldout_rmse_before_um']:.4f} → {r['heldout_rmse_after_um']:.4f} µm, reduction "
                      f"{100 * r['reduction_mean_square']:.0f} % of the excess mean square, adopted: {r['adopted']}")
            for s in d["steps"][1:]:
                print(f"  step {s['step']}: " + ", ".join(f"{e['effect']} {e['reduction']:.2f}" for e in s["effects"])
                      + f" → named {s['named'] or 'none'}")
            print(f"  held-out RMSE with the named effects {d['heldout_rmse_with_named_effects_um']:.4f} µm "
                  f"(noise floor {d['noise_floor_um']:.4f} µm); next: --model {d['recommended_model']}"
                  + "".join(f" --model-option {k}={v}" for k, v in d.get("recommended_model_options", {}).items()))
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
