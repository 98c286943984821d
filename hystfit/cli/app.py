"""The typer application and its error boundary.

Command modules (``hystfit/cli/<command>.py``) register themselves on :data:`app` when imported
(``hystfit/cli/__init__.py`` imports them all) with :func:`command`. Each command body is wrapped
by :func:`guarded`, which turns every :class:`~hystfit.errors.HystfitError` into one line on stderr
and exit code 2 — so the same behaviour holds under the console script and under typer's
``CliRunner``. Options that several commands share as a set (how to read captures, what to write)
are declared once as an :class:`OptionGroup` and expanded into each command's options by
:func:`expand_option_groups`.
"""

from __future__ import annotations

import dataclasses
import functools
import gc
import inspect
import signal
import sys
import threading
import typing
from contextlib import contextmanager
from typing import Callable, TypeVar

import typer
from typer.core import TyperGroup

from ..errors import HystfitError, Terminated

try:  # recent typer vendors click (its exceptions are not the click package's)
    from typer._click import exceptions as click_exceptions
except ImportError:  # pragma: no cover - older typer
    from click import exceptions as click_exceptions

F = TypeVar("F", bound=Callable)

class OneLineErrors(TyperGroup):
    """The command group: usage errors (bad option value, unknown option, missing argument) are
    printed like every other error — one ``hystfit: error:`` line on stderr, exit code 2 — instead of
    typer's framed box."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        if not standalone_mode:
            return super().main(args=args, prog_name=prog_name, complete_var=complete_var,
                                standalone_mode=False, **extra)
        try:
            code = super().main(args=args, prog_name=prog_name, complete_var=complete_var,
                                standalone_mode=False, **extra)
        except click_exceptions.NoArgsIsHelpError as exc:
            typer.echo(exc.ctx.get_help() if exc.ctx is not None else str(exc), err=True)
            sys.exit(2)
        except click_exceptions.ClickException as exc:
            where = exc.ctx.command_path if getattr(exc, "ctx", None) is not None else "hystfit"
            error_line(f"{exc.format_message()} (see '{where} --help')")
            sys.exit(exc.exit_code)
        except typer.Abort as exc:  # Ctrl-C or SIGTERM while the command line was parsed
            stop = exc.__context__ if isinstance(exc.__context__, KeyboardInterrupt) else KeyboardInterrupt()
            error_line(stop_message(stop))
            sys.exit(stop_code(stop))
        sys.exit(code if isinstance(code, int) else 0)

    def resolve_command(self, ctx, args):
        name, cmd, rest = super().resolve_command(ctx, args)
        if cmd is not None:
            _refuse_both_halves(cmd, rest, type(ctx)(cmd, info_name=name, parent=ctx))
        return name, cmd, rest


def _refuse_both_halves(cmd, args: list[str], ctx) -> None:
    """Both halves of an on/off pair on one command line (``--per-condition --global``,
    ``--plots --no-plots``) are a usage error, not "the last one wins" (a blind test's find:
    ``identify --per-condition --global`` fitted globally without a word)."""
    given = set(args[: args.index("--")] if "--" in args else args)
    for p in cmd.params:
        on, off = [o for o in getattr(p, "opts", ()) if o in given], [o for o in getattr(p, "secondary_opts", ())
                                                                         if o in given]
        if on and off:
            raise click_exceptions.UsageError(f"{on[0]} and {off[0]} contradict each other; give one of them", ctx)


app = typer.Typer(
    name="hystfit",
    cls=OneLineErrors,
    help="Identify, compare, invert and diagnose hysteresis models of piezo actuators.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


#: the message of the last error line printed (``hystfit batch`` puts a failed job's in its JSON row)
LAST_ERROR: list[str] = []


def error_line(message: str) -> None:
    """Print one error line on stderr: a line break inside the message (a file name holding one, a
    blind test's ``x\nbad.csv``) is shown as ``\n``, so a script that reads the error's line reads all of it."""
    one = str(message).replace("\r\n", "\\n").replace("\n", "\\n").replace("\r", "\\r")
    LAST_ERROR[:] = [one]
    typer.echo(f"hystfit: error: {one}", err=True)


def guarded(fn: F) -> F:
    """Map HystfitError (and Ctrl-C) raised by a command to a one-line message and an exit code."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except HystfitError as exc:
            error_line(str(exc))
            raise typer.Exit(exc.exit_code) from None
        except KeyboardInterrupt as exc:
            error_line(stop_message(exc))
            raise typer.Exit(stop_code(exc)) from None

    return wrapper  # type: ignore[return-value]


def stop_message(exc: KeyboardInterrupt) -> str:
    """The one line for a command stopped by Ctrl-C or by SIGTERM (:class:`hystfit.errors.Terminated`)."""
    return "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"


def stop_code(exc: KeyboardInterrupt) -> int:
    """The exit code of a command stopped by Ctrl-C (130) or by SIGTERM (143)."""
    return Terminated.exit_code if isinstance(exc, Terminated) else 130


def _raise_terminated(signum, frame) -> None:
    """The console script's SIGTERM handler: the command stops as on Ctrl-C (:class:`Terminated`)."""
    raise Terminated(f"signal {signum}")


@contextmanager
def _sigterm_stops_command():
    """While the command runs, SIGTERM raises :class:`Terminated` in it instead of ending the
    process on the spot, so its pools, servers and staged outputs are cleaned up as on Ctrl-C
    (processes it forks reset the handler: :func:`hystfit.parallel.fork_map`'s children, the
    figure server). Main thread only; the previous handler is restored afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, saved)


class OptionGroup:
    """Base of a frozen dataclass whose fields are options several commands share as a set.

    Each field is annotated with its ``Annotated[type, typer.Option(...)]`` alias and has its
    default. A command parameter annotated with the group (``capture: CaptureArgs =
    CaptureArgs()``) stands, in ``--help`` and on the command line, for the group's options at
    that place, and the command receives them as one instance (:func:`expand_option_groups`).
    """


def expand_option_groups(fn: F) -> F:
    """Let typer see the fields of every :class:`OptionGroup` parameter of ``fn`` as options in
    its place (same order, annotations and defaults), and call ``fn`` with the group built from
    them. Commands without a group are returned unchanged."""
    sig = inspect.signature(fn, eval_str=True)
    params: list[inspect.Parameter] = []
    groups: dict[str, tuple[type, list[str]]] = {}
    for p in sig.parameters.values():
        if not (isinstance(p.annotation, type) and issubclass(p.annotation, OptionGroup)):
            params.append(p)
            continue
        hints = typing.get_type_hints(p.annotation, include_extras=True)
        fields = dataclasses.fields(p.annotation)
        groups[p.name] = (p.annotation, [f.name for f in fields])
        params += [inspect.Parameter(f.name, p.kind, default=f.default, annotation=hints[f.name]) for f in fields]
    if not groups:
        return fn

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        for name, (group, names) in groups.items():
            kwargs[name] = group(**{n: kwargs.pop(n) for n in names})
        return fn(*args, **kwargs)

    wrapper.__signature__ = sig.replace(parameters=params)  # type: ignore[attr-defined]
    return wrapper  # type: ignore[return-value]


def command(name: str | None = None, *, on: typer.Typer | None = None) -> Callable[[F], F]:
    """Register a command on :data:`app` (or the sub-app ``on``): its option groups expanded
    (:func:`expand_option_groups`) and its errors mapped to one line (:func:`guarded`)."""
    register = (on or app).command(name)

    def decorate(fn: F) -> F:
        return register(guarded(expand_option_groups(fn)))

    return decorate


def _show_version(value: bool) -> None:
    if value:
        from .. import __version__

        typer.echo(f"hystfit {__version__}")
        raise typer.Exit(0)


@app.callback()
def _root(version: bool = typer.Option(False, "--version", is_eager=True, callback=_show_version,
                                       help="Print the version and exit.")) -> None:
    """Identify, compare, invert and diagnose hysteresis models of piezo actuators."""


#: commands that draw figures unless told ``--no-plots``: their figure server starts before parsing
FIGURE_COMMANDS = ("identify", "compare", "diagnose", "invert", "track", "simulate")


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point.

    For a command that will probably draw (:data:`FIGURE_COMMANDS`, no ``--no-plots``/``--help``
    among the words), the figure server is forked first, so matplotlib loads on the other core
    while the command line is parsed (≈ 0.3 s: typer's validators) and the command loads and fits;
    the command claims it, or it is closed unused. Called without ``argv`` (the console script),
    every object is frozen out of the garbage collector at the end (:func:`gc.freeze`): the
    interpreter's exit then does not walk them. SIGTERM stops the command as Ctrl-C does, with its
    own line and exit code 143 (:func:`_sigterm_stops_command`).
    """
    _one_line_warnings()
    with _sigterm_stops_command():
        _main(argv)


#: True while the console script runs a command (:func:`main` without ``argv``): the process ends
#: when the command does, so work done only to save time may be dropped half-done on an error
#: (:func:`hystfit.cli.common.load_for_command`); never in a program that calls :func:`main` or
#: ``app`` (a test suite's ``CliRunner``), whose process goes on
PROCESS_ENDS_WITH_COMMAND = False


def process_ends_with_command() -> bool:
    """:data:`PROCESS_ENDS_WITH_COMMAND`, read at call time."""
    return PROCESS_ENDS_WITH_COMMAND


def _main(argv: list[str] | None) -> None:
    global PROCESS_ENDS_WITH_COMMAND
    words = sys.argv[1:] if argv is None else list(argv)
    PROCESS_ENDS_WITH_COMMAND = argv is None
    early = bool(words) and words[0] in FIGURE_COMMANDS and not {"--no-plots", "--help", "-h"} & set(words)
    if early:
        from ..report.render import preload_early

        preload_early()
    try:
        app(args=argv, prog_name="hystfit")
    finally:
        if early:
            from ..report.render import release_early

            release_early()
        if argv is None:
            # the console script: the process ends here. The interpreter's last collections would
            # walk every object the command made and imported (numba's, scipy's) only to free memory
            # the exit frees anyway (after a diagnose 0.33 s, frozen 0.06 s: benchmarks/exit_time.py);
            # frozen objects are left out of them. Files are closed by their context managers;
            # atexit handlers still run.
            gc.freeze()


def _one_line_warnings() -> None:
    """hystfit's own warnings (their message starts with ``hystfit:``, e.g. cells run in this
    process because no worker could be started) are printed as their message alone, one line, as
    the command's errors are; other warnings keep Python's format."""
    import warnings

    python_format = getattr(warnings.formatwarning, "python_format", warnings.formatwarning)

    def formatwarning(message, category, filename, lineno, line=None):
        if str(message).startswith("hystfit:"):
            return f"{message}\n"
        return python_format(message, category, filename, lineno, line)

    formatwarning.python_format = python_format
    warnings.formatwarning = formatwarning


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
