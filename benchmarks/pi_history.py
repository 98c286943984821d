"""PI's ``history`` option on captures that start at mid-stroke: the fit with the history the plant had
against the fit with the other one.

Run:  python benchmarks/pi_history.py

Plants: a classical PI (10 play operators, thresholds from the data, weights 0.3·e^(−r/15 V) µm/V,
offset 3 µm) started either from a ramp 0 V → u₀ (``ramp``, paper 003's initial state) or with every
play at u₀ (``relaxed``: an actuator that rested at u₀ with its loops closed). Captures: sines about
50 V whose amplitude rises from 0 to 40 V over 2 s, at 1, 10, 50 and 100 Hz, 10 kHz, white sensor noise
σ = 0.02 µm (the rig-like drive of a blind test). Each plant's captures are identified per condition
with ``hystfit identify --model pi`` under each history; printed: the RMSE per condition (µm).
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hystfit.models.pi import PI  # noqa: E402
from hystfit.params import DataScale  # noqa: E402
from hystfit.synth import write_capture  # noqa: E402

DT = 1e-4
FREQUENCIES_HZ = (1.0, 10.0, 50.0, 100.0)
NOISE_UM = 0.02


def captures(history: str, folder: Path) -> None:
    t = np.arange(0, 2.0, DT)
    for k, f in enumerate(FREQUENCIES_HZ):
        u = 50.0 + (t / t[-1]) * 40.0 * np.sin(2 * np.pi * f * t)
        plant = PI(n_operators=10, history=history).adapt(DataScale.from_arrays([u], [u], [DT]))
        theta = np.r_[0.3 * np.exp(-plant.r / 15.0), 3.0]
        y = plant.simulate_one(theta, u, DT) + NOISE_UM * np.random.default_rng(k).standard_normal(t.size)
        write_capture(folder / f"rig_f{f:g}Hz.csv", t, u, y)


def main() -> None:
    from typer.testing import CliRunner

    from hystfit.cli import app

    print(f"RMSE (µm) per condition, noise {NOISE_UM} µm\n")
    print("| plant's history | fitted with | " + " | ".join(f"{f:g} Hz" for f in FREQUENCIES_HZ) + " |")
    print("|---|---|" + "---:|" * len(FREQUENCIES_HZ))
    with tempfile.TemporaryDirectory() as tmp:
        for truth in ("ramp", "relaxed"):
            data = Path(tmp) / truth
            captures(truth, data)
            for fitted in ("ramp", "relaxed"):
                r = CliRunner().invoke(app, ["identify", str(data), "--model", "pi", "--model-option",
                                             f"history={fitted}", "--out", str(Path(tmp) / f"{truth}-{fitted}"),
                                             "--no-plots", "--quiet", "--json"])
                if r.exit_code != 0:
                    raise SystemExit(r.output)
                rmse = {c["frequency_Hz"]: c["metrics"]["rmse_um"] for c in json.loads(r.stdout)["conditions"]}
                print(f"| {truth} | {fitted} | " + " | ".join(f"{rmse[f]:.4f}" for f in sorted(rmse)) + " |")


if __name__ == "__main__":
    main()
