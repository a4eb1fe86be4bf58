"""The documentation site (docs/, Sphinx) builds with warnings as errors, its internal links and
anchors all lead somewhere, and its command-line reference has every command and option of the
parsers (it is generated from them)."""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

from tests.conftest import REPO_ROOT

DOCS = REPO_ROOT / "docs"
pytestmark = pytest.mark.xdist_group("docs-site")      # one build, on one worker


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    pytest.importorskip("sphinx")
    pytest.importorskip("myst_parser")
    pytest.importorskip("pydata_sphinx_theme")
    out = tmp_path_factory.mktemp("site") / "html"
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
                           "-d", str(out.parent / "doctrees"), str(DOCS), str(out)],
                          capture_output=True, text=True, timeout=280, env=env, cwd=REPO_ROOT)
    assert proc.returncode == 0, f"the site does not build without warnings:\n{proc.stderr[-4000:]}"
    return out


class _Links(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.links: list[str] = []
        self.ids: set[str] = set()

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if a.get("id"):
            self.ids.add(a["id"])
        for key in ("href", "src"):
            if a.get(key):
                self.links.append(a[key])


def _parsed(path: Path) -> _Links:
    p = _Links()
    p.feed(path.read_text(encoding="utf-8"))
    return p


def test_the_site_builds_and_every_internal_link_and_anchor_leads_somewhere(site):
    pages = sorted(p for p in site.rglob("*.html") if "_static" not in p.relative_to(site).parts)
    assert len(pages) >= 30, [p.name for p in pages]
    parsed = {p: _parsed(p) for p in pages}
    broken = []
    for page, links in parsed.items():
        for link in links.links:
            url = urlsplit(link)
            if url.scheme or link.startswith("//") or link.startswith("mailto:"):
                continue                                     # outside links: not checked (no network)
            target = (page.parent / unquote(url.path)).resolve() if url.path else page
            if not target.exists():
                broken.append(f"{page.relative_to(site)}: {link} (no such file)")
            elif url.fragment and target.suffix == ".html":
                ids = parsed[target].ids if target in parsed else _parsed(target).ids
                if unquote(url.fragment) not in ids:
                    broken.append(f"{page.relative_to(site)}: {link} (no such anchor)")
    assert not broken, "\n".join(broken[:40])


def test_the_command_reference_has_every_command_and_option(site):
    from lfstudio.cli import build_parser

    page = (site / "reference" / "cli.html").read_text(encoding="utf-8")
    ids = _parsed(site / "reference" / "cli.html").ids
    text = re.sub(r"<[^>]+>", "", page)
    missing = []

    def walk(parser: argparse.ArgumentParser, name: str) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub_name, sub in action.choices.items():
                    if f"{name}-{sub_name}".lower() not in ids:
                        missing.append(f"section {name} {sub_name}")
                    walk(sub, f"{name}-{sub_name}")
            elif action.help != argparse.SUPPRESS:
                missing.extend(f"{name}: {o}" for o in action.option_strings if o not in text)

    walk(build_parser(), "lfstudio")
    assert not missing, missing[:40]
    assert "\u2013port" not in text and "--port" in text      # options stay typeable (no smart dashes)


def test_the_device_reference_documents_the_plugin_interfaces(site):
    text = re.sub(r"<[^>]+>", "", (site / "reference" / "devices.html").read_text(encoding="utf-8"))
    for name in ("Camera", "ArrayCamera", "MotionController", "capture", "grab", "move_to", "on_exposed"):
        assert name in text, name

