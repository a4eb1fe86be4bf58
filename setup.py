"""The wheel carries the documentation site: ``build_py`` builds ``docs/`` with Sphinx into
``lfstudio/site/`` (tools/build_backend/lfstudio_build.py gives the build environment the tools).
Everything else about the package is in pyproject.toml."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent


class BuildPyWithSite(build_py):
    def run(self) -> None:
        super().run()
        if getattr(self, "editable_mode", False) or self.dry_run:
            return                                  # a checkout: tools/docs.sh builds docs/_build/html
        out = Path(self.build_lib) / "lfstudio" / "site"
        try:
            import sphinx  # noqa: F401
            import myst_parser  # noqa: F401
            import pydata_sphinx_theme  # noqa: F401
        except ImportError as exc:
            print(f"lfstudio: the documentation site is not built into this wheel ({exc.name} is missing; "
                  "pip install . builds it)", file=sys.stderr)
            return
        with tempfile.TemporaryDirectory() as doctrees:
            env = dict(os.environ, PYTHONPATH=str(HERE) + os.pathsep + os.environ.get("PYTHONPATH", ""))
            subprocess.run([sys.executable, "-m", "sphinx", "-q", "-b", "html", "-d", doctrees,
                            str(HERE / "docs"), str(out)], check=True, env=env, cwd=HERE)
        for junk in (".buildinfo", ".doctrees"):
            path = out / junk
            if path.is_file():
                path.unlink()


setup(cmdclass={"build_py": BuildPyWithSite})
