"""hystfit's speed, measured in one run, and the targets of the speed issue checked.

Run:  python benchmarks/speed.py [--repeat 3]          (≈ 4 min on 2 cores)

1. Population evaluation (``bench_kernels.py``): straightforward, NumPy, hystfit's simulation
   and objective for ``pi``, ``bw`` (and ``pi2``) at P = 200, N = 5,000.
2. End-to-end wall times (``bench_end_to_end.py``): start-up, identify with PSO 200 × 300 and
   with ``auto``, ``auto`` against the best of 15 PSO runs, compare of all ten models.
3. The targets, each with the measured value and whether it is met. Prints Markdown.
"""

from __future__ import annotations

import argparse
import platform
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_end_to_end as e2e  # noqa: E402
import bench_kernels as kern  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    import numba
    import os

    print(f"Machine: {platform.machine()}, {os.cpu_count()} cores, numba {numba.__version__} "
          f"({numba.get_num_threads()} threads), Python {platform.python_version()}\n")
    krows = kern.measure()
    print("### Population evaluation (P = 200, N = 5,000)\n")
    print(kern.table(krows, markdown=True))
    erows = e2e.measure(args.repeat)
    print("\n### End to end (best of the repeats; wall time includes ≈ 1 s of Python start-up and imports)\n")
    print(e2e.table(erows, markdown=True))

    k = {r["model"].split()[0]: r for r in krows}
    e = {r["label"]: r for r in erows}
    P, N = k["pi"]["P"], k["pi"]["N"]
    pi_sim_eps = P / k["pi"]["simulate"]
    pi_obj_eps = P / k["pi"]["objective"]
    ratio_pi = k["pi"]["straightforward"] / k["pi"]["objective"]
    ratio_bw = k["bw"]["straightforward"] / k["bw"]["objective"]
    steps_pi = P * N / k["pi"]["simulate"]  # the PI recurrence's output for every candidate
    steps_bw = P * N / k["bw"]["objective"]
    pso_pi = e["identify pi, PSO 200 × 300, 1 condition"]
    pso_bw = e["identify bw, PSO 200 × 300, 1 condition"]
    auto_pi = e["identify pi, auto, 1 condition"]
    best15 = e["identify pi, PSO 200 × 300 × 15 runs + polish, 1 condition"]
    best15_np = e["identify pi, PSO 200 × 300 × 15 runs, no polish, 1 condition"]
    cmp_nofig = e["compare sample_data, all 10 models, auto, no figures"]
    cmp_fig = e["compare sample_data, all 10 models, auto, with figures"]
    second = e["second CLI call (`hystfit models --json`)"]

    def ok(flag: bool) -> str:
        return "yes" if flag else "**no**"

    targets = [
        ("pi population evaluation ≥ 150,000 evaluations/s", f"{pi_obj_eps:,.0f} (objective), "
         f"{pi_sim_eps:,.0f} (full simulation)", ok(min(pi_obj_eps, pi_sim_eps) >= 150_000)),
        ("≥ 1,000× the straightforward implementation", f"pi {ratio_pi:,.0f}×, bw {ratio_bw:,.0f}×",
         ok(min(ratio_pi, ratio_bw) >= 1000)),
        ("bw within 2× of pi per sample-step", f"bw objective {steps_bw / 1e9:.2f} G/s vs pi simulation "
         f"{steps_pi / 1e9:.2f} G/s: {steps_pi / steps_bw:.2f}×", ok(steps_pi / steps_bw <= 2.0)),
        ("identify, PSO 200 × 300, 1 condition, under 1 s after compilation",
         f"fit pi {pso_pi['fit_s']:.2f} s, bw {pso_bw['fit_s']:.2f} s (command {pso_pi['wall_s']:.2f} / "
         f"{pso_bw['wall_s']:.2f} s)", ok(max(pso_pi["fit_s"], pso_bw["fit_s"]) < 1.0)),
        ("auto reaches the best of 15 PSO runs in under 0.2 s (pi)",
         f"auto {auto_pi['fit_s']:.3f} s, RMSE {auto_pi['rmse_um']:.6f} µm; best of 15 PSO runs "
         f"{best15_np['rmse_um']:.6f} µm, {best15['rmse_um']:.6f} µm polished",
         ok(auto_pi["fit_s"] < 0.2 and auto_pi["rmse_um"] <= best15["rmse_um"] * (1 + 1e-9))),
        ("compare sample_data, all ten models, auto, under 60 s",
         f"{cmp_fig['wall_s']:.1f} s with figures, {cmp_nofig['wall_s']:.1f} s without",
         ok(cmp_fig["wall_s"] < 60)),
        ("a second CLI call starts in under 1 s", f"{second['wall_s']:.2f} s", ok(second["wall_s"] < 1.0)),
    ]
    print("\n### Targets\n")
    print("| target | measured | met |\n|---|---|---|")
    for t in targets:
        print(f"| {t[0]} | {t[1]} | {t[2]} |")


if __name__ == "__main__":
    main()
