"""hystfit — identify, compare, invert and diagnose hysteresis models of piezoelectric actuators.

Library entry points::

    from hystfit import load_captures
    from hystfit.identify import identify
    from hystfit.registry import models, optimizers   # name → class registries
"""

__version__ = "0.1.0"

from .errors import ConfigError, HystfitError, InputError, OutputError  # noqa: E402


def __getattr__(name):  # lazy imports keep `import hystfit` light
    if name in ("load_captures", "load_capture", "LoadOptions"):
        from . import io

        return getattr(io, name)
    raise AttributeError(name)


__all__ = ["__version__", "HystfitError", "InputError", "ConfigError", "OutputError",
           "load_captures", "load_capture", "LoadOptions"]
