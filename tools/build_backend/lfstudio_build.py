"""lfstudio's build backend: setuptools', plus the documentation site built into the wheel.

``pip install .`` (and ``python -m build``, pipx) build a wheel: its build environment gets the site's
tools besides setuptools (:data:`SITE_REQUIRES`), and ``setup.py``'s ``build_py`` builds the site
(Sphinx, ``docs/``) into the package as ``lfstudio/site/`` (Help → User guide opens it). An editable
install (``pip install -e .``, what ./run.sh and ./test.sh do) builds no site and needs none of the
tools: a checkout's site is ``tools/docs.sh``'s ``docs/_build/html``.
"""

from __future__ import annotations

from setuptools import build_meta as _setuptools
from setuptools.build_meta import *  # noqa: F401,F403 - every hook setuptools has, unchanged unless below

#: what building the site needs (the docs extra, and what the pages' generated reference imports of lfstudio)
SITE_REQUIRES = ["sphinx>=8", "pydata-sphinx-theme>=0.16", "myst-parser>=4",
                 "numpy>=1.26", "opencv-python-headless>=4.8", "tomli-w>=1.0"]


def get_requires_for_build_wheel(config_settings=None):
    return [*_setuptools.get_requires_for_build_wheel(config_settings), *SITE_REQUIRES]
