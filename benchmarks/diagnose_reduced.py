"""Scoring a fine base in the directions its data determine (``Linearization.reduced``): speed and agreement.

The withheld-effect captures with no effect switched on (raised cosines 30/60 V × 10/40/80 Hz and a
3-s step capture, 8 nm noise), a PI base with ``--n`` operators fitted on the fit part, and the
``dynamics`` effect (two searched parameters: the costliest search) fitted on top of it jointly
with a Gauss–Newton step of every base parameter — once with the searched parameters scored on the
full linearization (``REDUCE_ABOVE`` raised above the base's size) and once on the reduced one.
Prints the base's parameter count, the directions kept, the wall time of each fit and the
fit-sample SSE and φ each finds (the final solve is the full bounded one in both).

    python benchmarks/diagnose_reduced.py [--n 80]
"""

from __future__ import annotations

import argparse
import time

from hystfit import diagnose as D
from hystfit import effects as E
from hystfit.factory import make_model, make_optimizer
from hystfit.registry import optimizers


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=80, help="operators of the PI base")
    args = ap.parse_args()
    caps = D.withheld_effect_captures("none", 1.0, 0)
    settings = D.DiagnoseSettings()
    d = D._design(caps, settings, False)
    G = len(d.group_idx)
    jobs = D._base_fit_jobs(caps, d.views, d.group_idx, d.labels, d.conds, None)[G:]
    fits = D._base_fits(jobs, 0, make_model("pi", {"n_operators": args.n}), make_optimizer(optimizers.get("auto")),
                        0, None, None, False, lambda label: None)
    base = D._base_step(caps, d, fits, [c.y for c in caps], 0.008, settings)
    views = list(d.views)
    xs, lin = D._linearize(base.state, caps, views)
    eff = D._configured(["dynamics"], base.preds, views)[0]
    kept = lin.reduced(views).n
    print(f"PI base with {args.n} operators: {lin.n} step parameters, {kept} directions kept by the reduction")
    saved = E.REDUCE_ABOVE
    try:
        for label, limit in (("full linearization", 10 ** 9), ("reduced", saved)):
            E.REDUCE_ABOVE = limit
            t0 = time.perf_counter()
            fit = eff.fit(xs, views, lin)
            dt = time.perf_counter() - t0
            print(f"{label:>20}: {dt:7.1f} s, fit SSE {fit.sse:.6g}, phi {[round(float(p), 4) for p in fit.phi]}")
    finally:
        E.REDUCE_ABOVE = saved


if __name__ == "__main__":
    main()
