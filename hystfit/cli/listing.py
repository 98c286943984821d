"""``hystfit models`` and ``hystfit optimizers``: what is registered, with parameters, units and references."""

from __future__ import annotations

from typing import Annotated

import typer

from .app import command
from .common import new_table, print_json, stdout


#: ``--json`` of the listings
ListJson = Annotated[bool, typer.Option("--json", help="Machine-readable output.")]


@command("models")
def list_models(json_out: ListJson = False) -> None:
    """List the registered hysteresis models and blocks with their parameters (units, default bounds) and references."""
    from ..catalog import block_catalog, model_catalog

    cat = model_catalog()
    blk = block_catalog()
    if json_out:
        print_json({"models": cat, "blocks": blk})
        return
    for m in cat:
        stdout.print(_param_table(f"[bold]{m['name']}[/bold] — {m['title']}  ({m['reference']})", m["parameters"]))
        stdout.print(f"  {m['equation']}")
        stdout.print(f"  bounds shown for a reference stage (0–100 V → 0–30 µm); they scale with the data. "
                     f"Structure options: {m['structure'] or 'none'}\n")
    stdout.print("[bold]Blocks[/bold]: follow any model in an expression BASE+BLOCK+... (e.g. pi+creep+delay), "
                 "in the written order; options as --model-option BLOCK.KEY=VALUE, bounds as --bounds BLOCK.NAME=LO:HI. "
                 "Parameters and bounds are shown for a reference capture (1 s at 10 kHz, 0–100 V → 0–30 µm): a "
                 "structure option left None is set from the data, and with it the parameters (creep: one gain per "
                 "decade of τ from 0.01 s to the longest capture, so a 5 s capture adds creep.c3)\n")
    for b in blk:
        empty = ("per-capture offset and rate, projected out of the residual" if b["nuisance"]
                 else "structure only, identified from the data")
        stdout.print(_param_table(f"[bold]+{b['name']}[/bold] — {b['title']}  ({b['reference']})", b["parameters"], empty))
        stdout.print(f"  {b['equation']}   structure options: {b['structure'] or 'none'}\n")
    print_papers()


def _param_table(title: str, params: list[dict], empty: str | None = None):
    """One parameter table (name, unit, bounds on the reference scale, meaning)."""
    t = new_table(title=title, title_justify="left")
    for col in ("parameter", "unit", "lower", "upper", "meaning"):
        t.add_column(col)
    for p in params:
        t.add_row(p["name"], p["unit"], f"{p['lower']:.4g}", f"{p['upper']:.4g}", p["description"])
    if not params and empty:
        t.add_row("(none)", "", "", "", empty)
    return t


def print_papers() -> None:
    """The full citations of the papers the listings name as "paper 000" … "paper 004"."""
    from ..references import PAPERS

    stdout.print("Papers:", markup=False, highlight=False)
    for pid, text in PAPERS.items():
        stdout.print(f"  {pid}: {text}", markup=False, highlight=False)


#: stop-rule settings shared by the optimizers (hystfit.optimizers.base.StopRules) and what they mean
_STOP_SETTINGS = (("iters", "iterations"), ("max_evals", "evaluations"), ("stall_iter", "stall"),
                  ("target", "target value"), ("time_limit_s", "time limit"))


def _plain(text: str) -> str:
    """Docstring markup as plain text: ``x`` → x, :class:`~a.b.C` → C, *x* → x."""
    import re

    text = re.sub(r":\w+:`~?(?:[\w.]*\.)?([\w]+)`", r"\1", text)
    text = text.replace("``", "")
    return re.sub(r"(?<![\w*])\*([^*\s][^*]*?)\*(?![\w*])", r"\1", text)


def _doc_paragraph(doc: str, label: str) -> str:
    """The paragraph of ``doc`` that starts with ``label`` (e.g. "Bounds:"), as one plain line."""
    lines = [ln.strip() for ln in doc.splitlines()]
    for i, ln in enumerate(lines):
        if ln.startswith(label):
            para = [ln[len(label):].strip()]
            for nxt in lines[i + 1:]:
                if not nxt:
                    break
                para.append(nxt)
            return _plain(" ".join(para))
    return ""


def optimizer_rules(cls) -> dict[str, str]:
    """Stop rules and bounds handling of an optimizer class, from its docstring's "Stop rules:"
    and "Bounds:" paragraphs; the stop rules fall back to the stop settings it has."""
    doc = cls.__doc__ or ""
    fields = set(cls.option_names())
    stop = _doc_paragraph(doc, "Stop rules:") or "; ".join(
        f"{what} ({name})" for name, what in _STOP_SETTINGS if name in fields)
    return {"stop_rules": stop, "bounds_handling": _doc_paragraph(doc, "Bounds:")}


@command("optimizers")
def list_optimizers(json_out: ListJson = False) -> None:
    """List the registered optimizers: settings and defaults, stop rules, bounds handling, references."""
    from ..catalog import optimizer_catalog
    from ..registry import optimizers

    cat = [{**o, **optimizer_rules(optimizers.get(o["name"]))} for o in optimizer_catalog()]
    if json_out:
        print_json({"optimizers": cat})
        return
    for o in cat:
        t = new_table(title=f"[bold]{o['name']}[/bold] — {o['title']}  ({o['reference']})", title_justify="left",
                  show_header=False)
        t.add_column("", style="bold")
        t.add_column("")
        t.add_row("settings", ", ".join(f"{k}={v}" for k, v in o["settings"].items()) or "none")
        t.add_row("stop rules", o["stop_rules"])
        t.add_row("bounds", o["bounds_handling"] or "–")
        stdout.print(t)
    stdout.print("Settings are changed with --pop, --iters and --opt-option KEY=VALUE; the docstrings "
                 "(python -m pydoc hystfit.optimizers.<name>) give the equations.")
    print_papers()
