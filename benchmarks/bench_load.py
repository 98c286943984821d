"""Loading a 10⁷-row CSV capture: wall time and peak memory, hystfit against plain pandas.

Run:  python benchmarks/bench_load.py [--rows 10000000] [--general]

Writes a three-column CSV (time_s, voltage_V, displacement_um; 10 Hz raised cosine at 100 kHz,
≈ 270 MB) and loads it in a fresh process each way, reporting the wall time of the load and the
process's peak resident set size (``VmHWM``, including ≈ 0.2 GB of Python and libraries):

- ``hystfit.io.load_capture`` (pyarrow's parser straight to float64 for a plain numeric file),
- ``pandas.read_csv(path)`` (the straightforward reader: no validation, no condition detection),
- with ``--general``, hystfit's general reader (every cell as text first, as before the speed
  issue: ≈ 130 s and 4 GB on 10⁷ rows).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = {
    "hystfit": "import hystfit.io as h; c = h.load_capture(P); n = c.n",
    "hystfit general reader": "import hystfit.io as h; h.FAST_READ_BYTES = 1 << 62; c = h.load_capture(P); n = c.n",
    "pandas.read_csv": "import pandas as pd; d = pd.read_csv(P); n = len(d)",
}
# VmHWM (peak resident set of this process image), not ru_maxrss: Linux carries ru_maxrss over
# exec from the forking parent, which here holds the benchmark's own arrays
WRAP = ("import sys, time\nP = sys.argv[1]\nt0 = time.perf_counter()\n{body}\nwall = time.perf_counter() - t0\n"
        "hwm = [ln.split()[1] for ln in open('/proc/self/status') if ln.startswith('VmHWM:')][0]\n"
        "print(wall, hwm, n)\n")


def write_capture(path: Path, rows: int) -> None:
    import numpy as np
    import pyarrow as pa
    from pyarrow import csv as pcsv

    t = np.arange(rows) / 100_000.0
    u = 30.0 * (1 - np.cos(2 * np.pi * 10 * t))
    y = 0.1 * u + 0.8 * np.sin(2 * np.pi * 10 * t) + np.random.default_rng(0).normal(0, 0.01, rows)
    table = pa.table({"time_s": np.round(t, 6), "voltage_V": np.round(u, 6), "displacement_um": np.round(y, 6)})
    pcsv.write_csv(table, path)


def measure(rows: int = 10_000_000, general: bool = False) -> list[dict]:
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "capture.csv"
        write_capture(path, rows)
        for name, body in CHILD.items():
            if name == "hystfit general reader" and not general:
                continue
            r = subprocess.run([sys.executable, "-c", WRAP.format(body=body), str(path)], capture_output=True,
                               text=True, check=True)
            wall, peak_kb, n = r.stdout.split()
            out.append({"reader": name, "rows": int(n), "wall_s": float(wall), "peak_MB": int(peak_kb) / 1e3})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=10_000_000)
    ap.add_argument("--general", action="store_true", help="also the general reader (slow)")
    args = ap.parse_args()
    print("| reader | rows | load (s) | peak RSS (MB) |\n|---|---:|---:|---:|")
    for r in measure(args.rows, args.general):
        print(f"| {r['reader']} | {r['rows']:,} | {r['wall_s']:.1f} | {r['peak_MB']:.0f} |")


if __name__ == "__main__":
    main()
