"""What the command line imports before a command does any work.

Every command pays its parser's imports: typer 0.29 made pydantic a required dependency and builds a
pydantic ``TypeAdapter`` for every parameter of the parsed command (≈ 0.1 s on each command on the
benchmark machine: ``hystfit models`` 0.36 against 0.25 s), so pyproject.toml keeps typer below 0.29.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

_PROBE = r"""
import json, sys
from hystfit.cli import main
sys.argv = ["hystfit", *sys.argv[1:]]
try:
    main()
except SystemExit:
    pass
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in ("pydantic", "pydantic_core"))))
"""


@pytest.mark.parametrize("args", [["models", "--json"], ["identify", "/nonexistent/capture.csv", "--no-plots"]],
                         ids=["models", "identify-bad-path"])
def test_parsing_a_command_imports_no_pydantic(args):
    out = subprocess.run([sys.executable, "-c", _PROBE, *args], capture_output=True, text=True, timeout=120)
    last = out.stdout.strip().splitlines()[-1]
    assert json.loads(last) == [], f"parsing `hystfit {' '.join(args)}` imported {last}"
