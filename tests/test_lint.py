"""ruff's rules of pyproject.toml's [tool.ruff] hold for the package, the tests and the benchmarks
(run like lint-imports in tests/test_import_rules.py: a change that leaves an unused name, a
redefinition or an undefined name fails the suite)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.conftest import REPO_ROOT


def test_ruff_finds_nothing():
    ruff = Path(sys.executable).with_name("ruff")
    assert ruff.exists(), "ruff is missing: it is part of the test extras (pip install -e '.[test]')"
    r = subprocess.run([str(ruff), "check", "--no-cache", "lfstudio", "tests", "benchmarks"], cwd=REPO_ROOT,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
