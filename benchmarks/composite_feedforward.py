"""Open-loop feedforward through composite models, fed into the plant itself.

The plant: the virtual actuator with asymmetry, creep (1 %/decade, 10 ms … 10 s) and a lightly
damped 900 Hz stage (ζ = 0.05), 8 nm noise. Its campaign (``hystfit synth campaign``: 24
raised-cosine captures at 20/40/60 V × 10…80 Hz plus PRBS and steps) is identified with each
model (``--global``: one parameter set for every condition); ``hystfit invert PARAMS --sine
10,F,5`` gives the voltages for a 10 µm sine at F = 1, 10, 80 Hz, which drive the plant; the
tracking error is reported as RMSE in % of the 10 µm stroke.

    python benchmarks/composite_feedforward.py [--models pi,pi2,pi+asymmetry+creep+dynamics:n_operators=30]
                                               [--keep DIR]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from hystfit import synth
from hystfit.invert import sine_target

FREQS = (1.0, 10.0, 80.0)
AMP_UM = 10.0
#: MODEL or MODEL:KEY=VALUE[;KEY=VALUE] (structure options, as --model-option)
DEFAULT_MODELS = ("pi", "pi2", "pi+creep+dynamics", "pi+asymmetry+creep+dynamics",
                  "pi+asymmetry+creep+dynamics:n_operators=30")


def plant(sensor: bool = True) -> synth.Plant:
    """The plant; ``sensor=False``: the same stage without sensor noise and quantization (the
    tracking error of the stage itself)."""
    eff = synth.Effects(asymmetry=True, creep=True, dynamics=True, dynamics_fn_Hz=900.0, dynamics_zeta=0.05,
                        noise=sensor, quantization=sensor)
    return synth.Plant.default().with_effects(eff)


def run(cmd: list[str]) -> None:
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed: {res.stderr.strip().splitlines()[-1] if res.stderr else res.returncode}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default=",".join(DEFAULT_MODELS))
    ap.add_argument("--keep", type=Path, default=None)
    args = ap.parse_args()
    root = Path(tempfile.mkdtemp(prefix="hystfit-ff-")) if args.keep is None else args.keep
    exe = [sys.executable, "-c", "from hystfit.cli import main; main()"]
    p = plant()
    p_clean = plant(sensor=False)
    try:
        data = root / "campaign"
        synth.make_campaign(data, p, 0)
        print("RMSE of the plant's tracking error, % of the 10 µm stroke (voltages from `hystfit invert`); in brackets "
              "the stage without its 8 nm sensor noise (0.08 % of the stroke) and quantization")
        print(f"{'model[:options]':46s} " + " ".join(f"{f:>15g} Hz" for f in FREQS))
        for spec in args.models.split(","):
            m, _, opts = spec.partition(":")
            mo = [a for kv in opts.split(";") if kv for a in ("--model-option", kv)]
            out = root / f"id_{m.replace('+', '_')}"
            run(exe + ["identify", str(data), "--model", m, "--global", "--out", str(out), "--force", "--no-plots",
                       "--quiet"] + mo)
            row = []
            for i, f in enumerate(FREQS):
                v = root / f"v_{m.replace('+', '_')}_{f:g}.csv"
                run(exe + ["invert", str(out / "params.json"), "--sine", f"{AMP_UM:g},{f:g},5", "--out", str(v),
                           "--force", "--quiet"])
                d = pd.read_csv(v, comment="#")
                t = d["time_s"].to_numpy()
                u = d["voltage_V"].to_numpy()
                target = sine_target(AMP_UM, f, 5, 1.0 / float(t[1] - t[0])).y[: t.size]
                rms = [100.0 * np.sqrt(np.mean((synth.simulate_plant(q, t, u, seed=100 + i) - target) ** 2)) / AMP_UM
                       for q in (p, p_clean)]
                row.append(rms)
            print(f"{spec:46s} " + " ".join(f"{a:7.3f} % ({b:.3f})" for a, b in row))
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
