"""The typer application and its error boundary.

Command modules (``hystfit/cli/<command>.py``) register themselves on :data:`app` when imported
(``hystfit/cli/__init__.py`` imports them all). Each command body is wrapped by :func:`guarded`,
which turns every :class:`~hystfit.errors.HystfitError` into one line on stderr and exit code 2 —
so the same behaviour holds under the console script and under typer's ``CliRunner``.
"""

from __future__ import annotations

import functools
import sys
from typing import Callable, TypeVar

import typer

from ..errors import HystfitError

F = TypeVar("F", bound=Callable)

app = typer.Typer(
    name="hystfit",
    help="Identify, compare, invert and diagnose hysteresis models of piezo actuators.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def error_line(message: str) -> None:
    """Print one error line on stderr."""
    typer.echo(f"hystfit: error: {message}", err=True)


def guarded(fn: F) -> F:
    """Map HystfitError (and Ctrl-C) raised by a command to a one-line message and an exit code."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except HystfitError as exc:
            error_line(str(exc))
            raise typer.Exit(exc.exit_code) from None
        except KeyboardInterrupt:
            error_line("interrupted")
            raise typer.Exit(130) from None

    return wrapper  # type: ignore[return-value]


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point."""
    app(args=argv, prog_name="hystfit")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
