"""Desktop integration files: the .desktop entry, the icons, the user guide text shipped with the app."""

from __future__ import annotations

import configparser
import shutil
import subprocess

import pytest

from tests.conftest import REPO_ROOT

DESKTOP = REPO_ROOT / "packaging" / "lfstudio.desktop"
ICONS = REPO_ROOT / "resources" / "icons"


def test_desktop_entry_parses_with_required_keys():
    parser = configparser.ConfigParser(interpolation=None, strict=True)
    parser.optionxform = str            # keys are case-sensitive in .desktop files
    parser.read_string(DESKTOP.read_text(encoding="utf-8"))
    entry = parser["Desktop Entry"]
    assert entry["Type"] == "Application" and entry["Name"] == "lfstudio"
    assert entry["Icon"] == "lfstudio"
    assert entry["Exec"].split()[0] == "lfstudio" and entry["Terminal"] == "false"
    assert entry["Categories"].endswith(";")
    main_categories = {"AudioVideo", "Audio", "Video", "Development", "Education", "Game", "Graphics",
                       "Network", "Office", "Science", "Settings", "System", "Utility"}
    assert len(main_categories & set(entry["Categories"].split(";"))) == 1   # listed once in menus


@pytest.mark.skipif(shutil.which("desktop-file-validate") is None,
                    reason="desktop-file-validate not installed (apt install desktop-file-utils)")
def test_desktop_entry_validates():
    r = subprocess.run(["desktop-file-validate", str(DESKTOP)], capture_output=True, text=True)
    assert r.returncode == 0 and not r.stdout.strip(), r.stdout + r.stderr   # no errors, no hints


def test_icon_pngs_match_their_sizes(qapp):
    from PySide6.QtGui import QImage

    for size in (16, 32, 48, 64, 128, 256, 512):
        image = QImage(str(ICONS / "hicolor" / f"{size}x{size}" / "apps" / "lfstudio.png"))
        assert (image.width(), image.height()) == (size, size)
        assert image.hasAlphaChannel() and image.pixelColor(0, 0).alpha() == 0   # rounded tile, transparent corner
    assert (ICONS / "hicolor" / "scalable" / "apps" / "lfstudio.svg").read_bytes() == (ICONS / "lfstudio.svg").read_bytes()


def test_window_has_the_app_icon(qtbot):
    from lfstudio.gui.app import create_window

    window = create_window(simulated=True)
    qtbot.addWidget(window)
    sizes = {(s.width(), s.height()) for s in window.windowIcon().availableSizes()}
    assert {(16, 16), (48, 48), (256, 256)} <= sizes


def test_user_guide_section_extraction_skips_code_comments():
    from lfstudio.support.userguide import section, user_guide_markdown

    text = "# T\n## User guide\nintro\n```bash\n# a comment, not a heading\n```\n### Sub\nbody\n## Next\nx\n"
    got = section(text, "User guide")
    assert "a comment" in got and "### Sub" in got and "## Next" not in got
    guide = user_guide_markdown()
    assert "## User guide" in guide and "## When something goes wrong" in guide and "## Development" not in guide
