"""Children stopped right after they are forked: do they stop, and does anything get printed?

Run:  python benchmarks/fork_stop.py [--children 300] [--servers 30]

With a SIGTERM handler that raises (as the console script's), this process
1. starts ``--children`` times a ``parallel.fork_call`` child that would sleep 2 s and cancels it at
   once: how many of them ran on (the cancel waited more than 0.5 s for them);
2. starts ``--servers`` times the figure server and closes it at once: the median and longest
   wait, and how many waits exceeded 0.3 s (a server that went on importing matplotlib);
and counts the lines "Exception ignored" that the children printed on stderr (a parent's handler
run in a child during the interpreter's after-fork hooks). Run it from outside the checkout with
``PYTHONPATH=<tree>`` to measure another version (inside the checkout its own package is imported).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys

CHILD = r"""
import signal, statistics, sys, time
from hystfit import parallel
from hystfit.report import render

class Stop(BaseException):
    pass

def raising(signum, frame):
    raise Stop

signal.signal(signal.SIGTERM, raising)
n_children, n_servers = int(sys.argv[1]), int(sys.argv[2])
ran_on = 0
for _ in range(n_children):
    call = parallel.fork_call(lambda: time.sleep(2.0), workers=2, kernels=False)
    t0 = time.monotonic()
    call.cancel()
    ran_on += time.monotonic() - t0 > 0.5
waits = []
for _ in range(n_servers):
    server = render._FigureServer()
    t0 = time.monotonic()
    server.close(stop=True)
    waits.append(time.monotonic() - t0)
print(ran_on, statistics.median(waits) if waits else 0.0, max(waits, default=0.0), sum(w > 0.3 for w in waits))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--children", type=int, default=300)
    ap.add_argument("--servers", type=int, default=30)
    args = ap.parse_args()
    r = subprocess.run([sys.executable, "-c", CHILD, str(args.children), str(args.servers)], capture_output=True,
                       text=True, check=True, env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
    ran_on, median, longest, slow = r.stdout.split()
    printed = r.stderr.count("Exception ignored")
    print(f"| children cancelled at once that ran on | {ran_on} of {args.children} |")
    print(f"| figure servers closed at once: median / longest wait, waits over 0.3 s | "
          f"{float(median) * 1e3:.0f} / {float(longest) * 1e3:.0f} ms, {slow} of {args.servers} |")
    print(f"| 'Exception ignored' printed by the children | {printed} |")


if __name__ == "__main__":
    main()
