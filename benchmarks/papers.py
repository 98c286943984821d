"""Each paper's headline experiment rerun with hystfit, the paper's numbers beside hystfit's → docs/papers.md.

Run:  python benchmarks/papers.py [--only 000,001,002,003,004] [--out docs/papers.md] [--jobs 2]

Every number in the page comes from a hystfit command printed beside it (run by this script in a
scratch directory, seeds fixed), on the paper's own parameters where the paper gives them (004
Table 1, 001 Table 1), else on hystfit's virtual actuator (``sample_data/``). About 15 minutes on
2 cores. Where hystfit does not reproduce a paper's ranking, the page says so and why.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data"
sys.path.insert(0, str(ROOT))


def hystfit(args: list[str], cwd: Path) -> float:
    """Run ``hystfit ARGS`` (this checkout) in ``cwd``; returns the wall time (s). Fails loudly."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", "from hystfit.cli import main; main()", *args], cwd=cwd, env=env,
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"hystfit {' '.join(args)} failed:\n{r.stderr[-2000:]}")
    return time.perf_counter() - t0


def cmd(args: list[str]) -> str:
    return "hystfit " + " ".join(shlex.quote(str(a)) for a in args)


def fmt(x: float, d: int = 4) -> str:
    return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{d}g}"


# ---------------------------------------------------------------------------------------------- 004
#: paper 004 Table 1 (IGWO row): Kv, α, β, γ identified on the tilt mirror; J of Table 2 (min/max/mean)
P004_THETA = {"Kv": 1.0406, "alpha": 0.2313, "beta": 5.2349, "gamma": 2.1457}
P004_TABLE2 = {"igwo": (4.76e-3, 5.38e-3, 4.96e-3), "gwo": (4.88e-3, 6.96e-3, 5.63e-3), "pso": (4.90e-3, 1.03e-2, 6.52e-3)}


def paper_004(work: Path, jobs: int) -> list[str]:
    from hystfit.models.bw import BoucWen

    fs, f = 1000.0, 1.0
    t = np.arange(int(2 * fs / f) + 1) / fs
    u = 48 * np.sin(2 * np.pi * f * t - np.pi / 2) + 48  # 004 §3.2: U = 48 sin(2πft …) + 48, f = 1 Hz
    p = P004_THETA
    y_clean = BoucWen().simulate_one(np.array([p["Kv"], p["alpha"], p["beta"], p["gamma"], 0.0]), u, 1 / fs)
    # noise so that the truth itself scores 004's best J (4.76e-3): J = Σe²/Σy²
    sigma = math.sqrt(4.76e-3 * float(np.mean(y_clean ** 2)))
    y = y_clean + np.random.default_rng(4).normal(0, sigma, u.size)
    csv = work / "p004_bw.csv"
    pd.DataFrame({"time_s": t, "voltage_V": u, "displacement_um": y}).to_csv(csv, index=False)
    bounds = [b for name in ("Kv", "alpha", "beta", "gamma") for b in ("--bounds", f"{name}=0.1:10")]
    args = ["compare", csv.name, "--models", "bw", "--opts", "pso,gwo,igwo", "--runs", "30", "--pop", "60",
            "--iters", "50", "--no-polish", *bounds, "--bounds", "y0=-0.001:0.001", "--seed", "0",
            "--jobs", str(jobs), "--no-plots", "--quiet", "--out", "p004"]
    wall = hystfit(args, work)
    df = pd.read_csv(work / "p004" / "compare.csv")
    L = ["## Paper 004 — IGWO vs GWO vs PSO on Bouc–Wen (Table 2)", "",
         f"Data: Bouc–Wen with **004's own Table 1 parameters** (IGWO row: Kv {p['Kv']}, α {p['alpha']}, "
         f"β {p['beta']}, γ {p['gamma']}), driven by 004's input 48 sin(2πt − π/2) + 48 V (1 Hz, 2 cycles, "
         f"1 kHz), plus Gaussian noise σ = {sigma:.4g} chosen so that the true parameters score 004's best "
         "J = 4.76e-3. Search box [0.1, 10] for Kv, α, β, γ as in 004, 60 agents × 50 iterations "
         "(004's choice), 30 seeded runs each, no polish. J = Σe²/Σy_meas² (`j`).", "",
         f"```\n{cmd(args)}\n```", f"({wall:.0f} s)", "",
         "| optimizer | 004 min J | hystfit min J | 004 max J | hystfit max J | 004 mean J | hystfit mean J |",
         "|---|---:|---:|---:|---:|---:|---:|"]
    for o in ("igwo", "gwo", "pso"):
        j = df[df["optimizer"] == o]["j"].to_numpy()
        a, b, c = P004_TABLE2[o]
        L.append(f"| {o} | {fmt(a)} | {fmt(j.min())} | {fmt(b)} | {fmt(j.max())} | {fmt(c)} | {fmt(j.mean())} |")
    means = {o: df[df["optimizer"] == o]["j"].mean() for o in ("igwo", "gwo", "pso")}
    order = sorted(means, key=means.get)
    spread = (max(means.values()) - min(means.values())) / min(means.values())
    jm = float(np.max(np.abs(df["j_model"] / df["j"] - 1))) if "j_model" in df else float("nan")
    L += ["", f"J with the model output as denominator (`j_model`, 004 eq. 16 as printed) differs from `j` by at "
          f"most {100 * jm:.2g} % here. hystfit's ranking by mean J: {' < '.join(order)} (means within "
          f"{100 * spread:.2g} % of each other); 004's: igwo < gwo < pso. "
          + ("Reproduced." if order == ["igwo", "gwo", "pso"] and spread > 0.01 else
             "**Not reproduced**: with equal budgets on this 4-parameter problem all three reach the noise floor "
             "in every run, and PSO (inertia 0.9 → 0.4, velocity clamp, reflection at the bounds; 001's "
             "formulation) is not worse than GWO or IGWO. 004 does not give its PSO settings; its Table 2 "
             "spread (PSO max J 1.03e-2, twice the floor) suggests a PSO that stalls, which ours does not."), ""]
    return L


# ---------------------------------------------------------------------------------------------- 001
P001 = {"A1": 1e-8, "A2": 0.46827, "A3": 80.6817, "A4": 0.0031324, "A5": -0.2, "A6": 0.0010047}


def paper_001(work: Path, jobs: int) -> list[str]:
    from hystfit.params import DataScale
    from hystfit.factory import make_model

    fs = 1000.0
    t = np.arange(int(2 * fs) + 1) / fs
    u = 1.65 - 1.65 * np.cos(2 * np.pi * t)  # 001: 0 … 3.3 V, 1 Hz
    scale = DataScale.from_arrays([u], [u], [1 / fs])
    m = make_model("ch").adapt(scale)  # V_m, V_M of eq. 1 from this input
    names = [q.name for q in m.params(scale)]
    theta = np.array([P001.get(n, 0.0) for n in names], dtype=float)
    y = m.simulate_one(theta, u, 1 / fs)
    args = ["compare", "a20V_f10Hz.csv", "--models", "ch", "--opts", "pso,pso-cf", "--runs", "10", "--pop", "40",
            "--iters", "100", "--no-polish", "--seed", "0", "--jobs", str(jobs), "--no-plots", "--quiet",
            "--out", "p001"]
    (work / "a20V_f10Hz.csv").write_bytes((SAMPLE / "a20V_f10Hz.csv").read_bytes())
    wall = hystfit(args, work)
    df = pd.read_csv(work / "p001" / "compare.csv")
    L = ["## Paper 001 — Coleman–Hodgdon identified by PSO (Table 1)", "",
         f"001's Table 1 values ({', '.join(f'{k} = {v:g}' for k, v in P001.items())}) on 001's 0–3.3 V, 1 Hz "
         f"input give, through 001 eq. 1 as hystfit implements it (parameter order {', '.join(names)}), an output "
         f"spanning {np.ptp(y):.3g} µm — not the 0–1880 µm 001 reports: the printed values (A1 = 1e-8 with "
         "A2·e^{−A3·V_R} ≈ 0 makes the slope ≈ 1e-8 µm/V) cannot be the ones behind its figures, so 001's own "
         "parameters cannot be rerun. Instead: PSO (001 eq. 4–5) against PSO with constriction (eq. 6–7) on "
         "the virtual actuator's 20 V, 10 Hz capture, equal budgets (40 × 100), 10 seeded runs.", "",
         f"```\n{cmd(args)}\n```", f"({wall:.0f} s)", "",
         "| optimizer | best RMSE (µm) | median RMSE (µm) | worst RMSE (µm) |", "|---|---:|---:|---:|"]
    for o in ("pso", "pso-cf"):
        r = df[df["optimizer"] == o]["rmse_um"].to_numpy()
        L.append(f"| {o} | {fmt(r.min())} | {fmt(float(np.median(r)))} | {fmt(r.max())} |")
    L += ["", "001 reports convergence after 90 generations but no error figure to compare with.", ""]
    return L


# ---------------------------------------------------------------------------------------------- 002
#: paper 002 Table 3: max RMSE (µm), max MAPE, max SMAPE, min R² over 20/40/60 V × 10–80 Hz
P002 = {"nt": (0.0812, 0.045, 0.0456, 0.9994), "dahl": (0.8485, 0.2927, 0.539, 0.9399),
        "lugre": (35.6933, 7218.6, 0.7143, 0.0116), "pi": (0.3219, 0.1694, 0.2195, 0.9921),
        "bw": (1.0414, 0.2591, 0.239, 0.9095), "fp": (3.6322, 0.6044, 1.2133, 0.2147)}


def paper_002(work: Path, jobs: int) -> list[str]:
    args = ["compare", str(SAMPLE), "--models", "nt,dahl,lugre,pi,bw,fp", "--opts", "auto", "--mape-floor", "0",
            "--seed", "0", "--jobs", str(jobs), "--no-plots", "--quiet", "--out", "p002"]
    wall = hystfit(args, work)
    df = pd.read_csv(work / "p002" / "compare.csv")
    L = ["## Paper 002 — NT against Dahl, LuGre, PI, Bouc–Wen, FP (Table 3)", "",
         "Data: hystfit's virtual actuator (`sample_data/`: 20/40/60 V × 10–80 Hz, 002's grid), one "
         "parameter set per condition, the `auto` optimizer (exact linear solves + search), MAPE and SMAPE over "
         "every sample as in 002 (`--mape-floor 0`). Worst value over the 24 conditions, paper | hystfit.", "",
         f"```\n{cmd(args)}\n```", f"({wall:.0f} s)", "",
         "| model | max RMSE µm (002 \\| hystfit) | max MAPE | max SMAPE | min R² |", "|---|---|---|---|---|"]
    ours = {}
    for mdl, (rm, mp, sm, r2) in P002.items():
        d = df[df["model"] == mdl]
        o = (d["rmse_um"].max(), d["mape"].max(), d["smape"].max(), d["r2"].min())
        ours[mdl] = o
        L.append(f"| {mdl} | {fmt(rm)} \\| {fmt(o[0])} | {fmt(mp)} \\| {fmt(o[1])} | {fmt(sm)} \\| {fmt(o[2])} | "
                 f"{fmt(r2)} \\| {fmt(o[3])} |")
    rank_ours = sorted(ours, key=lambda k: ours[k][0])
    rank_paper = sorted(P002, key=lambda k: P002[k][0])
    L += ["", f"Ranking by worst RMSE — 002: {' < '.join(rank_paper)}; hystfit: {' < '.join(rank_ours)}. "
          + ("Same order." if rank_ours == rank_paper else
             "**Not the same order**: the virtual actuator is not 002's stage (its loop is a PI-type hysteresis "
             "with creep and a stage resonance, so the PI-like models fit it well), and hystfit solves the linear "
             "parameters exactly, which removes the failures (LuGre R² 0.0116, FP 0.2147) 002 reports for "
             "its search."), ""]
    return L


# ---------------------------------------------------------------------------------------------- 003
P003_BW = {"ff+pid": (91.5, 59.9), "smc-noinv": (110.1, 63.9), "smc": (119.9, 86.2)}


def paper_003(work: Path, jobs: int) -> list[str]:
    a1 = ["identify", str(SAMPLE / "broadband"), "--model", "hammerstein", "--seed", "0", "--no-plots", "--quiet",
          "--out", "p003_id"]
    w1 = hystfit(a1, work)
    ident = json.loads((work / "p003_id" / "params.json").read_text())
    a2 = ["track", "p003_id/params.json", "--sine", "2,10", "--offset", "20", "-c", "ff+pid,smc-noinv,smc",
          "--measure-bandwidth", "--no-plots", "--quiet", "--out", "p003_trk"]
    w2 = hystfit(a2, work)
    bw = json.loads((work / "p003_trk" / "bandwidth.json").read_text())["controllers"]
    L = ["## Paper 003 — Hammerstein model and sliding-mode inverse compensation (bandwidths)", "",
         "Model: hystfit's Hammerstein (PI + ERA state space, 003 eq. 1–12) identified on the virtual "
         "actuator's broadband captures; then 003's three controllers in closed loop around it — PID with "
         "inverse compensation (`ff+pid`), sliding mode without inverse compensation (`smc-noinv`), sliding "
         "mode with inverse compensation (`smc`) — and their tracking (−3 dB) and disturbance-rejection (0 dB) "
         "bandwidths measured with 2 µm sines about 20 µm.", "",
         f"```\n{cmd(a1)}\n{cmd(a2)}\n```", f"({w1 + w2:.0f} s)", "",
         "Fit: " + ", ".join(f"{c['label']} RMSE {c['metrics']['rmse_um']:.3g} µm, RE {c['metrics']['re']:.3g}"
                            for c in ident["conditions"]) + " (003 Table 1, 1–200 Hz sines on its stage: RMSE "
         "0.18–0.43 µm, RE 0.012–0.037; the virtual actuator is less noisy and its captures are the ones fitted).", "",
         "| controller | 003 tracking −3 dB (Hz) | hystfit | 003 disturbance 0 dB (Hz) | hystfit |",
         "|---|---:|---:|---:|---:|"]
    for c, (tr, di) in P003_BW.items():
        v = bw[c]
        L.append(f"| {c} | {tr} | {fmt(v['tracking_bandwidth_Hz'])} | {di} | {fmt(v['disturbance_bandwidth_Hz'])} |")
    L += ["", "0 = no rejection already at the lowest frequency, – = beyond the measured grid (fs/2000 … fs/5). "
          "The loop is a simulation around the identified model itself, so the inverse compensation is nearly "
          "exact and the controllers with it (`ff+pid`, `smc`) track far beyond 003's ≈ 100 Hz (003's stage "
          "adds modelling error, sensor noise and amplifier limits); without it (`smc-noinv`) the sliding mode "
          "alone tracks to a few tens of Hz. The disturbance-rejection bandwidths are set by the feedback "
          "designs (automatic bandwidth fs/20 for the PID, hystfit's default sliding-mode design; 003's gains "
          "are not given) and `smc` and `smc-noinv` share theirs, since the feedforward does not act on a "
          "disturbance.", ""]

    def holds(a, b, key):
        x, y = bw[a][key], bw[b][key]
        x = math.inf if x is None or (isinstance(x, float) and math.isnan(x)) else x
        y = math.inf if y is None or (isinstance(y, float) and math.isnan(y)) else y
        return x > y

    verdicts = [f"{a} > {b} for {what}: {'yes' if holds(a, b, key) else 'no'}"
                for key, what in (("tracking_bandwidth_Hz", "tracking"), ("disturbance_bandwidth_Hz", "disturbance"))
                for a, b in (("smc", "smc-noinv"), ("smc", "ff+pid"))]
    L += ["003's rankings here — " + "; ".join(verdicts) + " (003: yes to all four).", ""]
    return L


# ---------------------------------------------------------------------------------------------- 000
def paper_000(work: Path, jobs: int) -> list[str]:
    (work / "a60V_f50Hz.csv").write_bytes((SAMPLE / "a60V_f50Hz.csv").read_bytes())
    args = ["compare", "a60V_f50Hz.csv", "--models", "pi2", "--opts", "ipso,pso,ga", "--runs", "15", "--pop", "200",
            "--iters", "300", "--no-polish", "--seed", "0", "--jobs", str(jobs), "--no-plots", "--quiet",
            "--out", "p000"]
    wall = hystfit(args, work)
    df = pd.read_csv(work / "p000" / "compare.csv")
    L = ["## Paper 000 — improved PSO for the electromechanical model (generalized PI + second-order stage)", "",
         "Model `pi2` (000's generalized PI driving a second-order stage, two-step identification: the stage "
         "first, then the hysteresis) on the virtual actuator's 60 V, 50 Hz capture; IPSO against PSO-w and GA "
         "with 000's budget (200 particles × 300 iterations, 15 runs; IPSO has no iteration count, so "
         "`--iters` gives it the same evaluation budget), no polish. Our copy of 000 lacks its Table 2 (an image), so "
         "there are no numbers to put beside; 000's claim is that IPSO converges faster to a better fit.", "",
         f"```\n{cmd(args)}\n```", f"({wall:.0f} s)", "",
         "| optimizer | best RMSE (µm) | median RMSE (µm) | worst RMSE (µm) | mean run time (s) |",
         "|---|---:|---:|---:|---:|"]
    for o in ("ipso", "pso", "ga"):
        d = df[df["optimizer"] == o]
        r = d["rmse_um"].to_numpy()
        L.append(f"| {o} | {fmt(r.min())} | {fmt(float(np.median(r)))} | {fmt(r.max())} | "
                 f"{fmt(float(d['runtime_s'].mean()), 3)} |")
    med = {o: float(np.median(df[df['optimizer'] == o]['rmse_um'])) for o in ('ipso', 'pso', 'ga')}
    best = min(med, key=med.get)
    a2 = ["identify", "a60V_f50Hz.csv", "--model", "pi2", "--seed", "0", "--no-plots", "--quiet", "--out", "p000_auto"]
    w2 = hystfit(a2, work)
    auto = json.loads((work / "p000_auto" / "params.json").read_text())["conditions"][0]["metrics"]["rmse_um"]
    L += ["", f"Lowest median RMSE: {best}. " + ("000's ranking (IPSO first) reproduced." if best == "ipso" else
                                                   "**000's ranking (IPSO first) not reproduced** at this budget."),
          "", f"For scale, hystfit's default route on the same data, `{cmd(a2)}` ({w2:.0f} s: ρ and y0 solved "
          f"exactly, the other ten parameters searched), reaches RMSE {auto:.3g} µm: the twelve-parameter "
          "generalized PI is hard for every metaheuristic at this budget, and the ranking among them says little.",
          ""]
    return L


EXPERIMENTS = {"000": paper_000, "001": paper_001, "002": paper_002, "003": paper_003, "004": paper_004}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=",".join(EXPERIMENTS), help="comma list of papers (000 … 004)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "papers.md"))
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    keys = [k.strip() for k in args.only.split(",") if k.strip()]
    bad = [k for k in keys if k not in EXPERIMENTS]
    if bad:
        raise SystemExit(f"--only: unknown paper {bad[0]!r}; choose from {', '.join(EXPERIMENTS)}")
    t0 = time.perf_counter()
    lines = ["# The papers' experiments rerun with hystfit", "",
             "Made by `python benchmarks/papers.py` (every command below was run by it, seeds fixed; rerun it to "
             "regenerate this page). Paper numbers are copied from `shared/papers/`; where hystfit does not "
             "reproduce a paper's ranking the section says so and why.", ""]
    with tempfile.TemporaryDirectory() as tmp:
        for k in keys:
            t = time.perf_counter()
            lines += EXPERIMENTS[k](Path(tmp), args.jobs)
            print(f"paper {k}: {time.perf_counter() - t:.0f} s", file=sys.stderr)
    lines += [f"Total time of this page: {time.perf_counter() - t0:.0f} s on {os.cpu_count()} cores "
              f"(jobs = {args.jobs}).", ""]
    Path(args.out).write_text("\n".join(lines))
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
