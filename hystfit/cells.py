"""The store of finished cells that makes a run resumable.

Every finished cell is written, as it finishes, to ``OUT.partial/cells/<key>.pkl`` next to the
output directory ``OUT`` (one file per cell, written to a temporary name and renamed, so a killed
process leaves only whole cells). The key is a SHA-256 of everything the cell's numbers depend
on — the content of its captures (samples, sampling, condition, unit, warm-up), the model
expression and options, the optimizer and its settings, the bounds, the seed and the cell's place
in the seed derivation, the number of runs, the polish, and the hystfit version — so a changed
input or setting invalidates exactly the cells it affects, and a store can never hand back a cell
computed under other conditions. ``--resume`` reuses the cells found; a run without ``--resume``
does not read them (it overwrites them as it goes). Once the outputs are published, the store is
removed.

The files are Python pickles: load a store only from a directory you wrote yourself.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import secrets
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__

from .capture import Capture

#: suffix of the directory that holds the stored cells of OUT (``OUT.partial``)
PARTIAL_SUFFIX = ".partial"


def partial_dir(out: str | os.PathLike) -> Path:
    """Where the cells of a run writing ``out`` are stored: the sibling ``out.partial``."""
    out = Path(out)
    if not out.name or out.name in (".", ".."):
        out = out.resolve()
    return out.parent / f"{out.name}{PARTIAL_SUFFIX}"


def _array_digest(a: np.ndarray) -> str:
    a = np.ascontiguousarray(a)
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())
    return h.hexdigest()


def capture_digest(c: Capture) -> str:
    """SHA-256 of what a fit reads from a capture (not its file name: a renamed file is the same data)."""
    parts = {"u": _array_digest(c.u), "y": None if c.y is None else _array_digest(c.y), "t": _array_digest(c.t),
             "dt": float(c.dt), "unit": c.y_unit, "condition": [float(c.amplitude_V), float(c.frequency_Hz)],
             "warmup": int(c.warmup_samples)}
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()


def _canonical(x: Any) -> Any:
    """A JSON-able, order-independent form of ``x`` (arrays and captures by digest)."""
    if isinstance(x, Capture):
        return {"capture": capture_digest(x)}
    if isinstance(x, np.ndarray):
        return {"array": _array_digest(x)}
    if isinstance(x, dict):
        return {str(k): _canonical(v) for k, v in sorted(x.items(), key=lambda kv: str(kv[0]))}
    if isinstance(x, (list, tuple)):
        return [_canonical(v) for v in x]
    if isinstance(x, (np.integer, np.floating, np.bool_)):
        return x.item()
    if isinstance(x, float):
        return repr(x)  # nan, inf and every bit of the value
    if x is None or isinstance(x, (bool, int, str)):
        return x
    return repr(x)


def cell_key(kind: str, **parts: Any) -> str:
    """The store key of one cell: SHA-256 of its kind, ``parts`` and the hystfit version."""
    text = json.dumps({"kind": kind, "version": __version__, "parts": _canonical(parts)}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


class CellStore:
    """Finished cells on disk, one pickle per key, under ``root/cells``."""

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)
        self.dir = self.root / "cells"

    def get(self, key: str) -> Any | None:
        """The stored cell, or None (absent, or unreadable: a cell that cannot be read is recomputed)."""
        try:
            with open(self.dir / f"{key}.pkl", "rb") as fh:
                return pickle.load(fh)
        except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError, TypeError, ValueError):
            return None

    def put(self, key: str, value: Any) -> None:
        """Store one cell: written to a temporary file, then renamed (whole or absent)."""
        self.dir.mkdir(parents=True, exist_ok=True)
        tmp = self.dir / f".{key}.{secrets.token_hex(4)}.tmp"
        with open(tmp, "wb") as fh:
            pickle.dump(value, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, self.dir / f"{key}.pkl")

    def __len__(self) -> int:
        return len(list(self.dir.glob("*.pkl"))) if self.dir.is_dir() else 0

    def clear(self) -> None:
        """Remove every stored cell (and the store's directory)."""
        shutil.rmtree(self.root, ignore_errors=True)
