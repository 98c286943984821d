"""The withheld-effect proof of ``hystfit diagnose`` at scale: confusion matrix true effect × verdict.

For every effect of the virtual actuator (``hystfit.synth``) at several strengths and seeds, and
for a plant with no effect at all, the captures of :func:`hystfit.diagnose.withheld_effect_captures`
(raised cosines 30/60 V × 10/40/80 Hz, five cycles, plus a 3-s step-and-hold capture at 60 V; white
sensor noise σ = 8 nm) are diagnosed with a base model that lacks the effect (default ``pi``).

Usage::

    PYTHONPATH=. python benchmarks/diagnose_confusion.py [--model pi] [--seeds 0 1] [--max-effects 2] [--weak]

Prints, as Markdown: the confusion matrix (rows: the effect switched on; columns: the verdict),
then one row per run (strength, seed, held-out RMSE before, the true effect's reduction, the
verdict's reduction, what else was named, the ``where`` indicators, runtime). The seed draws the
sensor noise of every capture. ``--weak`` runs strengths near the detection limit instead.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hystfit.diagnose import DiagnoseSettings, diagnose, withheld_effect_captures  # noqa: E402
from hystfit.effects import EFFECTS  # noqa: E402
from hystfit.registry import models, optimizers  # noqa: E402

#: Strengths per effect (multiples of the virtual actuator's realistic defaults, see hystfit.synth.Effects):
#: dynamics divides f_n = 1200 Hz; drift is tested stronger because its default (0.01 µm/s) moves a
#: 3-s capture by 0.03 µm, about the noise.
STRENGTHS = {
    "dynamics": (0.5, 1.0, 2.0),
    "creep": (0.5, 1.0, 2.0),
    "asymmetry": (0.5, 1.0, 2.0),
    "drift": (3.0, 5.0, 10.0),
    "delay": (0.5, 1.0, 2.0),
}


#: Weak strengths: near the detection limit (the gap above noise is about the noise or less). Here a
#: correct verdict or ``none`` is right; naming a *wrong* effect is the failure to look for.
WEAK = {
    "dynamics": (0.25,),
    "creep": (0.1, 0.2),
    "asymmetry": (0.1, 0.2),
    "drift": (1.0,),
    "delay": (0.1, 0.2),
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="pi")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--none-seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--max-effects", type=int, default=2)
    ap.add_argument("--weak", action="store_true", help="the weak strengths (detection limit) instead")
    args = ap.parse_args(argv)
    strengths = WEAK if args.weak else STRENGTHS

    truth_labels = list(EFFECTS) + ["none"]
    verdict_labels = list(EFFECTS) + ["none"]
    matrix = {t: {v: 0 for v in verdict_labels} for t in truth_labels}
    rows = []
    runs = [(e, s, seed) for e in EFFECTS for s in strengths[e] for seed in args.seeds]
    runs += [("none", 1.0, seed) for seed in ([] if args.weak else args.none_seeds)]
    settings = DiagnoseSettings(max_effects=args.max_effects)
    t_all = time.perf_counter()
    for effect, strength, seed in runs:
        caps = withheld_effect_captures(effect, strength, seed)
        t0 = time.perf_counter()
        d = diagnose(caps, models.get(args.model)(), optimizers.get("auto")(), seed=seed, settings=settings)
        dt = time.perf_counter() - t0
        matrix[effect][d.verdict] += 1
        red = {r.effect: r.reduction for r in d.effects}
        sm = d.where["summary"]
        rows.append((effect, strength, seed, d.gap["heldout_rmse_out"], red.get(effect, float("nan")),
                     d.verdict, red.get(d.verdict, float("nan")), ", ".join(d.explained_by[1:]) or "–",
                     sm["frequency_exponent"], sm.get("amplitude_exponent_alone"), sm["low_frequency_share"],
                     sm["high_frequency_share"], dt))
        print(f"# {effect} ×{strength:g} seed {seed}: {d.verdict} ({dt:.1f} s)", file=sys.stderr, flush=True)

    n = len(runs)
    correct = sum(matrix[t][t] for t in truth_labels)
    print(f"Base model `{args.model}`, {n} runs, {correct}/{n} verdicts correct, "
          f"total {time.perf_counter() - t_all:.0f} s.\n")
    print("| true effect ↓ / verdict → | " + " | ".join(verdict_labels) + " |")
    print("|---|" + "---:|" * len(verdict_labels))
    for t in truth_labels:
        print(f"| **{t}** | " + " | ".join(str(matrix[t][v]) if matrix[t][v] else "·" for v in verdict_labels) + " |")
    print()
    print("| effect | strength | seed | held-out RMSE before (µm) | reduction of the true effect | verdict | "
          "its reduction | also named | f-exponent | A-exponent (alone) | low-freq share | high-freq share | time (s) |")
    print("|---|---:|---:|---:|---:|---|---:|---|---:|---:|---:|---:|---:|")

    def f(x, d=2):
        return "–" if x is None or x != x else f"{x:.{d}f}"

    for e, s, seed, before, red_true, verdict, red_v, also, fe, ae, lo, hi, dt in rows:
        print(f"| {e} | {s:g} | {seed} | {before:.4f} | {f(red_true)} | {verdict} | {f(red_v)} | {also} | {f(fe)} | "
              f"{f(ae)} | {f(lo)} | {f(hi)} | {dt:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
