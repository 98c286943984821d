"""hystfit's speed, measured in one run, and the targets of the speed issue checked.

Run:  python benchmarks/speed.py [--repeat 3] [--long]     (≈ 8 min on 2 cores; --long adds ≈ 20 min)
      python benchmarks/speed.py --commands [--repeat 5]   (only the whole-command targets, ≈ 3 min)
      python benchmarks/speed.py --imports                 (only what the one-condition identify and
                                                            ``hystfit models --json`` import, ≈ 5 s)

1. Population evaluation (``bench_kernels.py``): straightforward, NumPy, hystfit's simulation
   and objective for ``pi``, ``bw`` (and ``pi2``) at P = 200, N = 5,000.
2. End-to-end wall times (``bench_end_to_end.py``): start-up, the Quickstart with and without
   figures, one condition with PSO 200 × 300 with and without figures, identify with ``auto``,
   ``auto`` against the best of 15 PSO runs, compare of all ten models, diagnose.
3. What the one-condition command imports (``python -X importtime``, each top-level package's own
   import time wherever it is imported from), figures against the
   straightforward way (``bench_figures.py``), a 10⁷-row CSV load (``bench_load.py``) and, with
   ``--long``, ``fp`` and ``gpi`` on a 10⁶-sample capture (``memory.py``).
4. The targets, each with the measured value and whether it is met. Prints Markdown.

``--commands`` measures only the whole-command targets (Quickstart with and without figures, one
condition with figures, diagnose, compare with figures): each command's best wall time beside its
target, and the CPU seconds it used (its own process and every child), which a shared machine
disturbs less than the wall time, then the Quickstart's figures against its load + fit.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_end_to_end as e2e  # noqa: E402
import bench_figures as figs  # noqa: E402
import bench_kernels as kern  # noqa: E402
import bench_load as load  # noqa: E402


def import_breakdown(args: list[str], top: int = 10) -> tuple[float, list[tuple[str, float]]]:
    """Total import time of a CLI command and its most expensive top-level packages (``-X importtime``).

    Each package is charged its modules' own (self) times, wherever they were imported from: numba's
    context loads ``numba.np.*`` and ``scipy.linalg`` when the first kernel runs, pandas may come in
    through a report module; a cumulative time would charge them to whichever module came first.
    """
    with tempfile.TemporaryDirectory() as tmp:
        def cmd(name: str) -> list[str]:
            out = ["--out", str(Path(tmp) / name)] if args[0] in ("identify", "compare", "diagnose") else []
            return [sys.executable, "-X", "importtime", "-c", "from hystfit.cli import main; main()", *args, *out]

        subprocess.run(cmd("warm"), cwd=e2e.ROOT, env=e2e.command_env(), capture_output=True, check=True)  # caches warm
        r = subprocess.run(cmd("out"), cwd=e2e.ROOT, env=e2e.command_env(), capture_output=True, text=True, check=True)
    per_pkg: dict[str, float] = {}
    for line in r.stderr.splitlines():
        if not line.startswith("import time:") or "|" not in line:
            continue
        parts = line[len("import time:"):].split("|")
        try:
            own = int(parts[0]) / 1e6
        except ValueError:
            continue
        pkg = parts[2].strip().split(".")[0]
        per_pkg[pkg] = per_pkg.get(pkg, 0.0) + own
    return sum(per_pkg.values()), sorted(per_pkg.items(), key=lambda kv: -kv[1])[:top]


def print_import_breakdowns() -> None:
    """The import breakdown of the one-condition ``identify`` and of ``hystfit models --json``."""
    import os

    print(f"Load average at the start {os.getloadavg()[0]:.1f}\n")
    one = ["identify", e2e.ONE, "--model", "pi", *e2e.PSO, "--no-polish", "--quiet", "--no-plots"]
    for title, args in (("identify pi, PSO 200 × 300, --no-polish, 1 condition, --no-plots", one),
                        ("hystfit models --json", ["models", "--json"])):
        total, rows = import_breakdown(args)
        print(f"### Imports of `{title}`: {total:.2f} s\n")
        print("| package | import (s) |\n|---|---:|")
        for pkg, sec in rows:
            print(f"| {pkg} | {sec:.3f} |")
        print()


#: the whole-command targets of the speed issue: (row label of bench_end_to_end, target wall time in s);
#: the Quickstart without figures has none of its own (it is the "load + fit" the figures are held to)
QUICKSTART_NO_PLOTS = "Quickstart: identify sample_data (24 conditions), --no-plots"
COMMAND_TARGETS = [
    ("Quickstart: identify sample_data (24 conditions), every figure", 3.0),
    (QUICKSTART_NO_PLOTS, None),
    ("identify pi, PSO 200 × 300, --no-polish, 1 condition, with figures", 1.0),
    ("diagnose sample_data --model pi", 3.0),
    ("compare sample_data, all 10 models, auto, with figures", 20.0),
]


def cpu_model() -> str:
    """The processor's model name and widest vector extension (Linux: /proc/cpuinfo), else platform's."""
    try:
        with open("/proc/cpuinfo") as f:
            info = f.read()
    except OSError:
        return platform.processor() or platform.machine()
    name = next((ln.split(":", 1)[1].strip() for ln in info.splitlines() if ln.startswith("model name")), "")
    flags = set(next((ln.split(":", 1)[1].split() for ln in info.splitlines() if ln.startswith("flags")), []))
    widest = next((f for f in ("avx512f", "avx2", "avx", "sse4_2") if f in flags), "none")
    mhz = next((ln.split(":", 1)[1].strip() for ln in info.splitlines() if ln.startswith("cpu MHz")), "")
    return f"{name or platform.machine()}{f' {float(mhz):.0f} MHz' if mhz else ''}, widest vectors {widest}"


#: :func:`reference_seconds`' workloads, run in a fresh process with one BLAS thread
REFERENCE = """
import json, time
import numpy as np

def loop():
    s = 0
    for i in range(1_000_000):
        s += i

a = np.random.default_rng(0).standard_normal((1000, 1000))
out = {}
for name, fn in (("python_loop_1e6_s", loop), ("matmul_1000_s", lambda: a @ a)):
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    out[name] = min(times)
print(json.dumps(out))
"""


def reference_seconds() -> dict[str, float]:
    """The same small workloads on any machine (best of 3, one BLAS thread), to hold one machine's
    command times against another's: a Python loop of 10⁶ additions (what start-up, imports and
    orchestration cost) and a 1000 × 1000 float64 matrix product (the BLAS of the least-squares
    solves)."""
    import json

    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    r = subprocess.run([sys.executable, "-c", REFERENCE], env=env, capture_output=True, text=True, check=True)
    return json.loads(r.stdout)


def machine_line() -> str:
    """One line naming the machine, with its :func:`reference_seconds` and the load average."""
    import numba

    ref = reference_seconds()
    return (f"Machine: {platform.machine()}, {cpu_model()}, {os.cpu_count()} cores, numba {numba.__version__}, "
            f"Python {platform.python_version()}; reference workloads: Python loop of 10⁶ additions "
            f"{ref['python_loop_1e6_s'] * 1e3:.0f} ms, 1000 × 1000 matrix product (one thread) "
            f"{ref['matmul_1000_s'] * 1e3:.0f} ms; load average at the start {os.getloadavg()[0]:.1f} "
            f"(above 0.5 the machine is shared: compare ratios within one run)\n")


def _children_cpu() -> float:
    """CPU seconds of every child reaped so far (and of the children they reaped)."""
    e2e.reap_orphans()
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def command_targets(repeat: int) -> list[dict]:
    """Best wall time and the CPU seconds of that run for each command of :data:`COMMAND_TARGETS`."""
    commands = dict(e2e.COMMANDS)
    e2e.adopt_orphans()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, target in COMMAND_TARGETS:
            args, out = commands[label], Path(tmp) / "out"
            e2e.run(args, out)  # warm numba's on-disk cache
            runs = []
            for _ in range(repeat):
                cpu0, t0 = _children_cpu(), time.perf_counter()
                e2e.run(args, out)
                runs.append((time.perf_counter() - t0, _children_cpu() - cpu0))
            wall, cpu = min(runs)
            rows.append({"label": label, "target_s": target, "wall_s": wall, "cpu_s": cpu,
                         "walls": [w for w, _ in runs]})
    return rows


def print_command_targets(repeat: int) -> None:
    import os

    print(machine_line())
    print(f"Best of {repeat} runs after a warm-up\n")
    print("| command | wall (s) | target (s) | met | CPU of that run (s) | every run (s) |\n|---|---:|---:|---|---:|---|")
    rows = command_targets(repeat)
    for r in rows:
        target = "–" if r["target_s"] is None else f"{r['target_s']:g}"
        met = "–" if r["target_s"] is None else ("yes" if r["wall_s"] <= r["target_s"] else "**no**")
        print(f"| {r['label']} | {r['wall_s']:.2f} | {target} | {met} "
              f"| {r['cpu_s']:.2f} | {', '.join(f'{w:.2f}' for w in r['walls'])} |")
    by = {r["label"]: r for r in rows}
    figures = by[COMMAND_TARGETS[0][0]]["wall_s"] - by[QUICKSTART_NO_PLOTS]["wall_s"]
    load_fit = by[QUICKSTART_NO_PLOTS]["wall_s"]
    print(f"\nQuickstart figures {figures:.2f} s against load + fit {load_fit:.2f} s: "
          f"{'met' if figures <= load_fit else '**not met**'} (figures cost at most load + fit)")
    print(f"\nLoad average at the end {os.getloadavg()[0]:.1f}")


def long_models(models: tuple[str, ...] = ("fp", "gpi"), samples: int = 1_000_000) -> dict[str, float | None]:
    """Wall time of ``identify`` (auto, no figures) on a 10⁶-sample capture of the virtual actuator."""
    out: dict[str, float | None] = {}
    r = subprocess.run([sys.executable, str(Path(__file__).parent / "memory.py"), "--models", ",".join(models),
                        "--samples", str(samples), "--timeout", "1800"], cwd=e2e.ROOT, capture_output=True, text=True)
    for line in r.stdout.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) >= 2 and cells[0] in models:
            try:
                out[cells[0]] = float(cells[1])
            except ValueError:
                out[cells[0]] = None
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--long", action="store_true", help="also fp and gpi on a 10^6-sample capture (≈ 20 min)")
    ap.add_argument("--commands", action="store_true", help="only the whole-command targets (≈ 3 min)")
    ap.add_argument("--imports", action="store_true", help="only the import breakdowns (≈ 5 s)")
    args = ap.parse_args()
    if args.commands:
        print_command_targets(args.repeat)
        return
    if args.imports:
        print_import_breakdowns()
        return
    print(machine_line())
    krows = kern.measure()
    print("### Population evaluation (P = 200, N = 5,000)\n")
    print(kern.table(krows, markdown=True))
    erows = e2e.measure(args.repeat)
    print("\n### End to end (best of the repeats; wall time includes Python start-up and imports, ≈ 0.5 s)\n")
    print(e2e.table(erows, markdown=True))

    # --no-plots: the figures are drawn by a forked figure server whose imports would be counted too
    one = ["identify", e2e.ONE, "--model", "pi", *e2e.PSO, "--no-polish", "--quiet", "--no-plots"]
    imp_total, imp_top = import_breakdown(one)
    print(f"\n### Imports of `identify` (1 condition; the command's own process, matplotlib is imported by "
          f"the figure server): {imp_total:.2f} s\n")
    print("| package | import (s) |\n|---|---:|")
    for pkg, sec in imp_top:
        print(f"| {pkg} | {sec:.2f} |")
    fq = figs.quickstart_figures()
    fl = [figs.long_loop(n) for n in (10**6, 10**7)]
    print("\n### Figures (same fits; hystfit: parallel, per-pixel; straightforward: serial, every k-th sample)\n")
    print("| figures | hystfit | straightforward | ratio |\n|---|---:|---:|---:|")
    print(f"| Quickstart: {fq['hystfit_figures']} figures (straightforward draws {fq['straightforward_figures']}) | "
          f"{fq['hystfit_s']:.2f} s | {fq['straightforward_s']:.2f} s | {fq['straightforward_s'] / fq['hystfit_s']:.1f}× |")
    for r in fl:
        print(f"| loop of a periodic capture, {r['samples']:.0e} samples: time, points drawn, drawn/true voltage span | "
              f"{r['hystfit_s']:.2f} s, {r['hystfit_points']:,}, {r['hystfit_span']:.2f} | "
              f"{r['straightforward_s']:.2f} s, {r['straightforward_points']:,}, {r['straightforward_span']:.2f} | "
              f"{r['straightforward_s'] / r['hystfit_s']:.2f}× |")
    lrows = {r["reader"]: r for r in load.measure()}
    print("\n### Loading a 10⁷-row CSV (fresh process each)\n")
    print("| reader | load (s) | peak RSS (MB) |\n|---|---:|---:|")
    for r in lrows.values():
        print(f"| {r['reader']} | {r['wall_s']:.1f} | {r['peak_MB']:.0f} |")
    longm = long_models() if args.long else {}
    print_targets(krows, erows, imp_total, fq, fl, lrows, longm)


def print_targets(krows, erows, imp_total, fq, fl, lrows, longm) -> None:
    """The targets of the speed issue, each with the measured value and whether it is met."""
    import os

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
    qs = e["Quickstart: identify sample_data (24 conditions), every figure"]
    qs_np = e["Quickstart: identify sample_data (24 conditions), --no-plots"]
    one_fig = e["identify pi, PSO 200 × 300, --no-polish, 1 condition, with figures"]
    one_np = e["identify pi, PSO 200 × 300, --no-polish, 1 condition, --no-plots"]
    diag = e["diagnose sample_data --model pi"]
    hl, pl = lrows["hystfit"], lrows["pandas.read_csv"]

    # the straightforward one-condition command: the same PSO evaluations at the straightforward
    # rate (measured above at N samples, scaled to the capture's 5,001), and — generously — hystfit's
    # own loading, reporting and figures; running it would take ≈ 25 minutes
    sf_fit = one_fig["evaluations"] * (k["pi"]["straightforward"] / P) * (5001 / N)
    e2e_ratio = (sf_fit + one_fig["wall_s"] - one_fig["fit_s"]) / one_fig["wall_s"]

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
        ("Quickstart identify (24 conditions, every figure) ≤ 3 s",
         f"{qs['wall_s']:.2f} s ({qs_np['wall_s']:.2f} s with --no-plots)", ok(qs["wall_s"] <= 3.0)),
        ("figures cost at most load + fit", f"figures {qs['wall_s'] - qs_np['wall_s']:.2f} s, load + fit "
         f"{qs_np['wall_s']:.2f} s; {fq['straightforward_s'] / fq['hystfit_s']:.1f}× the straightforward figures",
         ok(qs["wall_s"] - qs_np["wall_s"] <= qs_np["wall_s"])),
        ("loop figure of a long periodic capture spans the data (no aliasing)",
         ", ".join(f"{r['samples']:.0e}: {r['hystfit_span']:.2f} (stride {r['straightforward_span']:.2f})" for r in fl),
         ok(all(abs(r["hystfit_span"] - 1) < 1e-9 for r in fl))),
        ("one condition, PSO 200 × 300, with figures ≤ 1.0 s",
         f"{one_fig['wall_s']:.2f} s ({one_np['wall_s']:.2f} s without; imports {imp_total:.2f} s)",
         ok(one_fig["wall_s"] <= 1.0)),
        ("one condition end to end ≥ 800× the straightforward implementation",
         f"{e2e_ratio:,.0f}× (straightforward: {one_fig['evaluations']:,} evaluations at its measured "
         f"{P / k['pi']['straightforward']:,.0f} evaluations/s = {sf_fit:,.0f} s, plus hystfit's own "
         f"{one_fig['wall_s'] - one_fig['fit_s']:.2f} s outside the fit)", ok(e2e_ratio >= 800)),
        ("compare sample_data, all models, auto, with figures ≤ 20 s", f"{cmp_fig['wall_s']:.1f} s",
         ok(cmp_fig["wall_s"] <= 20)),
        ("diagnose sample_data --model pi ≤ 3 s", f"{diag['wall_s']:.2f} s", ok(diag["wall_s"] <= 3.0)),
        ("10⁷-row CSV loads in ≤ 15 s with ≤ 2 GB peak",
         f"{hl['wall_s']:.1f} s, {hl['peak_MB']:.0f} MB (pandas.read_csv alone {pl['wall_s']:.1f} s, {pl['peak_MB']:.0f} MB)",
         ok(hl["wall_s"] <= 15 and hl["peak_MB"] <= 2000)),
        ("fp and gpi on a 10⁶-sample capture ≤ 60 s each",
         ", ".join(f"{m} {v:.0f} s" if v is not None else f"{m} failed" for m, v in longm.items())
         or "not measured (run with --long)",
         ok(bool(longm) and all(v is not None and v <= 60 for v in longm.values())) if longm else "–"),
    ]
    print(f"\nLoad average at the end: {os.getloadavg()[0]:.1f}")
    print("\n### Targets\n")
    print("| target | measured | met |\n|---|---|---|")
    for t in targets:
        print(f"| {t[0]} | {t[1]} | {t[2]} |")


if __name__ == "__main__":
    main()
