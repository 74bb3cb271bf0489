"""What the LinuxCNC integration modules share: paths, the skip marks, the CLI in JSON."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from ilcnc.cli import app

REPO = Path(__file__).resolve().parents[2]
PROFILE = REPO / "configs" / "linuxcnc-sim.yaml"
HAVE_LINUXCNC = shutil.which("linuxcnc") is not None
runner = CliRunner()


def needs_linuxcnc(what: str = "cannot run programs on LinuxCNC's motion controller") -> list[Any]:
    """Marks of a test that runs LinuxCNC: ``linuxcnc``, and a skip with a visible reason where it is missing."""
    return [
        pytest.mark.linuxcnc,
        pytest.mark.skipif(not HAVE_LINUXCNC, reason="LinuxCNC is not installed ('linuxcnc' not on PATH; Debian 12: "
                           f"apt-get install linuxcnc-uspace): {what}"),
    ]


def cli_json(*args: object) -> dict[str, Any]:
    """Run ``ilcnc ARGS --json``; it must succeed. Returns its JSON object."""
    res = runner.invoke(app, [str(a) for a in args] + ["--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.output)
