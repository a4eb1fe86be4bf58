"""The layering rules of pyproject.toml's [tool.importlinter] contracts hold (run with lint-imports),
and at run time the CLI loads neither Qt nor lfstudio.gui."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.conftest import REPO_ROOT


def test_import_linter_contracts_are_kept():
    lint = Path(sys.executable).with_name("lint-imports")
    assert lint.exists(), "import-linter is missing: it is part of the test extras (pip install -e '.[test]')"
    r = subprocess.run([str(lint), "--no-cache"], cwd=REPO_ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "0 broken" in r.stdout


def test_the_cli_loads_no_gui_and_no_qt():
    code = ("import sys\n"
            "import lfstudio.__main__\n"
            "from lfstudio.cli import build_parser\n"
            "build_parser()\n"          # imports every subcommand module
            "bad = sorted(m for m in sys.modules if m.startswith(('lfstudio.gui', 'PySide6', 'pyqtgraph')))\n"
            "print(bad)\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def test_every_part_of_lfstudio_is_under_the_contracts():
    """A new package (or top-level module) of lfstudio must be added to the contracts that cover
    "everything but ..." (pyproject.toml), so no rule silently misses it."""
    import pkgutil
    import tomllib

    import lfstudio

    parts = {f"lfstudio.{m.name}" for m in pkgutil.iter_modules(lfstudio.__path__)}
    contracts = {c["id"]: c for c in tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["tool"]
                 ["importlinter"]["contracts"]}
    everything_but = {"core-no-qt": {"lfstudio.gui"}, "sim-behind-studio": {"lfstudio.sim", "lfstudio.studio"}}
    for cid, exempt in everything_but.items():
        missing = sorted(parts - exempt - set(contracts[cid]["source_modules"]))
        assert not missing, f"pyproject.toml contract {cid!r}: add {missing} to its source_modules"


def test_docs_architecture_lists_the_layers_of_the_contract():
    """docs/architecture.md's layer list is the one lint-imports checks (top to bottom, same groups)."""
    import re
    import tomllib

    contracts = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    layers = next(c for c in contracts if c["id"] == "layers")["layers"]
    doc = (REPO_ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    block = re.search(r"<!-- layers .*?-->\s*```\n(.*?)```", doc, re.S)
    assert block, "docs/architecture.md lost its layer list"
    assert [line.strip() for line in block.group(1).splitlines() if line.strip()] == layers
