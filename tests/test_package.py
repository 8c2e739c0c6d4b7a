"""vislam installs as one package: vislam.ekf, vislam.graph, vislam.eval, never the generic
top-level names ekf, graph and eval; the public API is importable from ``vislam``."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

import vislam


def _python(code: str, cwd) -> subprocess.CompletedProcess:
    """``code`` in a fresh interpreter of this environment, outside the checkout, so the
    checkout's folders are not on sys.path (as for a user who pip-installed vislam)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


def test_import_vislam_works_and_generic_names_do_not(tmp_path):
    proc = _python(
        "import importlib.util, vislam, vislam.ekf, vislam.graph, vislam.eval, vislam.eval.cli\n"
        "print([importlib.util.find_spec(n) is None for n in ('ekf', 'graph', 'eval')])",
        tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[True, True, True]", proc.stdout


@pytest.mark.parametrize("name", sorted(vislam._EXPORTS))
def test_every_public_name_resolves(name):
    value = getattr(vislam, name)
    module = getattr(value, "__module__", None) or vislam._EXPORTS[name]  # data: no __module__
    assert module.startswith("vislam."), module
    assert name in dir(vislam)


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        vislam.nope  # noqa: B018


def test_import_vislam_does_not_import_gtsam(tmp_path):
    proc = _python("import sys, vislam; vislam.load_sequence; print('gtsam' in sys.modules)",
                   tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "False"


def test_console_script_points_into_the_package():
    from importlib.metadata import entry_points

    (script,) = [e for e in entry_points(group="console_scripts") if e.name == "vislam"]
    assert script.value == "vislam.eval.cli:main"
