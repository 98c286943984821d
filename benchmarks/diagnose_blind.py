"""diagnose on a plant none of its settings were chosen on: a coarse base, several effects at once.

The plant: 14 play operators at 0…78 V with weights 0.35·e^(−j/5) µm/V (a 124 µm stroke), driven
by rising-amplitude sines 0…90 V over 40 cycles at 15 / 50 / 120 Hz, 10 kHz, 8 nm sensor noise.
Three cases: a 700 Hz stage + creep switched on, a 0.3 ms delay + asymmetry, nothing. Each is
diagnosed globally with ``--model pi`` (ten operators); prints what was named, the resolution
converged before the effects (every doubling), the check after them, the held-out RMSE with the
named effects against the noise floor, and every step's reductions.

    python benchmarks/diagnose_blind.py [--cases dynamics+creep,none]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hystfit import synth
from hystfit.capture import Capture
from hystfit.diagnose import diagnose
from hystfit.factory import make_model, make_optimizer
from hystfit.registry import optimizers

CASES = {
    "dynamics+creep": dict(dynamics=True, dynamics_fn_Hz=700.0, creep=True),
    "delay+asymmetry": dict(delay=True, delay_s=3e-4, asymmetry=True),
    "none": {},
}


def captures(effects: dict) -> list[Capture]:
    r = tuple(np.linspace(0, 78, 14))
    w = tuple(0.35 * np.exp(-np.arange(14) / 5.0))
    plant = synth.Plant(thresholds_V=r, weights_um_per_V=w).with_effects(
        synth.Effects(noise=True, noise_sigma_um=0.008, **effects))
    caps = []
    for i, f in enumerate((15.0, 50.0, 120.0)):
        t, u = synth.rising_sine(90.0, f, 40, 10_000)
        caps.append(Capture(source=f"blind_{f:g}Hz.csv", t=t, u=u, y=synth.simulate_plant(plant, t, u, seed=10 + i),
                            dt=1e-4, amplitude_V=float(np.ptp(u)), frequency_Hz=f))
    return caps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES))
    args = ap.parse_args()
    opt = make_optimizer(optimizers.get("auto"))
    for name in args.cases.split(","):
        t0 = time.perf_counter()
        d = diagnose(captures(CASES[name]), make_model("pi"), opt)
        first, post = d.resolution_before_effects, d.resolution
        print(f"truth {name}: named {', '.join(d.explained_by) or 'none'}; held-out RMSE with them "
              f"{d.heldout_rmse_named:.4g} µm (noise floor {d.noise['sigma']:.4g} µm); recommended "
              f"{d.recommended_model} {d.recommended_options}; split {d.split['kind']}; {time.perf_counter() - t0:.0f} s")
        if first is not None:
            print("  resolution before the effects: " + "; ".join(
                f"{s['from']}→{s['to']} held-out {s['heldout_rmse_before_out']:.4g}→{s['heldout_rmse_after_out']:.4g} µm "
                f"({100 * s['reduction_mean_square']:.0f} % of the excess mean square, "
                f"{'adopted' if s['adopted'] else 'kept'})" for s in first["steps"]))
        if post is not None:
            print(f"  resolution after the effects: {post['from']}→{post['to']} held-out "
                  f"{post['heldout_rmse_before_out']:.4g}→{post['heldout_rmse_after_out']:.4g} µm, reduction "
                  f"{100 * post['reduction_mean_square']:.0f} % of the excess mean square, "
                  f"{'adopted' if post['adopted'] else 'kept'}")
        for c in d.resolution_during_selection:
            print(f"  during the selection, after {' + '.join(c['effects'])}: {c['from']}→{c['to']} "
                  f"{100 * c['reduction_mean_square']:.0f} %, {'adopted' if c['adopted'] else 'kept'}")
        for i, step in enumerate(d.steps):
            named = d.explained_by[i] if i < len(d.explained_by) else "nothing"
            together = [f"{r.effect} with {r.joint['with']}" for r in step if r.joint is not None]
            print(f"  step {i + 1}: " + ", ".join(f"{r.effect} {r.reduction:.2f}" for r in step)
                  + f" → {named}" + (f" (named together: {together[0]})" if together else ""))


if __name__ == "__main__":
    main()
