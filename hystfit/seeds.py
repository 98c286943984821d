"""Seeds: the one rule for a valid ``--seed`` and how each run derives its own.

Kept apart from the orchestration modules so that the command line validates ``--seed`` without
importing them (the models, the optimizers).
"""

from __future__ import annotations

import numpy as np

from .errors import ConfigError

__all__ = ["SEED_MAX", "check_seed", "run_seed"]

#: the largest seed (numpy's SeedSequence takes any integer; the CLI and the library accept 32 bits)
SEED_MAX = 2 ** 32 - 1


def check_seed(seed) -> int:
    """``seed`` as an int; :class:`ConfigError` unless it is an integer in [0, 2**32 − 1] (the CLI's
    ``--seed`` range), so the library refuses what the command line refuses, with the same words."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) <= SEED_MAX:
        raise ConfigError(f"seed must be an integer in [0, {SEED_MAX}]. Got {seed!r} instead.")
    return int(seed)


def run_seed(seed: int, cell: int, run: int) -> int:
    """Derived seed of run ``run`` of cell ``cell``: reproducible and independent across runs."""
    return int(np.random.SeedSequence([int(seed), int(cell), int(run)]).generate_state(1, dtype=np.uint32)[0])
