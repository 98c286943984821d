"""Exceptions raised by hystfit.

Every error a user can cause (bad file, bad column, bad option) is a :class:`HystfitError`.
The CLI's single error boundary (``hystfit.cli.main``) prints ``str(error)`` as one line on
stderr and exits with ``error.exit_code`` (2), never a traceback. Messages name the file,
the row or column, the rule that was broken and what to do about it.
"""

from __future__ import annotations


class HystfitError(Exception):
    """Base class of every error hystfit reports to a user (exit code 2)."""

    exit_code = 2


class InputError(HystfitError, ValueError):
    """A capture file cannot be used: missing, unreadable, malformed or unsuitable data."""


class ConfigError(HystfitError, ValueError):
    """An option, parameter bound, model or optimizer name is invalid."""


class OutputError(HystfitError, OSError):
    """An output location cannot be written (exists and is not empty, no permission, ...)."""


class NoResultError(HystfitError):
    """A command ran but produced no usable result (e.g. every cell of ``compare`` failed).

    Exit code 3, so scripts can tell "nothing to use" from bad input (2) and Ctrl-C (130).
    """

    exit_code = 3


class CellsFailedError(HystfitError):
    """A command finished and wrote its outputs, but some cells failed on every attempt.

    Exit code 4, so scripts can tell "done, with holes" from "nothing to use" (3). The failed
    cells and their errors are in the outputs.
    """

    exit_code = 4


class Terminated(KeyboardInterrupt):
    """SIGTERM reached the command line (a job scheduler's time limit, ``timeout``, ``kill``).

    Raised in the command's main thread by the console script's handler, it takes the path of
    Ctrl-C (a :class:`KeyboardInterrupt`): process pools are stopped at once, nothing half-written
    is left, a resumable run keeps the cells it stored. The command says so in one line and exits
    143 (128 + SIGTERM, what a shell reports for a process the signal ended).
    """

    exit_code = 143
