"""Batch files: a list of hystfit jobs in TOML, for shell scripts and batch systems.

::

    # jobs.toml — paths and globs are relative to this file
    [defaults]                 # options for every job whose command has them (a job's own win)
    seed = 0
    plots = false

    [[job]]
    name = "lut"               # optional; default: job-1, job-2, ...
    command = "identify"       # identify | compare | diagnose | simulate
    data = ["captures/*.csv"]  # files, directories or globs (a string or a list)
    out = "results/lut"
    model = "pi+creep"         # every other key is a command-line option, without the dashes
    runs = 3

    [[job]]
    command = "simulate"
    params = "results/lut/params.json"   # simulate's PARAMS argument (an earlier job's output is fine)
    data = "validation/*.csv"
    out = "results/validation"

Option values: ``true`` gives the flag (``plots = true`` → ``--plots``), ``false`` its negative
(``--no-plots``, or the flag's other half: ``per_condition = false`` → ``--global``), a list repeats
the option (``bounds = ["a=0:1", "b=0:2"]``), anything else is its text. This module reads and
checks the file; ``hystfit batch`` checks the option names against each command and runs the jobs.
"""

from __future__ import annotations

import glob
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

from .errors import ConfigError

#: commands a batch job may run
BATCH_COMMANDS = ("identify", "compare", "diagnose", "simulate")

#: keys of a job that are not command-line options
JOB_KEYS = ("name", "command", "data", "out", "params")


@dataclass(frozen=True)
class BatchJob:
    """One job: ``hystfit COMMAND [PARAMS] DATA... --out OUT OPTIONS``."""

    name: str
    command: str
    data: tuple[Path, ...]
    out: Path
    params: Path | None = None
    options: dict = field(default_factory=dict)  # the job's own options
    defaults: dict = field(default_factory=dict)  # [defaults]: used where the command has the option


def _read_toml(path: Path) -> dict:
    try:
        import tomllib
    except ImportError:  # Python 3.10
        raise ConfigError(f"{path}: batch files need Python >= 3.11 (the standard library's tomllib); this is "
                          f"Python {sys.version_info.major}.{sys.version_info.minor} — run the jobs as separate "
                          "commands, or use Python 3.11 or newer") from None
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such batch file; give the path of a TOML file with [[job]] tables") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the batch file ({exc.strerror or exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc}); fix the file (see docs/scale.md for an example)") from None


def _expand(path: Path, where: str, value, base: Path) -> tuple[Path, ...]:
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list) or not items or not all(isinstance(v, str) and v for v in items):
        raise ConfigError(f"{path}: {where} data must be a path or glob, or a list of them; "
                          "e.g. data = [\"captures/*.csv\"]")
    out: list[Path] = []
    for item in items:
        pattern = item if os.path.isabs(item) else str(base / item)
        if glob.has_magic(pattern):
            hits = sorted(glob.glob(pattern))
            if not hits:
                raise ConfigError(f"{path}: {where} data {item!r} matches no file; check the pattern (paths are "
                                  "relative to the batch file)")
            out += [Path(h) for h in hits]
        else:
            out.append(Path(pattern))
    return tuple(out)


def load_batch(path: str | os.PathLike) -> list[BatchJob]:
    """Read and check a batch file; every mistake is a :class:`ConfigError` naming the file and the job."""
    path = Path(path)
    doc = _read_toml(path)
    base = path.parent
    unknown = set(doc) - {"defaults", "job"}
    if unknown:
        raise ConfigError(f"{path}: unknown top-level key(s) {', '.join(sorted(unknown))}; a batch file has "
                          "[defaults] and [[job]] tables only")
    defaults = doc.get("defaults", {})
    if not isinstance(defaults, dict):
        raise ConfigError(f"{path}: [defaults] must be a table of options")
    bad = set(defaults) & set(JOB_KEYS)
    if bad:
        raise ConfigError(f"{path}: [defaults] cannot set {', '.join(sorted(bad))}; set them in each [[job]]")
    raw = doc.get("job", [])
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{path}: no jobs; add at least one [[job]] table with command, data and out")
    jobs, names, outs = [], set(), set()
    for k, entry in enumerate(raw, start=1):
        name = str(entry.get("name", f"job-{k}"))
        where = f"job {name!r}"
        command = entry.get("command")
        if command not in BATCH_COMMANDS:
            raise ConfigError(f"{path}: {where}: command {command!r} is not one of {', '.join(BATCH_COMMANDS)}")
        if name in names:
            raise ConfigError(f"{path}: {where}: the name is used twice; give every job its own name")
        for key, example in (("data", '["captures/*.csv"]'), ("out", f'"results/{name}"')):
            if key not in entry:
                raise ConfigError(f"{path}: {where}: {key} is missing; e.g. {key} = {example}")
        if not isinstance(entry["out"], str) or not entry["out"]:
            raise ConfigError(f"{path}: {where}: out must be a directory path (text)")
        out = Path(entry["out"]) if os.path.isabs(entry["out"]) else base / entry["out"]
        if out.resolve() in outs:
            raise ConfigError(f"{path}: {where}: out {entry['out']!r} is the output of another job; give each its own")
        params = None
        if command == "simulate":
            if not isinstance(entry.get("params"), str):
                raise ConfigError(f"{path}: {where}: simulate needs params = \"PATH/params.json\" (an identify output)")
            params = Path(entry["params"]) if os.path.isabs(entry["params"]) else base / entry["params"]
        elif "params" in entry:
            raise ConfigError(f"{path}: {where}: params is for simulate jobs only; remove it")
        data = _expand(path, where, entry["data"], base)
        options = {k: v for k, v in entry.items() if k not in JOB_KEYS}
        for key, value in {**defaults, **options}.items():
            if isinstance(value, dict) or (isinstance(value, list) and any(isinstance(v, (dict, list)) for v in value)):
                raise ConfigError(f"{path}: {where}: option {key!r} must be a value or a list of values")
        names.add(name)
        outs.add(out.resolve())
        jobs.append(BatchJob(name, command, data, out, params, options, dict(defaults)))
    return jobs
