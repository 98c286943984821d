"""Peak memory and wall time of `hystfit identify` on a 10⁶-sample capture, per model.

Run:  python benchmarks/memory.py [--models pi,bw,...] [--samples 1000000] [--timeout 1800]

Writes one capture of the virtual actuator (raised cosine 0→60 V at 10 Hz, 10 kHz, the sample
plant with all its default effects; ``hystfit synth capture``), then runs
``hystfit identify CAPTURE --model M --no-plots`` for each model in a fresh process and reports
its peak resident set size (VmHWM of that process image — not ``ru_maxrss``, which Linux carries
over exec from the forking parent — what ``/usr/bin/time -v`` calls the maximum resident set size,
including ≈ 0.45 GB for Python, numpy, scipy, pandas, pyarrow and numba
themselves), its wall time, its CPU time (user + system of all its threads: on a shared machine the
wall time grows with the load, the CPU time much less) and the RMSE of the fit. The target is < 1 GB peak.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = ("import json, resource, sys\n"
         "from hystfit.cli import main\n"
         "try:\n    main(sys.argv[1:])\nexcept SystemExit as exc:\n    assert exc.code in (0, None), exc.code\n"
         "ru = resource.getrusage(resource.RUSAGE_SELF)\n"
         "hwm = [ln.split()[1] for ln in open('/proc/self/status') if ln.startswith('VmHWM:')][0]\n"
         "print('PEAK_KB', hwm, 'CPU_S', ru.ru_utime + ru.ru_stime, file=sys.stderr)\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default="pi,bw,pi2,hammerstein,ch,nt,dahl,lugre,fp,gpi")
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per model")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cap = Path(tmp) / "big.parquet"
        cycles = (args.samples - 1) / 1000  # 10 Hz at 10 kHz: 1000 samples per cycle
        subprocess.run([sys.executable, "-c", "from hystfit.cli import main; main()", "synth", "capture", str(cap), "-a", "60", "-f", "10",
                        "--cycles", f"{cycles:g}", "--fs", "10000", "--force"], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        print(f"capture: {args.samples:,} samples (raised cosine 0→60 V, 10 Hz, 10 kHz, default plant)\n")
        print("| model | wall time (s) | CPU time (s) | peak RSS (MB) | < 1 GB | RMSE (µm) |\n|---|---:|---:|---:|---|---:|")
        for model in [m.strip() for m in args.models.split(",") if m.strip()]:
            out = Path(tmp) / f"out-{model}"
            cmd = [sys.executable, "-c", CHILD, "identify", str(cap), "--model", model, "--no-plots", "--quiet",
                   "--json", "--out", str(out), "--force"]
            t0 = time.perf_counter()
            try:
                r = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
            except subprocess.TimeoutExpired:
                print(f"| {model} | > {args.timeout:.0f} | – | – | – | – |", flush=True)
                continue
            wall = time.perf_counter() - t0
            if r.returncode != 0 or "PEAK_KB" not in r.stderr:
                lines = r.stderr.strip().splitlines() or ["?"]
                said = [ln for ln in lines if ln.startswith("hystfit: error:")]  # the CLI's one-line error
                why = (said[0].removeprefix("hystfit: error:").strip() if said else lines[-1])[:160]
                print(f"| {model} | {wall:.1f} | – | – | – | refused: {why} |", flush=True)
                continue
            peak = int(r.stderr.split("PEAK_KB")[1].split()[0]) / 1e3
            cpu = float(r.stderr.split("CPU_S")[1].split()[0])
            rmse = json.loads(r.stdout)["conditions"][0]["metrics"]["rmse_um"]
            print(f"| {model} | {wall:.1f} | {cpu:.1f} | {peak:.0f} | {'yes' if peak < 1000 else '**no**'} | {rmse:.4f} |",
                  flush=True)


if __name__ == "__main__":
    main()
