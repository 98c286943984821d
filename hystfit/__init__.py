"""hystfit — identify, compare, invert and diagnose hysteresis models of piezoelectric actuators.

Library entry points::

    from hystfit import load_captures, models, optimizers
    from hystfit.identify import identify
"""

__version__ = "0.1.0"

from .errors import ConfigError, HystfitError, InputError, OutputError  # noqa: E402
from .registry import models, optimizers  # noqa: E402


def __getattr__(name):  # lazy imports keep `import hystfit` light
    if name in ("load_captures", "load_capture", "LoadOptions"):
        from . import io

        return getattr(io, name)
    raise AttributeError(name)


__all__ = ["__version__", "HystfitError", "InputError", "ConfigError", "OutputError", "models", "optimizers",
           "load_captures", "load_capture", "LoadOptions"]
