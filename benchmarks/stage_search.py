"""The stage's search in a diagnosis: how many scores it takes and where it ends, against the
Nelder–Mead polish it replaced.

The diagnosis of DATA (default sample_data) with ``--model pi``, in this process, on one process
(``SELECTION_WORKERS = 1``: every score counted here), once warm-up first, then each variant:

- ``this tree``: the polish by L-BFGS-B on the SSE's exact gradient (``effects._gradient_polish``);
- ``Nelder–Mead polish``: the same, with the polish a Nelder–Mead of at most 40 scores from the same
  start (``effects._polish``, as before; the second iteration of a refit still starts from φ₀
  without a local grid).

Per variant: the stage's scores by kind (grid points ranked on the subsample of rows, grid points
scored on every row, polish scores — a gradient evaluation counts as one score), the CPU seconds
of the stage's fits (its polishes and the grid points it scores on every row; the ranking is
scored before them, in the diagnosis' CPU) and of the whole diagnosis, the first step's stage (f_n, ζ, held-out RMSE with
it) and the named effects with the held-out RMSE of the final model.

    python benchmarks/stage_search.py [DATA] [--repeat 2]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections import Counter
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from hystfit import diagnose as D  # noqa: E402
from hystfit import effects as E  # noqa: E402
from hystfit.factory import make_model, make_optimizer  # noqa: E402
from hystfit.io import LoadOptions, load_captures  # noqa: E402
from hystfit.registry import optimizers  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


class _Counting:
    """Counts the stage's scores by kind and times its fits, by wrapping the functions they run."""

    def __init__(self) -> None:
        self.scores: Counter = Counter()
        self.fit_cpu = 0.0
        self.coarse: set[int] = set()
        self.polishing = False
        self.patches: list = []

    def _patch(self, owner, name, value) -> None:
        self.patches.append((owner, name, getattr(owner, name)))
        setattr(owner, name, value)

    def install(self, variant: str) -> None:
        count = self
        real_coarse, real_score, real_fit = E.coarse_design, E.Effect.score, E.Effect.fit
        real_grad, real_sg, real_nm = E._gradient_polish, E._score_and_gradient, E._polish

        def coarse_design(design):
            out = real_coarse(design)
            count.coarse.add(id(out))
            return out

        def score(self, phi, scoring):
            if self.name == "dynamics":
                kind = "polish" if count.polishing else ("ranked on rows" if id(scoring) in count.coarse
                                                         else "grid, every row")
                count.scores[kind] += 1
            return real_score(self, phi, scoring)

        def score_and_gradient(effect, *a, **k):
            if effect.name == "dynamics":
                count.scores["polish"] += 1
            return real_sg(effect, *a, **k)

        def polishing(fn):
            def run(*a, **k):
                count.polishing = True
                try:
                    return fn(*a, **k)
                finally:
                    count.polishing = False
            return run

        def nelder_mead(effect, scoring, seen, x0, lo, hi, logs, maxfun=None):
            def scored(phi):
                key = phi.tobytes()
                if key not in seen:
                    seen[key] = effect.score(phi, scoring)
                return seen[key]
            return real_nm(scored, x0, lo, hi, logs)

        def fit(self, *a, **k):
            t = time.process_time()
            try:
                return real_fit(self, *a, **k)
            finally:
                if self.name == "dynamics":
                    count.fit_cpu += time.process_time() - t

        self._patch(E, "coarse_design", coarse_design)
        self._patch(D, "coarse_design", coarse_design)
        self._patch(E.Effect, "score", score)
        self._patch(E, "_score_and_gradient", score_and_gradient)
        self._patch(E, "_gradient_polish", polishing(nelder_mead if variant == "nm" else real_grad))
        self._patch(E.Effect, "fit", fit)

    def remove(self) -> None:
        for owner, name, value in reversed(self.patches):
            setattr(owner, name, value)


VARIANTS = (("this tree", "tree"), ("Nelder–Mead polish", "nm"))


def _run(caps, variant: str) -> dict:
    count = _Counting()
    count.install(variant)
    try:
        t = time.process_time()
        d = D.diagnose(caps, make_model("pi", {}), make_optimizer(optimizers.get("auto"), {}), seed=0)
        cpu = time.process_time() - t
    finally:
        count.remove()
    stage = next((e for e in d.steps[0] if e.effect == "dynamics"), None) if d.steps else None
    return {"scores": count.scores, "fit_cpu": count.fit_cpu, "cpu": cpu, "stage": stage, "d": d}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=str(ROOT / "sample_data"))
    ap.add_argument("--repeat", type=int, default=2, help="runs of each variant, alternately (median CPU)")
    args = ap.parse_args()
    D.SELECTION_WORKERS = 1
    caps = load_captures([Path(args.data)], LoadOptions())
    _run(caps, "tree")  # warm-up: kernels loaded, imports done
    runs: dict[str, list] = {v: [] for _, v in VARIANTS}
    for _ in range(args.repeat):
        for _, v in VARIANTS:
            runs[v].append(_run(caps, v))
    print(f"`diagnose {args.data} --model pi` in one process, warm, {args.repeat} runs of each variant "
          f"alternately (median CPU)\n")
    print("| variant | ranked on rows | grid, every row | polish | stage's fits, CPU (s) | diagnosis, CPU (s) "
          "| step 1: stage f_n (Hz), ζ, held-out RMSE with it | named | held-out RMSE with them |")
    print("|---|---:|---:|---:|---:|---:|---|---|---:|")
    for label, v in VARIANTS:
        r = runs[v][-1]
        s, d, st = r["scores"], r["d"], r["stage"]
        step1 = (f"{st.params['fn_Hz']:.6g}, {st.params['zeta']:.4g}, {st.heldout_rmse_after:.6g}"
                 if st is not None else "–")
        print(f"| {label} | {s['ranked on rows']} | {s['grid, every row']} | {s['polish']} "
              f"| {statistics.median(x['fit_cpu'] for x in runs[v]):.3f} "
              f"| {statistics.median(x['cpu'] for x in runs[v]):.2f} | {step1} | {', '.join(d.explained_by) or 'none'} "
              f"| {d.gap['heldout_rmse_after_explained_out']:.7g} |")


if __name__ == "__main__":
    main()
