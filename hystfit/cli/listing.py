"""``hystfit models`` and ``hystfit optimizers``: what is registered, with parameters, units and references."""

from __future__ import annotations

from typing import Annotated

import typer
from rich.table import Table

from .app import app, guarded
from .common import print_json, stdout


@app.command("models")
@guarded
def list_models(json_out: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False) -> None:
    """List the registered hysteresis models with their parameters (units, default bounds) and references."""
    from ..catalog import model_catalog

    cat = model_catalog()
    if json_out:
        print_json({"models": cat})
        return
    for m in cat:
        t = Table(title=f"[bold]{m['name']}[/bold] — {m['title']}  ({m['reference']})", title_justify="left")
        for col in ("parameter", "unit", "lower", "upper", "meaning"):
            t.add_column(col)
        for p in m["parameters"]:
            t.add_row(p["name"], p["unit"], f"{p['lower']:.4g}", f"{p['upper']:.4g}", p["description"])
        stdout.print(t)
        stdout.print(f"  {m['equation']}")
        stdout.print(f"  bounds shown for a reference stage (0–100 V → 0–30 µm); they scale with the data. "
                     f"Structure options: {m['structure'] or 'none'}\n")


@app.command("optimizers")
@guarded
def list_optimizers(json_out: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False) -> None:
    """List the registered optimizers with their settings, defaults and references."""
    from ..catalog import optimizer_catalog

    cat = optimizer_catalog()
    if json_out:
        print_json({"optimizers": cat})
        return
    t = Table(title="optimizers")
    for col in ("name", "title", "reference", "settings (defaults)"):
        t.add_column(col)
    for o in cat:
        t.add_row(o["name"], o["title"], o["reference"], ", ".join(f"{k}={v}" for k, v in o["settings"].items()))
    stdout.print(t)
