"""Sphinx configuration of lfstudio's documentation site (tools/docs.sh builds and opens it).

Markdown pages through myst-parser, the pydata-sphinx-theme; the command-line reference is generated
from lfstudio's own parsers (_ext/lfstudio_cli.py), the device interfaces from their docstrings."""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))            # lfstudio itself (the checkout)
sys.path.insert(0, str(HERE / "_ext"))

from lfstudio import __version__  # noqa: E402

project = "lfstudio"
author = "the lfstudio authors"
copyright = "the lfstudio authors, MIT licence"
version = release = __version__

extensions = ["myst_parser", "sphinx.ext.autodoc", "lfstudio_cli"]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store", "plugins/example-camera/lfstudio_example_camera",
                    "plugins/example-rig/lfstudio_example_rig"]
myst_enable_extensions = ["colon_fence", "deflist"]
# no "smart" dashes or quotes: the pages quote options (--port) and commands that must stay typeable
smartquotes = False
myst_heading_anchors = 4             # links like conventions.md#calibrationjson-... reach their heading

autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False}

html_theme = "pydata_sphinx_theme"
html_title = f"lfstudio {version}"
html_logo = "../resources/icons/hicolor/64x64/apps/lfstudio.png"
html_favicon = "../resources/icons/hicolor/32x32/apps/lfstudio.png"
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "header_links_before_dropdown": 5,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
html_show_sourcelink = False
html_copy_source = False
