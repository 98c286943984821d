"""The blind cases behind the CHANGELOG's fixes of 2026-11-28, rebuilt and rerun.

Run:  python benchmarks/blind_cases.py [--other TREE]

Each case is made with ``hystfit synth capture`` (the virtual stage, fixed seeds) and small pandas
edits, then run through the command line as a user would, in a temporary directory. Printed:

1. A biased drive (±30 V about 100 V, 20 Hz, 5 kHz): ``identify --warmup 0.05`` RMSE per model; and
   two mildly biased sines of ``benchmarks/figure_bytes.py``'s blind set (10…70 V, 15…65 V).
2. lugre (fitted without an output offset by default) on a capture whose sensor is 50 µm off: the
   note naming ``--model-option offset=true``.
3. gpi and pi on an output with a large constant offset (nm with +5e6 nm; µm with +1e8 µm).
4. ``diagnose`` on a 500 Hz drive sampled at 5 kHz: the noise floor against the repeatability, and
   whether the command warns.
5. ``track --bandwidth 1000`` on a 5 kHz PI table: the refusal's line.
6. ``conditions.tonal_share`` of the drives hystfit.synth makes (what decides the broadband warning).

``--other TREE`` runs the cases of 1 with that tree too (a worktree of an older commit), beside this
one: the "before" of the CHANGELOG's numbers.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIASED_MODELS = ("pi", "bw", "gpi", "fp", "dahl", "ch", "nt", "lugre")


def hystfit(tree: Path, args: list, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-m", "hystfit", *map(str, args)], cwd=cwd, env=env,
                          capture_output=True, text=True)


def rmse(tree: Path, data: Path, cwd: Path, *extra) -> str:
    out = cwd / f"o_{abs(hash((str(tree), str(data), extra)))}"
    r = hystfit(tree, ["identify", data, "--out", out, "--force", "--no-plots", "--quiet", *extra], cwd)
    if r.returncode:
        return "error: " + r.stderr.strip().splitlines()[-1]
    cond = json.loads((out / "params.json").read_text())["conditions"][0]["metrics"]
    return f"{next(v for k, v in cond.items() if k.startswith('rmse_')):.4g}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--other", default=None, help="another tree for the 'before' of case 1")
    a = ap.parse_args()
    import pandas as pd

    trees = [("this", ROOT)] + ([("other", Path(a.other).resolve())] if a.other else [])
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        synth = [("bias.csv", ["-e", "sine", "-a", "30", "-f", "20", "--cycles", "4", "--fs", "5000", "--offset",
                               "100"]),
                 ("sine_35Hz.csv", ["-e", "sine", "-a", "30", "-f", "35", "--cycles", "6", "--offset", "40",
                                    "--seed", "12", "--effects", "dynamics"]),
                 ("sine_250Hz.csv", ["-e", "sine", "-a", "25", "-f", "250", "--cycles", "400", "--offset", "40",
                                     "--seed", "13"]),
                 ("rc.csv", ["-a", "60", "-f", "20", "--cycles", "3", "--fs", "5000"]),
                 ("f500.csv", ["-a", "60", "-f", "500", "--cycles", "60", "--fs", "5000", "--effects",
                               "dynamics,noise"])]
        for name, opts in synth:
            r = hystfit(ROOT, ["synth", "capture", d / name, *opts], d)
            assert r.returncode == 0, r.stderr
        rc = pd.read_csv(d / "rc.csv")
        off = rc.copy()
        off["displacement_um"] += 50.0
        off.to_csv(d / "off50.csv", index=False)
        for shift, name in ((0.0, "nm_0.csv"), (5e6, "nm_5e6.csv")):
            nm = rc.rename(columns={"displacement_um": "displacement_nm"})
            nm["displacement_nm"] = rc["displacement_um"] * 1000.0 + shift
            nm.to_csv(d / name, index=False)
        big = rc.copy()
        big["displacement_um"] += 1e8
        big.to_csv(d / "um_1e8.csv", index=False)

        print("## 1. Biased drives: identify RMSE (output unit)\n")
        cols = " | ".join(t for t, _ in trees)
        print(f"| capture | model | {cols} |\n|---|---|" + "---:|" * len(trees))
        for data, models, extra in (("bias.csv", BIASED_MODELS, ["--warmup", "0.05"]),
                                    ("sine_35Hz.csv", ("pi", "bw", "gpi", "dahl"), []),
                                    ("sine_250Hz.csv", ("pi", "bw", "gpi", "dahl"), [])):
            for m in models:
                vals = " | ".join(rmse(tree, d / data, d, "--model", m, *extra) for _, tree in trees)
                print(f"| {data} | {m} | {vals} |")

        print("\n## 2. lugre without an output offset, sensor 50 µm off\n")
        r = hystfit(ROOT, ["identify", d / "off50.csv", "--model", "lugre", "--out", d / "lug", "--no-plots"], d)
        note = [ln.strip() for ln in r.stderr.splitlines() if "output offset" in ln and "offset=true" in ln]
        print(f"RMSE {rmse(ROOT, d / 'off50.csv', d, '--model', 'lugre')}; note: {note[0] if note else 'none'}")

        print("\n## 3. Large output offsets: identify RMSE\n")
        print(f"| capture | model | {cols} |\n|---|---|" + "---:|" * len(trees))
        for data, m, seeds in (("nm_0.csv", "gpi", (0, 1, 2, 3)), ("nm_5e6.csv", "gpi", (0, 1, 2, 3)),
                               ("rc.csv", "pi", (0,)), ("um_1e8.csv", "pi", (0,))):
            vals = " | ".join(", ".join(rmse(tree, d / data, d, "--model", m, "--seed", s) for s in seeds)
                              for _, tree in trees)
            print(f"| {data} | {m} (seeds {', '.join(map(str, seeds))}) | {vals} |")

        print("\n## 4. diagnose on a 500 Hz drive at 5 kHz (10 samples per cycle)\n")
        r = hystfit(ROOT, ["diagnose", d / "f500.csv", "--model", "pi", "--out", d / "dg", "--no-plots"], d)
        n = json.loads((d / "dg" / "diagnosis.json").read_text())["noise"]
        warned = any(ln.startswith("warning: the noise floor") for ln in r.stderr.splitlines())
        print(f"noise floor σ {n['sigma_um']:.3g} µm, repeatability {n['repeatability_um']:.3g} µm, "
              f"samples per cycle {n['samples_per_cycle_min']:.3g}, warning printed: {warned}")

        print("\n## 5. track --bandwidth 1000 on a 5 kHz PI table\n")
        r = hystfit(ROOT, ["identify", d / "rc.csv", "--model", "pi", "--out", d / "pi", "--no-plots", "--quiet"], d)
        r = hystfit(ROOT, ["track", d / "pi" / "params.json", "--sine", "10,20", "--offset", "2", "--controller",
                           "pid", "--bandwidth", "1000", "--out", d / "trk", "--no-plots", "--quiet"], d)
        print(f"exit {r.returncode}: {r.stderr.strip().splitlines()[-1] if r.stderr.strip() else ''}")

    print("\n## 6. Tonal share: the strongest spectral line's share of the input's power\n")
    from hystfit import synth as S
    from hystfit.conditions import TONAL_SHARE_MIN, tonal_share

    fs = 10_000
    drives = [("sine 23.7 Hz, 5 cycles", S.sine(30, 23.7, 5, fs)),
              ("raised cosine, 1.5 cycles", S.raised_cosine(60, 20, 1.5, fs)),
              ("triangle 7 Hz", S.triangle(60, 7, 4, fs)), ("rising-amplitude sine", S.rising_sine(60, 20, 50, fs)),
              ("PRBS 2.5 kHz", S.prbs(60, fs, 3.0, 2500.0, seed=1)),
              ("multisine, 3 lines", S.multisine(60, [10, 40, 160], fs, 3.0)),
              ("multisine, 5 lines", S.multisine(60, S.multisine_frequencies(1000.0, 3.0, 5), fs, 3.0)),
              ("multisine, 40 lines", S.multisine(60, S.multisine_frequencies(1000.0, 3.0), fs, 3.0))]
    print(f"| drive | share | broadband (< {TONAL_SHARE_MIN:g}) |\n|---|---:|---|")
    for name, (_, u) in drives:
        share = tonal_share(u)
        print(f"| {name} | {100 * share:.1f} % | {'yes' if share < TONAL_SHARE_MIN else 'no'} |")


if __name__ == "__main__":
    main()
