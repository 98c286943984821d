"""The ``params.json`` schema: one frozen type written and read back.

:class:`ParamsFile` (with its :class:`Cell` per condition and :class:`ParamRecord` per parameter) is the
persistent form of an identification: ``identify`` builds it with :meth:`ParamsFile.from_result` and
writes :meth:`ParamsFile.to_dict`; ``simulate``, ``invert`` and ``track`` read it back with
:func:`load_params` → :meth:`ParamsFile.from_dict`, and ``from_dict(to_dict())`` is exact (tested).

Schema ``hystfit.params`` version 2 (version 1, before composite models, is still read)::

    {"schema": "hystfit.params", "schema_version": 2,
     "tool": {"name": "hystfit", "version": "..."},
     "model": {"name", "title", "reference", "equation", "base", "blocks", "options"},
     "optimizer": {"name", "settings", "polish", "runs", "start"},   # start: "defaults", "given" or what
                                                                      # it was (diagnose: its own fit)
     "seed": int, "mode": "per-condition" | "global",
     "units": {"input": "V", "output": "um", "time": "s"},
     "bounds_overrides": {name: [lo, hi]},
     "conditions": [{"label", "amplitude_V", "frequency_Hz", "sources", "model_structure",
                     "data_scale", "parameters": [{"name", "unit", "value", "stderr", "lower", "upper",
                     "at_bound", "determined", "description"}], "metrics": {...}, "per_capture": [...], "runtime_s",
                     "evaluations", "best_run",
                     "runs": [{"run", "seed", "fun", "rmse_<unit>", "nfev", "iterations", "wall_time_s",
                               "stop", "polished"}],
                     "run_spread": {...}, "blocks": {...} (composite models only)}]}

The other JSON outputs name their schema and version here too (:data:`SCHEMAS`, :func:`schema_header`).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from .errors import ConfigError, HystfitError, InputError
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
#: every JSON document hystfit writes: kind → (schema name, version)
SCHEMAS = {
    "params": (SCHEMA, SCHEMA_VERSION),
    "diagnosis": ("hystfit.diagnosis", 1),
    "invert": ("hystfit.invert", 1),
    "track": ("hystfit.track", 1),
}


def schema_fields(kind: str) -> dict[str, Any]:
    """``{"schema", "schema_version"}`` of a JSON output of kind ``kind`` (see :data:`SCHEMAS`)."""
    name, version = SCHEMAS[kind]
    return {"schema": name, "schema_version": version}


def schema_header(kind: str) -> dict[str, Any]:
    """``{"schema", "schema_version", "tool"}`` of a JSON output of kind ``kind`` (see :data:`SCHEMAS`)."""
    name, version = SCHEMAS[kind]
    return {"schema": name, "schema_version": version, "tool": {"name": "hystfit", "version": __version__}}


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


@dataclass(frozen=True)
class ParamRecord:
    """One identified parameter as written to ``params.json`` (units in ``unit``)."""

    name: str
    unit: str
    value: float
    stderr: float | None
    lower: float
    upper: float
    at_bound: str | None
    description: str = ""
    #: False when the data do not determine the parameter (its standard error is infinite, written
    #: null: :func:`hystfit.identify._stderr`); True otherwise, at a bound too
    determined: bool = True

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "unit": self.unit, "value": self.value, "stderr": self.stderr,
                "lower": self.lower, "upper": self.upper, "at_bound": self.at_bound, "determined": self.determined,
                "description": self.description}

    @classmethod
    def from_dict(cls, d: dict) -> "ParamRecord":
        se = d.get("stderr")
        return cls(str(d["name"]), str(d.get("unit", "")), float(d["value"]), None if se is None else float(se),
                   float(d["lower"]), float(d["upper"]), d.get("at_bound"), str(d.get("description", "")),
                   bool(d.get("determined", True)))


@dataclass(frozen=True)
class Cell:
    """One look-up-table cell of ``params.json``: the fitted model of one condition (or of the global fit)
    and everything reported about it. Written by :meth:`from_fit` + :meth:`to_dict`, read back by
    :meth:`from_dict` — the same type both ways."""

    label: str
    amplitude_V: float
    frequency_Hz: float
    model: Model
    theta: np.ndarray
    scale: DataScale
    parameters: tuple[ParamRecord, ...] = ()
    sources: tuple[str, ...] = ()
    metrics: dict = field(default_factory=dict)
    per_capture: tuple[dict, ...] = ()
    runtime_s: float | None = None
    evaluations: int | None = None
    best_run: int | None = None
    runs: tuple[dict, ...] = ()
    run_spread: dict = field(default_factory=dict)
    blocks: dict | None = None

    def predict(self, u: np.ndarray, dt: float) -> np.ndarray:
        return self.model.simulate_one(self.theta, u, dt)

    @classmethod
    def from_fit(cls, fit: ConditionFit) -> "Cell":
        u = fit.unit
        params = tuple(ParamRecord(p.name, unit_param(p, u), float(v), float(se), p.lower, p.upper, at, p.description,
                                   determined=not (se == math.inf))
                       for p, v, se, at in zip(fit.params, fit.theta, fit.stderr, fit.at_bound))
        runs = tuple({"run": r.run, "seed": r.seed, "fun": r.fun, f"rmse_{u}": r.rmse, "nfev": r.nfev,
                      "iterations": r.result.nit, "wall_time_s": r.wall_time_s, "stop": r.result.message,
                      "polished": r.polish is not None} for r in fit.runs)
        blocks = fit.model.describe_blocks(fit.theta, u) if fit.model.composition is not None else None
        return cls(fit.label, fit.amplitude_V, fit.frequency_Hz, fit.model, np.asarray(fit.theta, dtype=np.float64),
                   fit.scale, params, tuple(c.source for c in fit.captures), dict(fit.metrics),
                   tuple(fit.per_capture), fit.runtime_s, fit.evaluations, fit.best_run, runs, fit.spread(), blocks)

    def to_dict(self) -> dict[str, Any]:
        out = {
            "label": self.label, "amplitude_V": self.amplitude_V, "frequency_Hz": self.frequency_Hz,
            "sources": list(self.sources),
            "model_structure": self.model.structure(),
            "data_scale": asdict(self.scale),
            "parameters": [p.to_dict() for p in self.parameters],
            "metrics": self.metrics,
            "per_capture": list(self.per_capture),
            "runtime_s": self.runtime_s, "evaluations": self.evaluations,
            "best_run": self.best_run, "runs": list(self.runs), "run_spread": self.run_spread,
        }
        if self.blocks is not None:
            out["blocks"] = self.blocks
        return out

    @classmethod
    def from_dict(cls, expr: str, c: dict, i: int = 0) -> "Cell":
        """Cell ``i`` of a parameter file, checked to be usable: parameters of the model's count, finite,
        and a trial simulation that runs (so a damaged file fails here, naming the field, not later)."""
        where = f"conditions[{i}]"
        model = model_from_structure(expr, c["model_structure"])
        records = tuple(ParamRecord.from_dict(q) for q in c["parameters"])
        theta = np.array([q.value for q in records], dtype=np.float64)
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
        cell = cls(label, float("nan") if a is None else float(a), float("nan") if f is None else float(f), model,
                   theta, scale, records, tuple(c.get("sources", ())), dict(c.get("metrics", {})),
                   tuple(c.get("per_capture", ())), c.get("runtime_s"), c.get("evaluations"), c.get("best_run"),
                   tuple(c.get("runs", ())), dict(c.get("run_spread", {})), c.get("blocks"))
        u = np.linspace(scale.u_min, scale.u_max, 8)
        with np.errstate(all="ignore"):
            cell.predict(u, scale.dt)  # raises on a structure/parameter mismatch the checks above missed
        return cell


@dataclass(frozen=True)
class ParamsFile:
    """The content of ``params.json`` (schema :data:`SCHEMA`, version :data:`SCHEMA_VERSION`): what
    ``identify`` writes (:meth:`from_result` → :meth:`to_dict`) and what simulate / invert / track read
    back (:func:`load_params` → :meth:`from_dict`) — one type both ways."""

    path: str
    model_name: str
    unit: str
    mode: str
    cells: tuple[Cell, ...]
    model_options: dict = field(default_factory=dict)
    optimizer: dict = field(default_factory=dict)
    seed: int | None = None
    bounds_overrides: dict = field(default_factory=dict)
    tool_version: str = __version__

    @classmethod
    def from_result(cls, res: IdentifyResult, path: str = "") -> "ParamsFile":
        return cls(path, res.fits[0].model.name if res.fits else res.model_name, res.unit, res.mode,
                   tuple(Cell.from_fit(f) for f in res.fits), dict(res.model_options),
                   {"name": res.optimizer_name, "settings": res.optimizer_settings, "polish": res.polish,
                    "runs": res.runs, "start": res.start},
                   res.seed, {k: list(v) for k, v in res.bounds_overrides.items()})

    def to_dict(self) -> dict[str, Any]:
        m = self.cells[0].model if self.cells else make_model(self.model_name)
        base, blocks = m.composition if m.composition is not None else (m, ())
        return json_safe({
            **schema_header("params"),
            "tool": {"name": "hystfit", "version": self.tool_version},
            "model": {"name": m.name, "title": m.title, "reference": m.reference, "equation": m.equation,
                      "base": base.name, "blocks": [b.name for b in blocks],
                      "options": self.model_options},
            "optimizer": self.optimizer,
            "seed": self.seed, "mode": self.mode,
            "units": {"input": "V", "output": self.unit, "time": "s"},
            "bounds_overrides": self.bounds_overrides,
            "conditions": [c.to_dict() for c in self.cells],
        })

    def check_unit(self, unit: str, what: str, fix: str) -> None:
        """Refuse data in another output unit than the parameters (one-line :class:`ConfigError`).

        The parameters (weights in ``unit``/V, offsets in ``unit``) hold for the unit they were
        identified in: applied to data in another unit the model is off by the unit's factor while
        its outputs are labelled with the parameter file's unit. hystfit keeps every output in the
        unit its file names (captures are not converted on load) and refuses a mix, as ``identify``,
        ``compare`` and ``diagnose`` do for captures in several units; ``simulate``, ``invert`` and
        ``track`` check their capture, target or plant here. ``what`` names the data (``"nm.csv:
        the output"``), ``fix`` says what to do.
        """
        if unit != self.unit:
            raise ConfigError(f"{what} is in {unit} but {self.path} is in {self.unit}; {fix}")

    @classmethod
    def from_dict(cls, data: dict, path: str = "") -> "ParamsFile":
        """Validated read of a parameter-file dict; :class:`ValueError`/:class:`KeyError`/
        :class:`HystfitError` name the field that is wrong (:func:`load_params` adds the file name)."""
        if not isinstance(data, dict) or data.get("schema") != SCHEMA:
            raise ValueError(f"field 'schema' is not {SCHEMA!r}; this is not a hystfit parameter file")
        if data.get("schema_version") not in READABLE_VERSIONS:
            raise ValueError(f"field 'schema_version' is {data.get('schema_version')!r}; this hystfit reads versions "
                             f"{', '.join(map(str, READABLE_VERSIONS))}")
        expr = data["model"]["name"]
        if not isinstance(expr, str):
            raise ValueError(f"model.name must be text, got {expr!r}")
        make_model(expr)  # an unknown model or block is named before anything else
        unit = data["units"]["output"]
        if unit not in OUTPUT_UNITS:
            raise ValueError(f"units.output {unit!r} is not one of {', '.join(OUTPUT_UNITS)}")
        cells = tuple(Cell.from_dict(expr, c, i) for i, c in enumerate(data["conditions"]))
        return cls(path, expr, unit, data.get("mode", "per-condition"), cells,
                   dict(data["model"].get("options") or {}), dict(data.get("optimizer") or {}), data.get("seed"),
                   dict(data.get("bounds_overrides") or {}), str((data.get("tool") or {}).get("version", "")))


def identify_to_dict(res: IdentifyResult) -> dict[str, Any]:
    """The ``params.json`` content of an identification (:meth:`ParamsFile.from_result` → ``to_dict``)."""
    return ParamsFile.from_result(res).to_dict()


def dumps(data: dict) -> str:
    return json.dumps(data, indent=2, allow_nan=False) + "\n"


def load_params(path: str | Path) -> ParamsFile:
    """Read a ``params.json`` written by ``hystfit identify`` (validated; errors name the file and field)."""
    p = Path(path)
    try:
        data = json.loads(p.read_text())
    except FileNotFoundError:
        raise InputError(f"{p}: no such parameter file; pass the params.json written by 'hystfit identify' (or by "
                         "'hystfit diagnose', when it hands a model over)") from None
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
        pf = ParamsFile.from_dict(data, str(p))
    except HystfitError as exc:
        raise InputError(f"{p}: {exc}; regenerate it with 'hystfit identify'") from None
    except Exception as exc:  # noqa: BLE001 - an untrusted file: any malformation is the user's input error
        raise InputError(f"{p}: malformed parameter file ({exc.__class__.__name__}: {exc}); regenerate it with "
                         "'hystfit identify'") from None
    if not pf.cells:
        raise InputError(f"{p}: field 'conditions' is empty; regenerate it with 'hystfit identify'")
    return pf
