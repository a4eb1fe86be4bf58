"""Start the Qt application."""

from __future__ import annotations

import logging
import os
import sys
import traceback

from lfstudio.resources import RESOURCES_DIR, user_config_dir

log = logging.getLogger("lfstudio")


def _install_excepthook(state) -> None:
    """Unexpected exceptions in slots become a message box and a log entry, never a crash or a traceback."""
    log_path = user_config_dir() / "lfstudio.log"

    def hook(exc_type, exc, tb):
        text = "".join(traceback.format_exception(exc_type, exc, tb))
        try:
            log_path.parent.mkdir(parents=True, exist_ok=True)
            with open(log_path, "a", encoding="utf-8") as fh:
                fh.write(text + "\n")
        except OSError:
            pass
        sys.__stderr__.write(text)
        state.report_error("Unexpected error", f"{exc_type.__name__}: {exc}\n\nDetails were written to {log_path}.")

    sys.excepthook = hook


def create_window(simulated: bool = True):
    """Build the application state and main window (a QApplication must exist)."""
    from lfstudio.gui.main_window import MainWindow
    from lfstudio.gui.state import AppState

    # background Python threads (scan engine, device workers, jobs) share the GIL with the GUI
    # thread; a shorter switch interval hands it back to the GUI sooner (fewer visible stalls)
    sys.setswitchinterval(0.001)
    state = AppState(simulated=simulated)
    return MainWindow(state)


def run_app(simulated: bool = True, dataset: str | None = None, screenshot: str | None = None) -> int:
    from PySide6.QtCore import QTimer
    from PySide6.QtWidgets import QApplication

    logging.basicConfig(level=logging.DEBUG if os.environ.get("LFSTUDIO_DEBUG") else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    app = QApplication.instance() or QApplication(sys.argv[:1])
    app.setApplicationName("lfstudio")
    app.setOrganizationName("lfstudio")
    style = RESOURCES_DIR / "style.qss"
    if style.is_file():
        app.setStyleSheet(style.read_text(encoding="utf-8"))
    window = create_window(simulated=simulated)
    _install_excepthook(window.state)
    if dataset:
        from lfstudio.dataset import Dataset
        from lfstudio.errors import LfError
        try:
            window.state.set_dataset(Dataset.open(dataset))
        except LfError as exc:
            window.state.report_error("Open dataset", str(exc))
    window.show()
    if simulated:
        QTimer.singleShot(0, window.connect_simulated_studio)
    if screenshot:
        def grab() -> None:
            window.grab().save(screenshot)
            print(f"saved {screenshot}")
            window.close()
            app.quit()
        QTimer.singleShot(3000, grab)
    return app.exec()
