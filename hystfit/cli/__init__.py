"""Command-line interface: parsing and printing only (no numerics).

Every command lives in its own module and registers itself on :data:`app` when imported.
"""

from .app import app, main

# Command modules (import order = order in ``hystfit --help``).
from . import identify as _identify  # noqa: E402,F401
from . import simulate as _simulate  # noqa: E402,F401
from . import compare as _compare  # noqa: E402,F401
from . import synth as _synth  # noqa: E402,F401
from . import listing as _listing  # noqa: E402,F401

__all__ = ["app", "main"]
from . import diagnose as _diagnose  # noqa: E402,F401
from . import invert as _invert  # noqa: E402,F401
from . import track as _track  # noqa: E402,F401
