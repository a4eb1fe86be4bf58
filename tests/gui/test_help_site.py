"""Help → User guide (F1) opens the built documentation site's page for the panel the keyboard is in
when the site is built and shipped, and the in-app guide when it is not."""

from __future__ import annotations

import pytest
from PySide6.QtGui import QDesktopServices

from lfstudio.gui.app import create_window


@pytest.fixture
def window(qtbot):
    w = create_window(simulated=True)
    qtbot.addWidget(w)
    w.show()
    qtbot.waitExposed(w)
    yield w
    w.close()


def test_f1_opens_the_sites_page_of_the_panel_and_the_guide_without_a_site(qtbot, window, tmp_path, monkeypatch):
    import lfstudio.gui.main_window as main_window

    site = tmp_path / "html"
    (site / "how-to").mkdir(parents=True)
    for page in ("index.html", "how-to/scan.html", "how-to/rig.html"):
        (site / page).write_text("<html><body>page</body></html>")
    opened: list[str] = []
    monkeypatch.setattr(QDesktopServices, "openUrl", staticmethod(lambda url: opened.append(url.toLocalFile()) or True))
    monkeypatch.setenv("LFSTUDIO_DOCS_SITE", str(site))

    assert window.show_user_guide("scanPanel") is None
    assert opened[-1] == str(site / "how-to" / "scan.html")
    assert window.show_user_guide(None) is None and opened[-1] == str(site / "index.html")
    # the panel the keyboard is in: a widget inside the Rig panel's dock
    inside = window.panels["rigDock"]
    monkeypatch.setattr(main_window.QApplication, "focusWidget", staticmethod(lambda: inside))
    assert window.help_topic() == "rigDock"
    window.findChild(main_window.QAction, "actionUserGuide").trigger()            # what F1 does
    assert opened[-1] == str(site / "how-to" / "rig.html")

    monkeypatch.setenv("LFSTUDIO_DOCS_SITE", "")                                  # not built: the in-app guide
    dialog = window.show_user_guide("scanPanel")
    assert dialog is not None and "Planning a scene" in dialog.browser.toPlainText()
    assert len(opened) == 3
    dialog.close()


def test_f1_in_a_dialog_opens_the_dialogs_page_and_the_guide_says_how_to_build_the_site(qtbot, window, tmp_path,
                                                                                        monkeypatch):
    from PySide6.QtCore import Qt
    from PySide6.QtWidgets import QApplication, QDialog

    site = tmp_path / "html"
    (site / "how-to").mkdir(parents=True)
    for page in ("index.html", "how-to/export.html"):
        (site / page).write_text("<html><body>page</body></html>")
    opened: list[str] = []
    monkeypatch.setattr(QDesktopServices, "openUrl", staticmethod(lambda url: opened.append(url.toLocalFile()) or True))
    monkeypatch.setenv("LFSTUDIO_DOCS_SITE", str(site))
    dialog = QDialog(window)                            # stands for the Export dialog (its object name)
    dialog.setObjectName("exportDialog")
    qtbot.addWidget(dialog)
    dialog.show()
    dialog.activateWindow()
    qtbot.waitUntil(lambda: QApplication.activeWindow() is dialog)
    qtbot.keyClick(dialog, Qt.Key.Key_F1)                # F1 while the dialog is in front
    qtbot.waitUntil(lambda: bool(opened))
    assert opened == [str(site / "how-to" / "export.html")]
    dialog.close()

    monkeypatch.setenv("LFSTUDIO_DOCS_SITE", "")         # not built: the in-app guide says how to build it
    guide = window.show_user_guide("scanPanel")
    text = " ".join(guide.browser.toPlainText().split())
    assert "tools/docs.sh" in text and "pip install ." in text and "search" in text
    guide.close()


def test_the_site_has_a_page_for_every_panel_and_dialog_f1_names():
    from lfstudio.support.userguide import SITE_PAGES
    from tests.conftest import REPO_ROOT

    sources = {p for p in SITE_PAGES.values()}
    missing = [p for p in sources if not (REPO_ROOT / "docs" / p.replace(".html", ".md")).is_file()]
    assert not missing, missing
    gui = "\n".join(p.read_text(encoding="utf-8") for p in (REPO_ROOT / "lfstudio" / "gui").rglob("*.py"))
    unnamed = [name for name in SITE_PAGES if f'"{name}"' not in gui]
    assert not unnamed, f"no panel or dialog has these object names: {unnamed}"
