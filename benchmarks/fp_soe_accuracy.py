"""fp on a long capture: the fitted θ evaluated by the sum-of-exponentials route and by the exact one.

Run:  python benchmarks/fp_soe_accuracy.py OUT/params.json CAPTURE.parquet

``OUT`` is the output of ``hystfit identify CAPTURE --model fp`` on a capture long enough for the SOE
route (``hystfit.models.fp.SOE_MIN_SAMPLES``); prints the RMSE of that θ by both routes and the largest
difference of the two simulated outputs (the exact route is the FFT evaluation of the windowed
Grünwald–Letnikov recurrence, O(N log N) per candidate).
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from hystfit.io import load_capture
from hystfit.models import fp as fp_module


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("params")
    ap.add_argument("capture")
    args = ap.parse_args()
    cond = json.load(open(args.params))["conditions"][0]
    theta = np.array([[p["value"] for p in cond["parameters"]]])
    cap = load_capture(args.capture)
    u, y, dt = cap.u, cap.y, cap.dt
    model = fp_module.FractionalZener(**cond["model_structure"])
    assert model.soe_route(u.shape[0], dt), "capture too short for the SOE route"
    y_soe = model.simulate(theta, u, dt)[0]
    fp_module.SOE_MIN_SAMPLES = 10 ** 15  # the exact route for the same θ
    y_exact = model.simulate(theta, u, dt)[0]
    rmse = [float(np.sqrt(np.mean((v - y) ** 2))) for v in (y_soe, y_exact)]
    print(f"N = {u.shape[0]:,}: RMSE SOE {rmse[0]:.6f}, exact {rmse[1]:.6f} "
          f"(relative difference {abs(rmse[0] - rmse[1]) / rmse[1]:.1e}); max |ŷ_SOE − ŷ_exact| = "
          f"{np.abs(y_soe - y_exact).max():.2e}")


if __name__ == "__main__":
    main()
