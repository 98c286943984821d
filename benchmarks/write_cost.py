"""What writing one output file costs: :func:`hystfit.io.atomic_write_bytes` with and without its
``fsync``, and a plain ``Path.write_bytes``, per file, in wall and CPU milliseconds.

Run:  python benchmarks/write_cost.py [--dir DIR] [--files 49] [--kb 60] [--repeat 5]

Writes ``--files`` files of ``--kb`` kB (the size of a Quickstart figure; 49 is the Quickstart's
count) into a fresh directory under ``--dir`` (default: the system's temporary directory; pass the
file system your outputs go to), each way in turn, ``--repeat`` rounds, and prints the median per
file. The ``fsync`` waits for the disk: its cost is wall time, not CPU, and it depends on the
file system and the disk, not on the machine's load.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from hystfit.io import atomic_write_bytes


def _round(d: Path, data: bytes, n: int, how: str) -> tuple[float, float]:
    write = {"atomic, fsync": lambda p: atomic_write_bytes(p, data),
             "atomic, no fsync": lambda p: atomic_write_bytes(p, data, sync=False),
             "plain": lambda p: p.write_bytes(data)}[how]
    w, c = time.perf_counter(), time.process_time()
    for i in range(n):
        write(d / f"{i}.png")
    return (time.perf_counter() - w) / n * 1e3, (time.process_time() - c) / n * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dir", default=None)
    ap.add_argument("--files", type=int, default=49)
    ap.add_argument("--kb", type=float, default=60.0)
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    data = os.urandom(int(a.kb * 1024))
    ways = ("atomic, fsync", "atomic, no fsync", "plain")
    got: dict[str, list[tuple[float, float]]] = {w: [] for w in ways}
    with tempfile.TemporaryDirectory(dir=a.dir) as tmp:
        for r in range(a.repeat):
            for how in ways[r % 3:] + ways[:r % 3]:  # the order turns from round to round
                d = Path(tmp) / f"{r}-{ways.index(how)}"
                d.mkdir()
                got[how].append(_round(d, data, a.files, how))
        print(f"{a.files} files of {a.kb:g} kB in {tmp}, {a.repeat} rounds, median per file\n")
        print("| write | wall (ms) | CPU (ms) | wall of all the files (s) |\n|---|---:|---:|---:|")
        for how in ways:
            wall = statistics.median(x for x, _ in got[how])
            cpu = statistics.median(y for _, y in got[how])
            print(f"| {how} | {wall:.2f} | {cpu:.2f} | {wall * a.files / 1e3:.3f} |")


if __name__ == "__main__":
    main()
