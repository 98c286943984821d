"""Where a diagnosis spends its CPU, and what each statistical setting of it costs and changes.

Run:  python benchmarks/diagnose_budget.py [DATA] [--model pi] [--repeat 2]

In one process, serially (``SELECTION_WORKERS = 1``, one BLAS thread), after a warm-up diagnosis
of ``DATA`` (default: sample_data): the CPU seconds (``time.process_time``, best of ``--repeat``)
of a default diagnosis, with the parts it spends them on — the searched candidates' scores per
effect, the placebo refits, the resolution checks, the linearizations — and then of a diagnosis
with each setting changed (``max_effects=2``, ``placebo_draws=3``, ``resolution_check=False``),
with its verdict, the base resolution it ended on and the held-out RMSE with the named effects.
Printed as Markdown. CPU seconds move less than wall time on a shared machine but still move;
``perf stat -e instructions:u`` around the command counts work more steadily.
"""

from __future__ import annotations

import argparse
import collections
import os
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=str(ROOT / "sample_data"))
    ap.add_argument("--model", default="pi")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()

    import hystfit.diagnose as D
    import hystfit.effects as E
    from hystfit.factory import make_model, make_optimizer
    from hystfit.io import LoadOptions, load_captures
    from hystfit.registry import optimizers

    D.SELECTION_WORKERS = 1
    caps = load_captures([Path(args.data)], LoadOptions())
    model, opt = make_model(args.model, {}), make_optimizer(optimizers.get("auto"), {})
    D.diagnose(caps, model, opt, seed=0)  # warm-up: imports, numba's cache

    cpu: dict[str, float] = collections.defaultdict(float)
    calls: collections.Counter = collections.Counter()

    def timed(owner, name, label):
        fn = getattr(owner, name)

        def wrapper(*a, **k):
            key = label(a)
            t0 = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                cpu[key] += time.process_time() - t0
                calls[key] += 1

        setattr(owner, name, wrapper)
        return fn

    def run(settings):
        best = None
        for _ in range(args.repeat):
            cpu.clear()
            calls.clear()
            t0 = time.process_time()
            d = D.diagnose(caps, model, opt, seed=0, settings=settings)
            total = time.process_time() - t0
            if best is None or total < best[0]:
                best = (total, d, dict(cpu), dict(calls))
        return best

    saved = [(E.Effect, "score", timed(E.Effect, "score", lambda a: f"score {a[0].name}")),
             (D, "_placebo_gain", timed(D, "_placebo_gain", lambda a: "placebo refits")),
             (D, "resolution_check", timed(D, "resolution_check", lambda a: "resolution checks")),
             (D, "_linearize", timed(D, "_linearize", lambda a: "linearizations"))]
    total, d, parts, counts = run(D.DiagnoseSettings())
    for owner, name, fn in saved:
        setattr(owner, name, fn)
    print(f"Data: {args.data} ({len(caps)} captures), base model {args.model}; best of {args.repeat}\n")
    print(f"### Default diagnosis: {total:.2f} s of CPU\n\nParts can nest (a resolution check linearizes and "
          "scores too), so they do not add up to the total.\n\n| part | CPU (s) | calls |\n|---|---:|---:|")
    for k, v in sorted(parts.items(), key=lambda kv: -kv[1]):
        print(f"| {k} | {v:.2f} | {counts[k]} |")

    print("\n### Settings\n\n| setting | CPU (s) | against default | named | base resolution | held-out RMSE |"
          "\n|---|---:|---:|---|---|---:|")
    for label, settings in [("default", D.DiagnoseSettings()),
                            ("max_effects=2", replace(D.DiagnoseSettings(), max_effects=2)),
                            ("placebo_draws=3", replace(D.DiagnoseSettings(), placebo_draws=3)),
                            ("resolution_check=False", replace(D.DiagnoseSettings(), resolution_check=False))]:
        t, dd, _, _ = run(settings) if label != "default" else (total, d, None, None)
        res = dd.base_resolution or {}
        print(f"| {label} | {t:.2f} | {t / total - 1:+.0%} | {', '.join(dd.explained_by) or 'none'} "
              f"| {res.get('given', '–')} → {res.get('final', '–')} | {dd.heldout_rmse_named:.5g} {dd.unit} |")


if __name__ == "__main__":
    main()
