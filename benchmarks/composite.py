"""Composite models on rig-like data: speed of the whole command and the gain over plain models.

Makes three rising-amplitude captures of the virtual actuator (crest rising over the capture,
20 / 40 / 100 Hz, 40,000 samples each at 10 kHz) with asymmetry, two creep time constants, a
450 Hz stage (ζ 0.1), a 0.5 ms delay and 10 nm of sensor noise; identifies on 20 + 100 Hz with
``--global`` and validates with ``simulate`` on 40 Hz — the issue's real-rig protocol, on a plant
whose truth is known. Prints the wall time of each ``identify`` command and the held-out RMSE of
each model, beside the noise floor.

    python benchmarks/composite.py [--models pi,gpi,pi+creep+delay+asymmetry,MODEL:n_operators=20,...] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path


from hystfit import synth

SIGMA_UM = 0.01
FS = 10_000.0
N = 40_000
DEFAULT_MODELS = ("pi", "gpi", "pi+creep+delay", "pi+asymmetry+creep+delay", "pi+asymmetry+creep+dynamics+delay")


def plant() -> synth.Plant:
    eff = synth.Effects(asymmetry=True, creep=True, creep_tau_s=(0.02, 0.3), creep_gain=(0.03, 0.02),
                        dynamics=True, dynamics_fn_Hz=450.0, dynamics_zeta=0.1, delay=True, delay_s=0.5e-3,
                        noise=True, noise_sigma_um=SIGMA_UM)
    return synth.Plant.default().with_effects(eff)


def make_data(root: Path) -> tuple[Path, Path]:
    fit, val = root / "fit", root / "validate"
    fit.mkdir(parents=True)
    val.mkdir(parents=True)
    p = plant()
    for i, f in enumerate((20.0, 40.0, 100.0)):
        cycles = N * f / FS
        t, u = synth.rising_sine(60.0, f, cycles, FS)
        y = synth.simulate_plant(p, t, u, seed=i)
        synth.write_capture((val if f == 40.0 else fit) / f"rising_{int(f)}Hz.csv", t, u, y, "um")
    return fit, val


def run(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed: {res.stderr.strip().splitlines()[-1] if res.stderr else res.returncode}")
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default=",".join(DEFAULT_MODELS))
    ap.add_argument("--keep", type=Path, default=None, help="keep the data and outputs in this directory")
    args = ap.parse_args()
    root = Path(tempfile.mkdtemp(prefix="hystfit-composite-")) if args.keep is None else args.keep
    exe = [sys.executable, "-c", "from hystfit.cli import main; main()"]
    try:
        fit, val = make_data(root)
        print(f"noise floor {SIGMA_UM * 1e3:.1f} nm; fit on 20 + 100 Hz, validate on 40 Hz (3 × {N} samples)")
        print(f"{'model':40s} {'identify s':>10s} {'fit nm':>8s} {'held-out nm':>12s} {'× noise':>8s}")
        for spec in args.models.split(","):
            m, _, opts = spec.partition(":")  # MODEL or MODEL:KEY=VALUE[;KEY=VALUE] (structure options)
            mo = [a for kv in opts.split(";") if kv for a in ("--model-option", kv)]
            out = root / f"id_{m.replace('+', '_')}"
            wall = run(exe + ["identify", str(fit), "--model", m, "--global", "--out", str(out), "--force",
                              "--no-plots", "--quiet"] + mo)
            fit_rmse = json.loads((out / "params.json").read_text())["conditions"][0]["metrics"]["rmse_um"]
            sim = root / f"sim_{m.replace('+', '_')}"
            run(exe + ["simulate", str(out / "params.json"), str(val), "--out", str(sim), "--force", "--no-plots", "--quiet"])
            metrics = json.loads(next(sim.glob("*_metrics.json")).read_text())
            held = metrics.get("rmse_um", metrics.get("metrics", {}).get("rmse_um"))
            print(f"{spec:40s} {wall:10.2f} {1e3 * fit_rmse:8.1f} {1e3 * held:12.1f} {held / SIGMA_UM:8.2f}")
        both = root / "all3"
        both.mkdir(exist_ok=True)
        for f in list(fit.glob("*.csv")) + list(val.glob("*.csv")):
            shutil.copy(f, both / f.name)
        m = "pi+creep+delay+asymmetry"
        wall = min(run(exe + ["identify", str(both), "--model", m, "--global", "--out", str(root / "speed"), "--force",
                              "--no-plots", "--quiet"]) for _ in range(2))
        print(f"speed: identify {m} --global on the three {N}-sample captures: {wall:.2f} s (target ≤ 10 s, "
              "best of 2, the whole command)")
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
