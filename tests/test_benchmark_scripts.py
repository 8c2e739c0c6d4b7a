"""Every research script in benchmarks/ starts: ``--help`` prints its usage and exits 0.

The scripts are research tools, not the product, so this is all the fast tier asks of them
(their own checks, where kept, are in the regression tier). Each runs in this process as
``__main__`` (what ``python benchmarks/NAME.py --help`` does, without a second interpreter's
start-up), so a script that no longer imports, or whose flags no longer parse, fails here."""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
SCRIPTS = sorted(p.name for p in BENCHMARKS.glob("*.py"))


def test_there_are_scripts():
    assert SCRIPTS


@pytest.mark.parametrize("name", SCRIPTS)
def test_script_starts(name, monkeypatch, capsys):
    path = BENCHMARKS / name
    monkeypatch.setattr(sys, "argv", [str(path), "--help"])
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    with pytest.raises(SystemExit) as exit_info:
        runpy.run_path(str(path), run_name="__main__")
    assert exit_info.value.code in (0, None), capsys.readouterr().err[-2000:]
    assert "usage:" in capsys.readouterr().out
