"""A wheel of lfstudio (``pip install .``, pipx) carries the built documentation site as
``lfstudio/site/`` (setup.py's build_py; tools/build_backend gives the wheel's build environment the
tools), with the page Help → User guide (F1) opens for each panel and dialog; an editable install
(./run.sh, ./test.sh) needs none of the tools and builds no site."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile

import pytest

from tests.conftest import REPO_ROOT


def test_the_wheels_build_asks_for_the_sites_tools_and_the_editable_build_does_not():
    sys.path.insert(0, str(REPO_ROOT / "tools" / "build_backend"))
    try:
        import lfstudio_build
    finally:
        sys.path.pop(0)
    wheel = " ".join(lfstudio_build.get_requires_for_build_wheel())
    editable = " ".join(lfstudio_build.get_requires_for_build_editable())
    for tool in ("sphinx", "pydata-sphinx-theme", "myst-parser"):
        assert tool in wheel and tool not in editable


def test_the_wheel_carries_the_site_with_every_page_f1_opens(tmp_path):
    pytest.importorskip("sphinx")
    pytest.importorskip("myst_parser")
    pytest.importorskip("pydata_sphinx_theme")
    from lfstudio.support.userguide import SITE_PAGES

    # the test's environment has the tools already: no build isolation (no network), a copy of the
    # checkout's files (the build writes build/ and *.egg-info beside them)
    src = tmp_path / "src"
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=REPO_ROOT, capture_output=True,
                           text=True, check=True).stdout.split()
    for name in files:
        path = REPO_ROOT / name
        if path.is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            (src / name).write_bytes(path.read_bytes())
    env = dict(os.environ, PIP_NO_INDEX="1")
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                           "--disable-pip-version-check", "-w", str(tmp_path / "dist"), str(src)],
                          capture_output=True, text=True, timeout=280, env=env)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    (wheel,) = (tmp_path / "dist").glob("lfstudio-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert "lfstudio/site/index.html" in names and "lfstudio/site/search.html" in names
    missing = sorted({f"lfstudio/site/{page}" for page in SITE_PAGES.values()} - names)
    assert not missing, missing
