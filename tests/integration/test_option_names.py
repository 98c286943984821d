"""One name per concept across commands (issue 14 item 13).

Every option that several commands share — found by the flag, so a new command is checked too —
must have the same spellings, default and range everywhere, and no concept may have two names.
"""

from collections import defaultdict

import pytest
import typer.main

from hystfit.cli import app

#: Options whose default legitimately differs per command, with the reason.
DEFAULT_DIFFERS = {
    "--out": "each command writes its own kind of output (hystfit-out, hystfit-compare, ...)",
    "--per-condition": "identify builds a look-up table (per condition), diagnose asks one model (global)",
    "--fs": "a capture's sample rate vs a built-in trajectory's",
    "--condition": "no default anywhere; typed per command",
    "--effects": "synth: the simulated plant's effects (default set); diagnose: the candidates to test (all)",
    "--noise": "µm everywhere; synth keeps the plant's own sensor noise unless given, track adds none",
}

#: Spellings retired in favour of one name: they may only exist as hidden aliases.
RETIRED = {"--figures": "--plots"}

def _range(p) -> tuple:
    """(min, max) of an option: on the parameter (typer >= 0.29) or on its click range type."""
    kind = getattr(p, "type", None)
    return tuple(getattr(p, k, None) if getattr(p, k, None) is not None else getattr(kind, k, None)
                 for k in ("min", "max"))


def _commands():
    root = typer.main.get_command(app)

    def walk(cmd, path):
        if hasattr(cmd, "commands"):
            for n, c in cmd.commands.items():
                yield from walk(c, path + [n])
        else:
            yield " ".join(path), cmd

    return dict(walk(root, []))


def _flag(p) -> str:
    return max(p.opts, key=len)


def test_shared_options_have_one_spelling_default_and_range():
    seen = defaultdict(list)
    for name, cmd in _commands().items():
        for p in cmd.params:
            if p.param_type_name != "option" or p.hidden:
                continue
            seen[_flag(p)].append((name, p))
    problems = []
    for flag, uses in seen.items():
        if len(uses) < 2:
            continue
        first_cmd, first = uses[0]
        for cmd, p in uses[1:]:
            if sorted(p.opts + p.secondary_opts) != sorted(first.opts + first.secondary_opts):
                problems.append(f"{flag}: spelled {p.opts + p.secondary_opts} in {cmd}, "
                                f"{first.opts + first.secondary_opts} in {first_cmd}")
            if flag not in DEFAULT_DIFFERS and p.default != first.default:
                problems.append(f"{flag}: default {p.default!r} in {cmd}, {first.default!r} in {first_cmd}")
            if _range(p) != _range(first):
                problems.append(f"{flag}: range differs between {cmd} and {first_cmd}")
    assert not problems, "\n".join(problems)


def test_a_flag_is_always_spelled_the_same_way():
    """A flag that appears in several commands comes with the same other spellings everywhere
    (``--global`` is always the other half of ``--per-condition/--global``, never a lone flag)."""
    spellings = defaultdict(set)
    for name, cmd in _commands().items():
        for p in cmd.params:
            if p.param_type_name != "option" or p.hidden:
                continue
            full = tuple(sorted(p.opts + p.secondary_opts))
            for flag in full:
                spellings[flag].add(full)
    clashes = {flag: sorted(v) for flag, v in spellings.items() if len(v) > 1}
    assert not clashes, clashes


def test_retired_spellings_are_hidden_aliases_only():
    for name, cmd in _commands().items():
        visible = {o for p in cmd.params if not getattr(p, "hidden", False) for o in p.opts + p.secondary_opts}
        for old, new in RETIRED.items():
            assert old not in visible, f"{name}: shows {old}; the one name is {new}"


@pytest.mark.parametrize("flag", ["--seed", "--pop", "--iters", "--jobs", "--runs"])
def test_numeric_options_state_their_range(flag):
    for name, cmd in _commands().items():
        for p in cmd.params:
            if flag in p.opts:
                checked = _range(p)[0] is not None or p.callback is not None
                assert checked, f"{name} {flag}: no lower limit"
                if flag == "--seed":
                    assert p.callback is not None and "4294967295" in p.help, f"{name} --seed: not the shared check"
