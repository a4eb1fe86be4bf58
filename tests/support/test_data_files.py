"""Every file the app reads from ``resources/`` is installed by ``pip install .``/pipx: pyproject's
``[tool.setuptools.data-files]`` lists files by explicit globs, so a new resource file that no glob
covers would be missing from installed copies (they only find it in a checkout)."""

from __future__ import annotations

import glob
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:   # Python < 3.11
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[2]


def test_every_resource_file_is_installed_as_data():
    data_files = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["data-files"]
    installed = {Path(p).resolve() for patterns in data_files.values() for pattern in patterns
                 for p in glob.glob(str(ROOT / pattern))}
    resources = {p.resolve() for p in (ROOT / "resources").rglob("*")
                 if p.is_file() and "__pycache__" not in p.parts}
    missing = sorted(str(p.relative_to(ROOT)) for p in resources - installed)
    assert resources and not missing, f"add these to [tool.setuptools.data-files] in pyproject.toml: {missing}"
    assert (ROOT / "README.md").resolve() in installed
    from lfstudio.support.userguide import CHAPTER_PAGES, GUIDE_PAGES

    pages = {(ROOT / "docs" / page).resolve() for page in GUIDE_PAGES + CHAPTER_PAGES}
    assert pages <= installed, sorted(str(p) for p in pages - installed)     # the in-app user guide
