"""The ``params.json`` schema: writing identification results and reading them back.

Schema ``hystfit.params`` version 1 (documented in the README)::

    {"schema": "hystfit.params", "schema_version": 1,
     "tool": {"name": "hystfit", "version": "..."},
     "model": {"name", "title", "reference", "equation", "options"},
     "optimizer": {"name", "settings", "polish", "runs"},
     "seed": int, "mode": "per-condition" | "global",
     "units": {"input": "V", "output": "um", "time": "s"},
     "bounds_overrides": {name: [lo, hi]},
     "conditions": [{"label", "amplitude_V", "frequency_Hz", "sources", "model_structure",
                     "data_scale", "parameters": [{"name", "unit", "value", "stderr", "lower", "upper", "at_bound"}],
                     "metrics": {...}, "per_capture": [...], "runtime_s", "evaluations",
                     "runs": [{"run", "seed", "fun", "rmse_<unit>", "nfev", "wall_time_s", "stop"}],
                     "run_spread": {...}}]}
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from .errors import HystfitError, InputError
from .io import OUTPUT_UNITS
from .identify import ConditionFit, IdentifyResult, unit_param
from .models.base import Model
from .models.composite import model_from_structure
from .params import DataScale
from .factory import make_model

SCHEMA = "hystfit.params"
SCHEMA_VERSION = 2
#: versions this hystfit reads (version 1: before composite models; read as version 2)
READABLE_VERSIONS = (1, 2)


def json_safe(x: Any) -> Any:
    """JSON-safe copy: numpy scalars to Python, NaN/inf to None, tuples and arrays to lists."""
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if math.isfinite(x) else None
    if isinstance(x, np.ndarray):
        return json_safe(x.tolist())
    return x


def unit_keys(d: Any, unit: str) -> Any:
    """Keys ending in ``_out`` (or holding ``_out_``) renamed to the output unit (``rmse_out`` →
    ``rmse_um``); ``sigma`` → ``sigma_<unit>``. The one renaming of the output-unit placeholder in
    result keys (:func:`hystfit.params.with_output_unit` for unit texts)."""
    if isinstance(d, dict):
        out = {}
        for k, v in d.items():
            key = k
            if isinstance(k, str):
                if k == "sigma":
                    key = f"sigma_{unit}"
                elif k.endswith("_out"):
                    key = k[:-4] + f"_{unit}"
                elif "_out_" in k:
                    key = k.replace("_out_", f"_{unit}_")
            out[key] = unit_keys(v, unit)
        return out
    if isinstance(d, (list, tuple)):
        return [unit_keys(v, unit) for v in d]
    return d


def condition_to_dict(fit: ConditionFit) -> dict[str, Any]:
    u = fit.unit
    params = []
    for p, v, se, at in zip(fit.params, fit.theta, fit.stderr, fit.at_bound):
        params.append({"name": p.name, "unit": unit_param(p, u), "value": float(v), "stderr": float(se),
                       "lower": p.lower, "upper": p.upper, "at_bound": at, "description": p.description})
    runs = [{"run": r.run, "seed": r.seed, "fun": r.fun, f"rmse_{u}": r.rmse, "nfev": r.nfev,
             "iterations": r.result.nit, "wall_time_s": r.wall_time_s, "stop": r.result.message,
             "polished": r.polish is not None} for r in fit.runs]
    out = {
        "label": fit.label, "amplitude_V": fit.amplitude_V, "frequency_Hz": fit.frequency_Hz,
        "sources": [c.source for c in fit.captures],
        "model_structure": fit.model.structure(),
        "data_scale": asdict(fit.scale),
        "parameters": params,
        "metrics": fit.metrics,
        "per_capture": list(fit.per_capture),
        "runtime_s": fit.runtime_s, "evaluations": fit.evaluations,
        "best_run": fit.best_run, "runs": runs, "run_spread": fit.spread(),
    }
    if fit.model.composition is not None:
        out["blocks"] = fit.model.describe_blocks(fit.theta, u)
    return out


def identify_to_dict(res: IdentifyResult) -> dict[str, Any]:
    m = res.fits[0].model if res.fits else make_model(res.model_name)
    base, blocks = m.composition if m.composition is not None else (m, ())
    return json_safe({
        "schema": SCHEMA, "schema_version": SCHEMA_VERSION,
        "tool": {"name": "hystfit", "version": __version__},
        "model": {"name": m.name, "title": m.title, "reference": m.reference, "equation": m.equation,
                  "base": base.name, "blocks": [b.name for b in blocks],
                  "options": res.model_options},
        "optimizer": {"name": res.optimizer_name, "settings": res.optimizer_settings, "polish": res.polish,
                      "runs": res.runs},
        "seed": res.seed, "mode": res.mode,
        "units": {"input": "V", "output": res.unit, "time": "s"},
        "bounds_overrides": {k: list(v) for k, v in res.bounds_overrides.items()},
        "conditions": [condition_to_dict(f) for f in res.fits],
    })


def dumps(data: dict) -> str:
    return json.dumps(data, indent=2, allow_nan=False) + "\n"


@dataclass(frozen=True)
class Cell:
    """One look-up-table cell read back from ``params.json``."""

    label: str
    amplitude_V: float
    frequency_Hz: float
    model: Model
    theta: np.ndarray
    scale: DataScale

    def predict(self, u: np.ndarray, dt: float) -> np.ndarray:
        return self.model.simulate_one(self.theta, u, dt)


@dataclass(frozen=True)
class ParamsFile:
    path: str
    model_name: str
    unit: str
    mode: str
    cells: tuple[Cell, ...]
    raw: dict


def _read_cell(expr: str, c: dict, i: int) -> Cell:
    """Cell ``i`` of a parameter file, checked to be usable: parameters of the model's count, finite,
    and a trial simulation that runs (so a damaged file fails here, naming the field, not later)."""
    where = f"conditions[{i}]"
    model = model_from_structure(expr, c["model_structure"])
    theta = np.array([float(q["value"]) for q in c["parameters"]], dtype=np.float64)
    scale = DataScale(**c["data_scale"])
    if not all(math.isfinite(float(getattr(scale, f))) for f in ("u_min", "u_max", "y_min", "y_max", "dt")) \
            or not scale.dt > 0:
        raise ValueError(f"{where}.data_scale must hold finite numbers and dt > 0")
    n = len(model.params(scale))
    if theta.shape != (n,):
        raise ValueError(f"{where}.parameters has {theta.size} values; model {model.name!r} with this structure has {n}")
    if not np.isfinite(theta).all():
        raise ValueError(f"{where}.parameters: value {theta[~np.isfinite(theta)][0]!r} is not a finite number")
    label = c["label"]
    if not isinstance(label, str):
        raise ValueError(f"{where}.label must be text, got {label!r}")
    a, f = c["amplitude_V"], c["frequency_Hz"]
    cell = Cell(label, float("nan") if a is None else float(a), float("nan") if f is None else float(f), model,
                theta, scale)
    u = np.linspace(scale.u_min, scale.u_max, 8)
    with np.errstate(all="ignore"):
        cell.predict(u, scale.dt)  # raises on a structure/parameter mismatch the checks above missed
    return cell


def load_params(path: str | Path) -> ParamsFile:
    """Read a ``params.json`` written by ``hystfit identify`` (validated; errors name the field)."""
    p = Path(path)
    try:
        data = json.loads(p.read_text())
    except FileNotFoundError:
        raise InputError(f"{p}: no such parameter file; pass the params.json written by 'hystfit identify'") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot read ({exc.__class__.__name__}); check the path and permissions") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{p}: line {exc.lineno}: not valid JSON ({exc.msg}); pass a params.json written by 'hystfit identify'") from None
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise InputError(f"{p}: field 'schema' is not {SCHEMA!r}; this is not a hystfit parameter file")
    if data.get("schema_version") not in READABLE_VERSIONS:
        raise InputError(f"{p}: field 'schema_version' is {data.get('schema_version')!r}; this hystfit reads versions "
                         f"{', '.join(map(str, READABLE_VERSIONS))}")
    try:
        expr = data["model"]["name"]
        if not isinstance(expr, str):
            raise ValueError(f"model.name must be text, got {expr!r}")
        make_model(expr)  # an unknown model or block is named before anything else
        unit = data["units"]["output"]
        if unit not in OUTPUT_UNITS:
            raise ValueError(f"units.output {unit!r} is not one of {', '.join(OUTPUT_UNITS)}")
        cells = [_read_cell(expr, c, i) for i, c in enumerate(data["conditions"])]
    except HystfitError as exc:
        raise InputError(f"{p}: {exc}; regenerate it with 'hystfit identify'") from None
    except Exception as exc:  # noqa: BLE001 - an untrusted file: any malformation is the user's input error
        raise InputError(f"{p}: malformed parameter file ({exc.__class__.__name__}: {exc}); regenerate it with "
                         "'hystfit identify'") from None
    if not cells:
        raise InputError(f"{p}: field 'conditions' is empty; regenerate it with 'hystfit identify'")
    return ParamsFile(str(p), data["model"]["name"], unit, data.get("mode", "per-condition"), tuple(cells), data)
