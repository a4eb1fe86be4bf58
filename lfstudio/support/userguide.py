"""The in-app user guide (Help → User guide, F1): the documentation site's tutorial and how-to pages
(``docs/tutorial``, ``docs/how-to``) as one Markdown text, wherever lfstudio runs from.

Source checkout: ``docs/`` next to the package. PyInstaller bundle: ``docs/`` is shipped in the bundle
folder. Installed (``pip install .``, pipx): ``PREFIX/share/lfstudio/docs``. Without the pages: the
README (``PREFIX/share/lfstudio/README.md``, else the package's long description from the installed
metadata), whose sections held the guide before the site existed.
"""

from __future__ import annotations

import os
import posixpath
import re
from pathlib import Path

PROJECT_URL = "https://github.com/lfstudio/lfstudio#readme"

#: the guide's pages (under docs/), in the order of a day
GUIDE_PAGES = ("tutorial/the-window.md", "tutorial/day-in-the-studio.md", "how-to/plan.md", "how-to/rig.md",
               "how-to/cameras.md", "how-to/plugins.md", "how-to/scan.md", "how-to/calibrate.md",
               "how-to/check.md", "how-to/process.md", "how-to/depth.md", "how-to/export.md", "how-to/import.md",
               "how-to/new-dataset-folder.md")
#: pages that follow the guide as chapters of their own
CHAPTER_PAGES = ("how-to/install.md", "how-to/troubleshoot.md")


def readme_path() -> Path | None:
    """README.md of a checkout, bundle or installed copy (``PREFIX/share/lfstudio``), or None: it
    sits next to the resources folder in each (:data:`lfstudio.resources.RESOURCES_DIR` finds that)."""
    from lfstudio.resources import RESOURCES_DIR

    path = RESOURCES_DIR.parent / "README.md"
    return path if path.is_file() else None


def docs_dir() -> Path | None:
    """The ``docs`` folder holding the guide's pages (beside the resources folder), or None."""
    from lfstudio.resources import RESOURCES_DIR

    path = RESOURCES_DIR.parent / "docs"
    return path if all((path / page).is_file() for page in GUIDE_PAGES + CHAPTER_PAGES) else None


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


def page_markdown(docs: Path, page: str, levels: int) -> str:
    """A page of the site as a part of the guide: headings ``levels`` deeper, its links and pictures
    relative to the folder above ``docs`` (where the guide's browser looks them up: ``docs/x.png``)."""
    folder = posixpath.dirname(f"docs/{page}")
    out, fenced = [], False
    for line in (docs / page).read_text(encoding="utf-8").splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
        if not fenced and line.startswith("#"):
            hashes = len(line) - len(line.lstrip("#"))
            if line[hashes:hashes + 1] == " ":
                line = "#" * min(6, hashes + levels) + line[hashes:]
        out.append(line)

    def relink(m: re.Match) -> str:
        target = m.group(2)
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith(("#", "/")):
            return m.group(0)
        return f"{m.group(1)}({posixpath.normpath(posixpath.join(folder, target))})"

    return re.sub(r"(!?\[[^\]]*\])\(([^)\s]+)\)", relink, "\n".join(out)).strip() + "\n"


def user_guide_markdown() -> str:
    """The user guide: the tutorial and how-to pages (a "User guide" chapter), then installing and
    troubleshooting as chapters of their own; without the pages, the README's sections of those names."""
    docs = docs_dir()
    if docs is not None:
        parts = ["## User guide\n"] + [page_markdown(docs, page, 2) for page in GUIDE_PAGES]
        parts += [page_markdown(docs, page, 1) for page in CHAPTER_PAGES]
        return "\n\n".join(parts)
    text = readme_markdown()
    parts = [section(text, t) for t in ("User guide", "Installing on a studio workstation",
                                        "When something goes wrong")]
    parts = [p for p in parts if p]
    return "\n\n".join(parts) if parts else text


#: the documentation site's page for each panel (its dock's object name) and dialog (its object name):
#: Help → User guide (F1) opens it
SITE_PAGES = {"plannerDock": "how-to/plan.html", "planPlotsDock": "how-to/plan.html", "rigDock": "how-to/rig.html",
              "cameraDock": "how-to/cameras.html", "liveViewDock": "how-to/cameras.html", "scanPanel": "how-to/scan.html",
              "calibrationPanel": "how-to/calibrate.html", "processingPanel": "how-to/process.html",
              # dialogs
              "calibrationWizard": "how-to/calibrate.html", "processDialog": "how-to/process.html",
              "exportDialog": "how-to/export.html", "importImagesDialog": "how-to/import.html",
              "importHevcDialog": "how-to/import.html", "depthDialog": "how-to/depth.html",
              "neighboursDialog": "how-to/check.html", "disparityDialog": "how-to/check.html",
              "settingsDialog": "tutorial/the-window.html"}


def site_dir() -> Path | None:
    """The built documentation site (the folder of its ``index.html``), or None: the folder
    ``LFSTUDIO_DOCS_SITE`` names (set and empty: no site), else ``docs/_build/html`` beside the resources
    folder (a checkout after ``tools/docs.sh``, a bundle built after it), else the package's ``site``
    folder (a wheel's build builds it: ``pip install .``, pipx)."""
    named = os.environ.get("LFSTUDIO_DOCS_SITE")
    if named is not None:
        folders = [Path(named)] if named else []
    else:
        from lfstudio.resources import RESOURCES_DIR

        folders = [RESOURCES_DIR.parent / "docs" / "_build" / "html", PACKAGE_SITE]
    return next((f for f in folders if (f / "index.html").is_file()), None)


#: where a wheel's build puts the site (setup.py's build_py)
PACKAGE_SITE = Path(__file__).resolve().parents[1] / "site"

#: the in-app guide's first lines when the site is not built (it has no search and no contents)
NO_SITE_NOTE = ("*This is the guide without its search and table of contents: the documentation site is not "
                "built here. In a checkout, `tools/docs.sh` builds it (then F1 opens it in the browser); "
                "`pip install .` builds it into the installed package.*")


def site_page(topic: str | None = None) -> Path | None:
    """The built site's page for ``topic`` (a panel's dock name or a dialog's object name,
    :data:`SITE_PAGES`; its start page for any other), or None when the site is not built and shipped
    (the in-app guide then shows :func:`user_guide_markdown`)."""
    site = site_dir()
    if site is None:
        return None
    page = site / SITE_PAGES.get(topic or "", "index.html")
    return page if page.is_file() else site / "index.html"
