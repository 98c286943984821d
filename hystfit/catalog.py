"""Descriptions of the registered models and optimizers (for ``hystfit models``/``optimizers`` and docs)."""

from __future__ import annotations

import dataclasses

from .params import DataScale, with_output_unit
from .references import cite
from .registry import blocks, models, optimizers

#: the reference data scale used to show default bounds: 0–100 V → 0–30 µm at 10 kHz
REFERENCE_SCALE = DataScale(u_min=0.0, u_max=100.0, y_min=0.0, y_max=30.0, dt=1e-4, rate_max=1e5, duration_s=1.0)


def model_catalog() -> list[dict]:
    out = []
    for name in models.names():
        cls = models.get(name)
        m = cls().adapt(REFERENCE_SCALE)
        params = [{"name": p.name, "unit": with_output_unit(p.unit, "um"), "lower": p.lower, "upper": p.upper,
                   "default": p.default, "description": p.description} for p in m.params(REFERENCE_SCALE)]
        structure = {f.name: f.default for f in dataclasses.fields(cls)}
        out.append({"name": name, "title": cls.title, "reference": cite(cls.reference), "equation": cls.equation,
                    "rate_dependent": cls.rate_dependent, "has_inverse": _has_inverse(cls), "structure": structure, "parameters": params,
                    "doc": cite((cls.__doc__ or "").strip().splitlines()[0])})
    return out


def block_catalog() -> list[dict]:
    """Every registered block: parameters (units, default bounds on the reference scale), structure
    options, equation, and how a composite uses it."""
    out = []
    for name in blocks.names():
        cls = blocks.get(name)
        b = cls().adapt(REFERENCE_SCALE)
        params = [{"name": f"{name}.{p.name}", "unit": with_output_unit(p.unit, "um"), "lower": p.lower, "upper": p.upper,
                   "default": p.default, "description": p.description} for p in b.params(REFERENCE_SCALE)]
        structure = {f.name: f.default for f in dataclasses.fields(cls)}
        out.append({"name": name, "title": cls.title, "reference": cite(cls.reference), "equation": cls.equation,
                    "nuisance": cls.nuisance, "structure": structure, "parameters": params,
                    "doc": (cls.__doc__ or "").strip().splitlines()[0]})
    return out


def _has_inverse(cls) -> bool:
    from .models.base import Model

    return cls.invert is not Model.invert


def optimizer_catalog() -> list[dict]:
    out = []
    for name in optimizers.names():
        cls = optimizers.get(name)
        settings = dict(cls.setting_docs())
        out.append({"name": name, "title": cls.title, "reference": cite(cls.reference), "settings": settings,
                    "doc": cite((cls.__doc__ or "").strip().splitlines()[0])})
    return out
