"""pyright's "basic" checks of pyproject.toml's [tool.pyright] hold for the package (run like ruff in
tests/test_lint.py): an attribute of None, a wrong argument type, a misspelt Qt enum or a view record
read with a key it does not have fails the suite. The checker runs on this interpreter's site-packages,
so it sees the libraries the tests import."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO_ROOT


@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_pyright_basic_finds_nothing_in_the_package():
    pyright = Path(sys.executable).with_name("pyright")
    assert pyright.exists(), "pyright is missing: it is part of the test extras (pip install -e '.[test]')"
    env = dict(os.environ, PYRIGHT_PYTHON_IGNORE_WARNINGS="1")      # no look for a newer version
    # -p: this checkout's [tool.pyright], never a pyrightconfig.json that pyright would find in a folder above
    r = subprocess.run([str(pyright), "--outputjson", "-p", str(REPO_ROOT / "pyproject.toml"), "--pythonpath",
                        sys.executable], cwd=REPO_ROOT,
                       capture_output=True, text=True, timeout=1100, env=env)
    try:
        report = json.loads(r.stdout)
    except ValueError:
        pytest.fail(f"pyright did not run (exit {r.returncode}): {r.stdout[-2000:]}{r.stderr[-2000:]}")
    assert report["summary"]["filesAnalyzed"] > 100          # the package, not an empty include
    errors = [d for d in report["generalDiagnostics"] if d["severity"] == "error"]
    shown = "\n".join(f"{Path(d['file']).relative_to(REPO_ROOT)}:{d['range']['start']['line'] + 1}: "
                      f"{d['message'].splitlines()[0]} ({d.get('rule', '')})" for d in errors[:40])
    assert not errors, f"{len(errors)} pyright errors:\n{shown}"
