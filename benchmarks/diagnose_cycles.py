"""The ``cycles`` hold-out of ``hystfit diagnose`` against the capture split, on rising-amplitude sines.

Three captures of the virtual actuator driven by rising-amplitude sines (0…60 V, 30 cycles) at
20 / 40 / 100 Hz, 10 kHz, 10 nm noise, base model ``pi`` with the plant's own thresholds (so the
base's resolution plays no part), with one or two effects switched on. For each, diagnose with
``DiagnoseSettings(split=...)`` "capture" (40 Hz held out whole) and "cycles" (the middle cycles
of every capture held out) and print the effects named and the first step's reductions.

    python benchmarks/diagnose_cycles.py
"""

from __future__ import annotations

import numpy as np

from hystfit import synth
from hystfit.capture import Capture
from hystfit.diagnose import DiagnoseSettings, diagnose
from hystfit.factory import make_model, make_optimizer
from hystfit.registry import optimizers

CASES = {
    "delay": dict(delay=True, delay_s=3e-4),
    "creep": dict(creep=True),
    "asymmetry": dict(asymmetry=True),
    "asymmetry+delay": dict(asymmetry=True, delay=True, delay_s=3e-4),
    "asymmetry+creep+delay": dict(asymmetry=True, creep=True, delay=True, delay_s=3e-4),
}


def captures(flags: dict, cycles: int = 30) -> list[Capture]:
    plant = synth.Plant.default().with_effects(synth.Effects(noise=True, noise_sigma_um=0.01, **flags))
    out = []
    for i, f in enumerate((20.0, 40.0, 100.0)):
        t, u = synth.rising_sine(60.0, f, cycles, 10_000)
        out.append(Capture(source=f"rs_{f:g}Hz.csv", t=t, u=u, y=synth.simulate_plant(plant, t, u, seed=i), dt=1e-4,
                           amplitude_V=float(np.ptp(u)), frequency_Hz=f))
    return out


def main() -> None:
    base = make_model("pi", {"thresholds_V": list(synth.DEFAULT_THRESHOLDS_V)})
    print("| truth | split | named | step-1 reductions |\n|---|---|---|---|")
    for name, flags in CASES.items():
        caps = captures(flags)
        for split in ("capture", "cycles"):
            d = diagnose(caps, base, make_optimizer(optimizers.get("auto")), settings=DiagnoseSettings(split=split))
            red = ", ".join(f"{r.effect} {r.reduction:.2f}" for r in d.effects[:3])
            print(f"| {name} | {split} | {', '.join(d.explained_by) or 'none'} | {red} |", flush=True)


if __name__ == "__main__":
    main()
