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
