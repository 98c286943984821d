"""Figures: hystfit's per-pixel reduction and parallel rendering against the straightforward way.

Run:  python benchmarks/bench_figures.py [--kinds [--instructions] | --compare | --cpu [--other TREE] [--repeat N]
                                         | --texts [--other TREE]]

1. The Quickstart's figures (``identify sample_data``: 24 conditions, a loop, time series and
   convergence figure each, and the overview), drawn by hystfit (``render_figures``: a process per
   core, fixed layouts, per-pixel reduction, no figure for a one-point convergence history) and
   the straightforward way (``straightforward.sf_*``: one after another, constrained layout, every
   k-th sample, every convergence figure). Same fits, same process, so only the drawing differs.
2. The CPU seconds of each figure kind of the Quickstart, drawn one after another in one process
   (``--kinds``: after the server's warm-up, as a worker draws them; the least noisy number on a
   shared machine). ``--compare``: the same for the figures of ``compare sample_data --models all
   --opts auto`` (fitted first, ≈ 20 s). ``--kinds --instructions``: the user-space instructions
   per figure of each kind instead (``perf stat`` where the machine has it): a fresh process draws
   every figure of the kind after the warm-up once and, in another run, four times; the
   difference over three passes, per figure. It repeats to about ±1 %, where CPU seconds move by
   ±20 % on a shared machine: use it to tell whether a change does less work.
3. ``--cpu [--other TREE] [--repeat N]``: the CPU seconds of the Quickstart's figures drawn in one
   fresh process after the figure server's import and warm-up, twice (the first pass as the
   command's figure workers draw, with layouts and texts made; the second with them kept), medians
   over ``--repeat`` processes; with ``--other``, that tree's too, alternately (both draw the same
   jobs, made here). Where ``perf stat`` cannot count instructions (as on this project's current
   machine), this is the rerunnable measure of a change to the drawing.
4. ``--texts [--other TREE]``: what a text the process has not drawn yet costs, in ms per text
   (180 titles such as ``pi – 40V_50Hz (a40V_f50Hz.csv)``, 12 pt, 110 dpi, best of 3): matplotlib's
   own ``RendererAgg.draw_text`` on a canvas just large enough, and the canvas's whole
   rasterisation of a new text (``canvas._rasterise``: scratch canvas, glyphs, ink search), in a
   fresh process per tree.
5. One loop figure of a long periodic capture (10⁶ and 10⁷ samples, 20,000 cycles): time, points
   drawn, and the voltage span of what is drawn against the data's span (stride: aliasing).
"""

from __future__ import annotations

import sys
import tempfile
import time
import types
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
ROOT = Path(__file__).resolve().parents[1]


def _quickstart_fit():
    from hystfit.identify import identify
    from hystfit.io import LoadOptions, load_captures
    from hystfit.registry import models, optimizers

    caps = load_captures([ROOT / "sample_data"], LoadOptions())
    return identify(caps, models.get("pi")(), optimizers.get("auto")(), seed=0, jobs=1)


def quickstart_figures() -> dict:
    """Wall time of the Quickstart's figures, hystfit against straightforward (same fits)."""
    import straightforward as sf

    from hystfit.report.identify_report import ConditionFigures
    from hystfit.report.render import _import_plotting

    res = _quickstart_fit()
    _import_plotting()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        (d / "h").mkdir()
        t0 = time.perf_counter()
        files = ConditionFigures(d / "h", res.optimizer_name).result(res)
        t_h = time.perf_counter() - t0
        n_h = len(list((d / "h" / "plots").glob("*.png")))
        (d / "s").mkdir()
        t0 = time.perf_counter()
        panels = []
        for f in res.fits:
            us, ys, yps = [c.u for c in f.captures], [c.y for c in f.captures], list(f.predictions)
            sf.sf_loop(d / "s" / f"loop_{f.label}.png", us, ys, yps, f.label)
            sf.sf_timeseries(d / "s" / f"ts_{f.label}.png", f.captures[0].t, f.captures[0].y, f.predictions[0], f.label)
            sf.sf_convergence(d / "s" / f"conv_{f.label}.png", f.best.result.history_best,
                              f.best.result.history_mean, f.label)
            panels.append({"title": f.label, "u": us, "y_meas": ys, "y_model": yps})
        sf.sf_overview(d / "s" / "overview.png", panels, "overview")
        t_s = time.perf_counter() - t0
        n_s = len(list((d / "s").glob("*.png")))
    del files
    return {"hystfit_s": t_h, "hystfit_figures": n_h, "straightforward_s": t_s, "straightforward_figures": n_s}


def figure_kinds(fit=None) -> dict[str, tuple[int, float]]:
    """CPU seconds per figure kind of the Quickstart, drawn serially here after the figure server's
    warm-up (``render._warm_up``), as one worker of the pool draws them: kind → (figures, seconds)."""
    from hystfit.report import render

    render._import_plotting()
    render._warm_up()
    with tempfile.TemporaryDirectory() as tmp:
        return _cpu_per_kind(_quickstart_jobs(Path(tmp), fit))


def _quickstart_jobs(out_dir: Path, fit=None) -> list:
    """The Quickstart's figure jobs (``fit``, or the Quickstart's fit made here), writing into
    ``out_dir/plots``, collected instead of drawn."""
    from hystfit.report import identify_report

    res = fit if fit is not None else _quickstart_fit()
    jobs: list = []
    figures = identify_report.ConditionFigures(out_dir, res.optimizer_name)
    figures._stream = types.SimpleNamespace(add=jobs.extend, result=lambda: None, cancel=lambda: None)  # collect
    figures.result(res)
    return jobs


def _cpu_per_kind(jobs) -> dict[str, tuple[int, float]]:
    """Draw ``jobs`` one after another here; kind → (figures, CPU seconds)."""
    from hystfit.report import render

    out: dict[str, tuple[int, float]] = {}
    for job in jobs:
        t0 = time.process_time()
        render._render(job)
        n, s = out.get(job.function, (0, 0.0))
        out[job.function] = (n + 1, s + time.process_time() - t0)
    return out


#: a fresh process that draws the jobs of one kind (pickled) ``passes`` times after the warm-up
_DRAW_KIND = """
import pickle, sys, tempfile
from dataclasses import replace
from pathlib import Path
from hystfit.report import render
render._import_plotting()
render._warm_up()
jobs = [j for j in pickle.load(open(sys.argv[1], "rb")) if j.function == sys.argv[2]]
with tempfile.TemporaryDirectory() as tmp:
    jobs = [replace(j, path=Path(tmp) / Path(j.path).name) for j in jobs]
    for j in jobs[:2]:  # the first drawings of the kind (layouts, texts), left out of the count
        render._render(j)
    for _ in range(int(sys.argv[3])):
        for j in jobs:
            render._render(j)
"""


def _instructions(args: list[str]) -> float | None:
    """User-space instructions of ``python -c _DRAW_KIND *args`` (None without ``perf stat``)."""
    import shutil
    import subprocess

    if shutil.which("perf") is None:
        return None
    r = subprocess.run(["perf", "stat", "-x,", "-e", "instructions:u", sys.executable, "-c", _DRAW_KIND, *args],
                       capture_output=True, text=True)
    for line in r.stderr.splitlines():
        value = line.split(",")[0]
        if line.split(",")[2:3] == ["instructions:u"] and value.isdigit():
            return float(value)
    return None


def figure_instructions(fit=None) -> dict[str, tuple[int, float]] | None:
    """Per figure kind of the Quickstart: (figures, user-space instructions per figure), from a
    fresh process drawing them 4 times against one drawing them once; None without ``perf stat``."""
    import pickle

    out: dict[str, tuple[int, float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        jobs = _quickstart_jobs(Path(tmp), fit)
        dump = Path(tmp) / "jobs.pickle"
        dump.write_bytes(pickle.dumps(jobs))
        for kind in dict.fromkeys(j.function for j in jobs):
            n = sum(j.function == kind for j in jobs)
            once, four = (_instructions([str(dump), kind, str(k)]) for k in (1, 4))
            if once is None or four is None:
                return None
            out[kind] = (n, (four - once) / (3 * n))
    return out


def compare_figure_kinds() -> dict[str, tuple[int, float]]:
    """CPU seconds per figure kind of ``compare sample_data --models all --opts auto`` (fitted first,
    ≈ 20 s), drawn serially here after the figure server's warm-up, as one worker draws them."""
    from hystfit.compare import compare
    from hystfit.io import LoadOptions, load_captures
    from hystfit.registry import models
    from hystfit.report import compare_report, render

    res = compare(load_captures([ROOT / "sample_data"], LoadOptions()), models.names(), ["auto"], seed=0)
    render._import_plotting()
    render._warm_up()
    jobs: list = []
    drawing = compare_report.render_figures
    compare_report.render_figures = lambda js, n_jobs=None: (jobs.extend(js), [j.path for j in js])[1]  # collect
    try:
        with tempfile.TemporaryDirectory() as tmp:
            compare_report._figures(res, Path(tmp))
            return _cpu_per_kind(jobs)
    finally:
        compare_report.render_figures = drawing


def long_loop(n: int, cycles: int = 20_000) -> dict:
    """One loop figure of an n-sample periodic capture: hystfit against every k-th sample."""
    import matplotlib.axes

    import straightforward as sf
    from hystfit.report import plots

    t = np.arange(n) / n
    u = 30.0 * (1 - np.cos(2 * np.pi * cycles * t))
    y = 0.1 * u + 0.8 * np.sin(2 * np.pi * cycles * t)
    yp = y + 0.01
    drawn: list[np.ndarray] = []
    original = matplotlib.axes.Axes.add_line  # every curve's route onto the axes (plot() takes it too)

    def spy(self, line):
        drawn.append(np.asarray(line.get_xdata(), float))
        return original(self, line)

    out = {"samples": n}
    with tempfile.TemporaryDirectory() as tmp:
        matplotlib.axes.Axes.add_line = spy
        try:
            for name, draw in (("hystfit", lambda p: plots.loop_figure(p, u, y, yp)),
                               ("straightforward", lambda p: sf.sf_loop(p, [u], [y], [yp]))):
                drawn.clear()
                t0 = time.perf_counter()
                draw(Path(tmp) / f"{name}.png")
                out[f"{name}_s"] = time.perf_counter() - t0
                out[f"{name}_points"] = int(drawn[0].size)
                out[f"{name}_span"] = float(np.nanmax(drawn[0]) - np.nanmin(drawn[0])) / float(np.ptp(u))
        finally:
            matplotlib.axes.Axes.add_line = original
    return out


#: draws the pickled jobs ``argv[1]`` twice after the server's import and warm-up; prints the
#: imported hystfit's file and each pass's CPU seconds
_DRAW_TWICE = r"""
import json, pickle, sys, tempfile, time
from dataclasses import replace
from pathlib import Path
import hystfit
from hystfit.report import render
jobs = pickle.load(open(sys.argv[1], "rb"))
render._import_plotting(lean=True)
render._warm_up()
passes = []
with tempfile.TemporaryDirectory() as tmp:
    jobs = [replace(j, path=Path(tmp) / Path(j.path).name) for j in jobs]
    for _ in range(2):
        t = time.process_time()
        for j in jobs:
            render._render(j)
        passes.append(time.process_time() - t)
print(json.dumps([hystfit.__file__, *passes]))
"""


def figure_cpu(other: str | None, repeat: int) -> dict[str, tuple[list[float], list[float]]]:
    """CPU seconds of the Quickstart's figures, first and second pass, per tree (see ``--cpu``)."""
    import json
    import os
    import pickle
    import subprocess

    trees = [str(ROOT)] + ([str(Path(other).resolve())] if other else [])
    out = {t: ([], []) for t in trees}
    with tempfile.TemporaryDirectory() as tmp:
        jobs = _quickstart_jobs(Path(tmp))
        dump = Path(tmp) / "jobs.pickle"
        dump.write_bytes(pickle.dumps(jobs))
        for i in range(repeat):
            for tree in (trees if i % 2 == 0 else trees[::-1]):
                env = {**os.environ, "PYTHONPATH": tree, "OPENBLAS_NUM_THREADS": "1"}
                r = subprocess.run([sys.executable, "-c", _DRAW_TWICE, str(dump)], env=env, cwd=tmp,
                                   capture_output=True, text=True, check=True)
                imported, first, second = json.loads(r.stdout.strip().splitlines()[-1])
                if not imported.startswith(tree):
                    raise RuntimeError(f"{tree}: imported {imported} instead")
                out[tree][0].append(first)
                out[tree][1].append(second)
    return out


#: times a new text's rasterisation (see ``--texts``); prints the imported hystfit and the ms per text
_TEXTS = r"""
import json, time
import hystfit
from hystfit.report import canvas, render
render._import_plotting(lean=True)
from matplotlib.backends.backend_agg import RendererAgg
from matplotlib.font_manager import FontProperties
prop = FontProperties(size=12)
titles = [f"pi – {a}V_{f}Hz (a{a}V_f{f}Hz.csv)" for a in range(10, 100) for f in (10, 20)]
page = RendererAgg(800, 600, 110)
gc = page.new_gc()
def per_text(draw):
    best = 9.0
    for _ in range(3):
        t = time.perf_counter()
        for s in titles:
            draw(s)
        best = min(best, (time.perf_counter() - t) / len(titles))
    return 1e3 * best
def matplotlib_draw(s):
    scratch = RendererAgg(700, 40, 110)
    RendererAgg.draw_text(scratch, scratch.new_gc(), 10, 30, s, prop, 0, False, None)
print(json.dumps([hystfit.__file__, per_text(matplotlib_draw), per_text(lambda s: canvas._rasterise(page, gc, s, prop, 0, None))]))
"""


def text_costs(other: str | None) -> dict[str, tuple[float, float]]:
    """ms per new text: matplotlib's draw_text and the canvas's rasterisation, per tree (``--texts``)."""
    import json
    import os
    import subprocess

    out = {}
    for tree in [str(ROOT)] + ([str(Path(other).resolve())] if other else []):
        env = {**os.environ, "PYTHONPATH": tree, "OPENBLAS_NUM_THREADS": "1"}
        with tempfile.TemporaryDirectory() as tmp:
            r = subprocess.run([sys.executable, "-c", _TEXTS], env=env, cwd=tmp, capture_output=True, text=True, check=True)
        imported, agg, ours = json.loads(r.stdout.strip().splitlines()[-1])
        if not imported.startswith(tree):
            raise RuntimeError(f"{tree}: imported {imported} instead")
        out[tree] = (agg, ours)
    return out


def main() -> None:
    if "--texts" in sys.argv[1:]:
        other = sys.argv[sys.argv.index("--other") + 1] if "--other" in sys.argv[1:] else None
        print("| tree | matplotlib's draw_text (ms per text) | the canvas's rasterisation of a new text (ms) |")
        print("|---|---:|---:|")
        for tree, (agg, ours) in text_costs(other).items():
            print(f"| {tree} | {agg:.2f} | {ours:.2f} |")
        return
    if "--cpu" in sys.argv[1:]:
        import argparse
        import statistics

        ap = argparse.ArgumentParser()
        ap.add_argument("--cpu", action="store_true")
        ap.add_argument("--other")
        ap.add_argument("--repeat", type=int, default=5)
        a = ap.parse_args()
        got = figure_cpu(a.other, a.repeat)
        print(f"Quickstart figures drawn in one process, CPU seconds, median of {a.repeat} (every run)\n")
        print("| tree | first pass (s) | second pass (s) |\n|---|---:|---:|")
        for tree, (first, second) in got.items():
            print(f"| {tree} | {statistics.median(first):.3f} ({', '.join(f'{v:.2f}' for v in first)}) | "
                  f"{statistics.median(second):.3f} ({', '.join(f'{v:.2f}' for v in second)}) |")
        return
    if "--kinds" in sys.argv[1:] and "--instructions" in sys.argv[1:]:
        counts = figure_instructions()
        if counts is None:
            print("perf stat cannot count instructions here (install linux-perf, or see perf_event_paranoid)")
            return
        print("| figure kind | figures | instructions per figure (M) |\n|---|---:|---:|")
        for name, (n, per) in counts.items():
            print(f"| {name} | {n} | {per / 1e6:.1f} |")
        return
    if "--kinds" in sys.argv[1:] or "--compare" in sys.argv[1:]:
        kinds = compare_figure_kinds() if "--compare" in sys.argv[1:] else figure_kinds()
        print("| figure kind | figures | CPU s | ms per figure |\n|---|---:|---:|---:|")
        for name, (n, s) in kinds.items():
            print(f"| {name} | {n} | {s:.2f} | {1e3 * s / n:.0f} |")
        print(f"| all | {sum(n for n, _ in kinds.values())} | {sum(s for _, s in kinds.values()):.2f} | |")
        return
    q = quickstart_figures()
    print("| figures | hystfit (s) | straightforward (s) | ratio |\n|---|---:|---:|---:|")
    print(f"| Quickstart identify, {q['hystfit_figures']} figures (straightforward: {q['straightforward_figures']}) | "
          f"{q['hystfit_s']:.2f} | {q['straightforward_s']:.2f} | {q['straightforward_s'] / q['hystfit_s']:.1f}× |")
    for n in (10**6, 10**7):
        r = long_loop(n)
        print(f"| loop figure, {n:.0e} samples: time / points / drawn voltage span ÷ data span | "
              f"{r['hystfit_s']:.2f} / {r['hystfit_points']:,} / {r['hystfit_span']:.3f} | "
              f"{r['straightforward_s']:.2f} / {r['straightforward_points']:,} / {r['straightforward_span']:.3f} | "
              f"{r['straightforward_s'] / r['hystfit_s']:.1f}× |")


if __name__ == "__main__":
    main()
