"""The user guide: the README's "User guide" section, wherever lfstudio runs from.

Source checkout: ``README.md`` next to the package. PyInstaller bundle: ``README.md`` is shipped in
the bundle folder. Installed (``pip install .``, pipx): ``PREFIX/share/lfstudio/README.md``, else the
package's long description read back from the installed metadata.
"""

from __future__ import annotations

import os
from pathlib import Path

PROJECT_URL = "https://github.com/lfstudio/lfstudio#user-guide"


def readme_path() -> Path | None:
    """README.md of a checkout, bundle or installed copy (``PREFIX/share/lfstudio``), or None: it
    sits next to the resources folder in each (:data:`lfstudio.resources.RESOURCES_DIR` finds that)."""
    from lfstudio.resources import RESOURCES_DIR

    path = RESOURCES_DIR.parent / "README.md"
    return path if path.is_file() else None


def readme_markdown() -> str:
    path = readme_path()
    if path is not None:
        return path.read_text(encoding="utf-8")
    try:
        from importlib.metadata import metadata

        text = metadata("lfstudio").json.get("description")  # the long description (README.md)
        if isinstance(text, str) and text.strip():
            return text
    except Exception:  # noqa: BLE001 - not installed: fall through
        pass
    return f"# lfstudio\n\nThe user guide is not shipped with this installation: see {PROJECT_URL}\n"


def section(markdown: str, title: str, level: int = 2) -> str:
    """The text of the ``level`` heading ``title`` up to the next heading of the same or higher level."""
    lines = markdown.splitlines()
    start = None
    fenced = False
    for i, line in enumerate(lines):
        if line.lstrip().startswith("```"):
            fenced = not fenced
        if fenced:
            continue
        hashes = len(line) - len(line.lstrip("#"))
        if start is None:
            if hashes == level and line[hashes:].strip() == title:
                start = i
        elif 0 < hashes <= level and line[hashes:hashes + 1] == " ":
            return "\n".join(lines[start:i]).strip() + "\n"
    return "\n".join(lines[start:]).strip() + "\n" if start is not None else ""


def user_guide_markdown() -> str:
    """The "User guide" section (with the install and troubleshooting sections when present)."""
    text = readme_markdown()
    parts = [section(text, t) for t in ("User guide", "Installing on a studio workstation",
                                        "When something goes wrong")]
    parts = [p for p in parts if p]
    return "\n\n".join(parts) if parts else text


#: the documentation site's page for each panel (its dock's object name): Help → User guide (F1) opens it
SITE_PAGES = {"plannerDock": "how-to/plan.html", "planPlotsDock": "how-to/plan.html", "rigDock": "how-to/rig.html",
              "cameraDock": "how-to/cameras.html", "liveViewDock": "how-to/cameras.html", "scanPanel": "how-to/scan.html",
              "calibrationPanel": "how-to/calibrate.html", "processingPanel": "how-to/process.html"}


def site_dir() -> Path | None:
    """The built documentation site (the folder of its ``index.html``), or None: ``docs/_build/html``
    beside the resources folder (a checkout after ``tools/docs.sh``, a bundle built after it), or the
    folder ``LFSTUDIO_DOCS_SITE`` names (set and empty: no site)."""
    named = os.environ.get("LFSTUDIO_DOCS_SITE")
    if named is not None:
        folder = Path(named) if named else None
    else:
        from lfstudio.resources import RESOURCES_DIR

        folder = RESOURCES_DIR.parent / "docs" / "_build" / "html"
    return folder if folder is not None and (folder / "index.html").is_file() else None


def site_page(topic: str | None = None) -> Path | None:
    """The built site's page for ``topic`` (a panel's dock name, :data:`SITE_PAGES`; its start page for
    any other), or None when the site is not built and shipped (the in-app guide then shows
    :func:`user_guide_markdown`)."""
    site = site_dir()
    if site is None:
        return None
    page = site / SITE_PAGES.get(topic or "", "index.html")
    return page if page.is_file() else site / "index.html"
