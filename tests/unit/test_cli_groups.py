"""Option groups of the command line: declared once, expanded in place into each command."""

from dataclasses import dataclass
from typing import Annotated

import pytest
import typer
from typer.testing import CliRunner

from hystfit.cli.app import OptionGroup, command, expand_option_groups
from hystfit.cli.common import CaptureArgs, FigureOutputArgs, FitCaptureArgs, OutputArgs
from hystfit.errors import ConfigError


@dataclass(frozen=True)
class _Pair(OptionGroup):
    alpha: Annotated[int, typer.Option("--alpha", help="First.")] = 1
    beta: Annotated[str, typer.Option("--beta", help="Second.")] = "b"


def test_a_group_stands_for_its_options_in_place_and_arrives_as_one_value():
    app = typer.Typer()
    seen = []

    @command(on=app)
    def run(first: Annotated[int, typer.Option("--first")] = 0, pair: _Pair = _Pair(),
            last: Annotated[int, typer.Option("--last")] = 0) -> None:
        seen.append((first, pair, last))

    @app.command()
    def other() -> None:  # two commands: typer keeps the command names
        pass

    r = CliRunner().invoke(app, ["run", "--beta", "x", "--first", "3", "--alpha", "5"])
    assert r.exit_code == 0, r.output
    assert seen == [(3, _Pair(5, "x"), 0)]
    flags = [p.opts[0] for p in typer.main.get_command(app).commands["run"].params]
    assert flags == ["--first", "--alpha", "--beta", "--last"]  # the group's options where the group stands


def test_a_command_without_groups_is_left_as_it_is():
    def plain(x: int = 1) -> int:
        return x

    assert expand_option_groups(plain) is plain


def test_deprecated_figures_spelling_sets_plots_and_chatty_follows_quiet_and_json():
    assert FigureOutputArgs(plots=True, figures_alias=False).plots is False
    assert FigureOutputArgs(plots=False).plots is False and FigureOutputArgs().plots is True
    assert OutputArgs().chatty and not OutputArgs(quiet=True).chatty and not OutputArgs(json_out=True).chatty


def test_capture_options_are_checked_and_warmup_only_where_fitting():
    assert CaptureArgs(time_col="0", fs=None).load_options().time_col == 0
    assert CaptureArgs().load_options().warmup_s == 0.0
    assert FitCaptureArgs(warmup=0.5).load_options(require_output=False).warmup_s == 0.5
    with pytest.raises(ConfigError, match="--stop 1: must be after --start"):
        CaptureArgs(start=2.0, stop=1.0).load_options()
    with pytest.raises(ConfigError, match="--output-unit 'km'"):
        CaptureArgs(output_unit="km").load_options()


@pytest.mark.parametrize("argv, frozen", [(None, 1), (["models"], 0)])
def test_the_console_script_freezes_every_object_before_the_interpreter_exits(monkeypatch, argv, frozen):
    """``main()`` as the console script (no argv) ends the process: its objects are frozen out of the
    interpreter's last collections (0.3 s of a diagnose); ``main(argv)`` called from Python is not."""
    import gc
    import importlib
    import sys

    app_module = importlib.import_module("hystfit.cli.app")  # the module (hystfit.cli.app is also the Typer)

    calls = []
    monkeypatch.setattr(gc, "freeze", lambda: calls.append("freeze"))
    monkeypatch.setattr(app_module, "app", lambda **kw: calls.append("app"))
    monkeypatch.setattr(sys, "argv", ["hystfit", "models"])
    app_module.main(argv)
    assert calls == ["app"] + ["freeze"] * frozen


def test_hystfits_own_warnings_are_printed_as_one_line_others_in_pythons_format(monkeypatch):
    import importlib
    import warnings

    app = importlib.import_module("hystfit.cli.app")  # the module (``hystfit.cli.app`` the package exports is the Typer app)
    monkeypatch.setattr(warnings, "formatwarning", warnings.formatwarning)
    app._one_line_warnings()
    app._one_line_warnings()  # installed twice (two commands in one process): still one line
    ours = warnings.formatwarning("hystfit: the worker processes could not be started (x); the 4 cells left run "
                                  "in this process", RuntimeWarning, "/x/parallel.py", 12)
    assert ours == "hystfit: the worker processes could not be started (x); the 4 cells left run in this process\n"
    other = warnings.formatwarning("something else", UserWarning, "/x/y.py", 3, line="")
    assert other.startswith("/x/y.py:3: UserWarning: something else")
