"""The recommended model diagnose hands over: started from the diagnosis's fit, or from scratch.

Run:  python benchmarks/diagnose_handover.py [--data DIR[,DIR…] …] [--work DIR] [--base MODEL]   (≈ 3 min on 2 cores)

For each data set (default: ``sample_data``; ``sample_data`` with its broadband captures; three
``hystfit synth campaign``s — seed 7 with every effect at 1.5×, seed 3 with asymmetry + dynamics +
noise, seed 11 with creep + delay + drift + noise; three rising-amplitude sines at 5, 20 and 50 Hz
with creep + delay + noise), ``diagnose`` with the base ``--base`` (default PI) and ``auto``, then the recommended model
identified on all the data twice: as ``hystfit diagnose`` does it (``auto``: from the diagnosis's own
fit, :func:`hystfit.diagnose.recommended_starts`, polished) and from scratch (``auto``'s own staged
start and polish, as before). Printed per data set: the effects named, which route was taken, the
wall time of each, the pooled RMSE over all samples at the handed-over start and after each.
Markdown.

A second table compares the hand-over's polish with its first damping as ``hystfit diagnose`` sets
it (:func:`hystfit.optimizers.lsq.polisher` with ``close_start``, λ₀ = 10⁻⁶) and with the default
λ₀ = 10⁻³: the wall time and the evaluations of each (a Jacobian counts d + 1), the pooled RMSE, and
the largest difference of a parameter between the two fits in its standard errors.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def _hystfit(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "hystfit", *args], check=True, capture_output=True, text=True)


def default_data(work: Path) -> list[list[Path]]:
    """The data sets of the module docstring (each a list of folders), written under ``work``."""
    sets = [[ROOT / "sample_data"], [ROOT / "sample_data", ROOT / "sample_data" / "broadband"]]
    for name, args in (("campaign_s7_all", ["--seed", "7", "--effects", "all", "--strength", "1.5"]),
                       ("campaign_s3_asym", ["--seed", "3", "--effects", "asymmetry,dynamics,noise"]),
                       ("campaign_s11_creep_delay_drift", ["--seed", "11", "--effects", "creep,delay,drift,noise"])):
        d = work / name
        if not d.exists():
            _hystfit("synth", "campaign", "--out", str(d), *args)
        sets.append([d])
    rising = work / "rising_sines"
    if not rising.exists():
        rising.mkdir(parents=True)
        for f in (5, 20, 50):
            _hystfit("synth", "capture", str(rising / f"rs_{f}Hz.csv"), "-a", "80", "-e", "rising-sine", "-f", str(f),
                     "--cycles", "12", "--seed", str(f), "--effects", "creep,delay,noise")
    sets.append([rising])
    return sets


def _start_rmse(caps, d, diag) -> float | None:
    """The pooled RMSE on all the data of the recommended model at the handed-over start (None
    without one)."""
    import math

    from hystfit.factory import make_model
    from hystfit.identify import adapted_model, condition_groups, prepare_shared
    from hystfit.conditions import condition_label
    from hystfit.objective import Objective, Series

    rec = prepare_shared(make_model(d.recommended_model, d.recommended_options), caps)
    starts = diag.recommended_starts(caps, d, rec)
    if starts is None:
        return None
    sse = n = 0.0
    for key, cs in condition_groups(caps, d.mode != "per-condition").items():
        theta = starts["global" if d.mode != "per-condition" else condition_label(key)]
        model, _ = adapted_model(cs, rec)
        obj = Objective(model, [Series(c.u, c.y, c.dt, c.warmup_samples) for c in cs])
        sse += float(obj(theta[None, :])[0]) * obj.n_total
        n += obj.n_total
    return math.sqrt(sse / n)


def main() -> None:
    import hystfit.cli  # noqa: F401  (the command line's BLAS thread settings, before numpy loads)
    import hystfit.diagnose as diag
    from hystfit.factory import make_model, make_optimizer
    from hystfit.io import load_captures
    from hystfit.registry import optimizers

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", nargs="*", default=None, help="data sets, each DIR[,DIR…] (default: the docstring's)")
    ap.add_argument("--work", type=Path, default=None, help="where the synthetic data sets are written (kept)")
    ap.add_argument("--base", default="pi", help="the base model diagnosed (default pi)")
    a = ap.parse_args()
    if a.data:
        sets = [[Path(p) for p in s.split(",")] for s in a.data]
    else:
        sets = default_data(a.work or Path(tempfile.mkdtemp(prefix="hystfit-handover-")))
    base, opt = make_model(a.base, {}), make_optimizer(optimizers.get("auto"))
    starts = diag.recommended_starts
    damping = []
    print("| data | named | recommended | route | time (s) | from scratch (s) | start RMSE | RMSE | from scratch RMSE |")
    print("|---|---|---|---|---:|---:|---:|---:|---:|")
    for folders in sets:
        caps = load_captures(folders)
        d = diag.diagnose(caps, base, opt, seed=0)
        name = " + ".join(f.name for f in folders)
        if not d.explained_by:
            print(f"| {name} | none | – | – | – | – | – | – | – |")
            continue
        rows = {}
        start_rmse = _start_rmse(caps, d, diag)
        for how in ("handed over", "scratch"):
            diag.recommended_starts = starts if how == "handed over" else (lambda *args, **kw: None)
            t = time.perf_counter()
            rec = diag.fit_recommended(caps, d, base, opt, seed=0)
            rows[how] = (time.perf_counter() - t, rec.pooled_rmse, rec.optimizer_name)
        diag.recommended_starts = starts
        (tw, rw, route), (tc, rc, _) = rows["handed over"], rows["scratch"]
        route = "diagnosis's fit, polished" if route != "auto" else "from scratch (no start)"
        opts = "".join(f" {k}={v}" for k, v in d.recommended_options.items())
        start = "–" if start_rmse is None else f"{start_rmse:.6f}"
        print(f"| {name} | {', '.join(d.explained_by)} | {d.recommended_model}{opts} | {route} | {tw:.2f} | {tc:.2f} "
              f"| {start} | {rw:.6f} | {rc:.6f} |")
        if route == "diagnosis's fit, polished":
            damping.append((name, _dampings(caps, d, base, opt, diag)))
    print("\n| data | λ₀ | time (s) | evaluations | RMSE | largest parameter difference (standard errors) |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, rows in damping:
        far = max(float(np.max(np.abs(a.theta - b.theta) / np.where(a.stderr > 0, a.stderr, np.inf)))
                  for a, b in zip(rows[0][3].fits, rows[1][3].fits))
        for lam, t, evals, rec in rows:
            print(f"| {name} | {lam:g} | {t:.2f} | {evals} | {rec.pooled_rmse:.6f} | {far:.4f} |")


def _dampings(caps, d, base, opt, diag) -> list[tuple]:
    """The hand-over's polish with its first damping as diagnose sets it and with the default one:
    per damping (λ₀, wall seconds, evaluations, the identification)."""
    from hystfit.optimizers import lsq

    rows = []
    for close in (True, False):
        diag.polisher = lambda close_start=False, close=close: lsq.polisher(close_start=close)
        try:
            t = time.perf_counter()
            rec = diag.fit_recommended(caps, d, base, opt, seed=0)
            rows.append((lsq.CLOSE_START_DAMPING if close else lsq.LSQ.damping0, time.perf_counter() - t,
                         sum(f.evaluations for f in rec.fits), rec))
        finally:
            diag.polisher = lsq.polisher
    return rows


if __name__ == "__main__":
    main()
