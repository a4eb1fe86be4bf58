"""Start the Qt application."""

from __future__ import annotations

import logging
import os
import sys

from lfstudio.errors import window_message
from lfstudio import __version__
from lfstudio.resources import RESOURCES_DIR

log = logging.getLogger("lfstudio")


def keep_image_work_on_the_gui_thread() -> None:
    """Qt scales and converts large images (a drawImage of the grid's mosaic, a thumbnail's
    conversion) on a pool of its own threads and waits for them: on a busy computer (two cores, a
    scan's threads, a check process) those threads wait for a core and the GUI thread with them,
    idle, for tens of milliseconds. ``QT_NO_GUI_THREADPOOL`` makes Qt do that work on the calling
    thread. Qt reads it once, at its first such image operation: call this before painting anything."""
    os.environ.setdefault("QT_NO_GUI_THREADPOOL", "1")


def create_window(simulated: bool = True):
    """Build the application state and main window (a QApplication must exist)."""
    from lfstudio.gui.icons import app_icon
    from lfstudio.gui.heartbeat import keep_out_of_gc
    from lfstudio.gui.main_window import MainWindow
    from lfstudio.gui.state import AppState
    from lfstudio.gui.widgets import install_wheel_guard

    # background Python threads (scan engine, device workers, jobs) share the GIL with the GUI
    # thread; a shorter switch interval hands it back to the GUI sooner (fewer visible stalls)
    sys.setswitchinterval(0.001)
    keep_image_work_on_the_gui_thread()
    install_wheel_guard()
    state = AppState(simulated=simulated)
    window = MainWindow(state)
    window.setWindowIcon(app_icon())
    keep_out_of_gc()          # the window lives as long as the app: keep full GC passes (stalls) small
    return window


def run_app(simulated: bool = True, dataset: str | None = None, screenshot: str | None = None) -> int:
    from PySide6.QtCore import QTimer
    from PySide6.QtWidgets import QApplication

    from lfstudio.gui.crash import install_exception_hooks, restore_exception_hooks
    from lfstudio.gui.heartbeat import install_watchdog
    from lfstudio.gui.icons import app_icon
    from lfstudio.support.logs import is_configured, setup_logging

    if not is_configured():          # the CLI sets it up (with --debug); direct callers get the defaults
        setup_logging()
    keep_image_work_on_the_gui_thread()
    running = QApplication.instance()
    app = running if isinstance(running, QApplication) else QApplication(sys.argv[:1])
    app.setApplicationName("lfstudio")
    app.setOrganizationName("lfstudio")
    app.setApplicationVersion(__version__)
    app.setDesktopFileName("lfstudio")      # Wayland/X11: match the window to lfstudio.desktop (and its icon)
    app.setWindowIcon(app_icon())
    style = RESOURCES_DIR / "style.qss"
    if style.is_file():
        app.setStyleSheet(style.read_text(encoding="utf-8"))
    window = create_window(simulated=simulated)
    reporter = install_exception_hooks(window)
    watchdog = install_watchdog(window)     # GUI stalls > 50 ms go to the log with their source  # noqa: F841 (kept while the app runs)
    log.info("lfstudio %s window open (%s)", __version__, "simulated studio" if simulated else "hardware")
    if dataset:
        from lfstudio.dataset import Dataset
        from lfstudio.errors import LfError
        try:
            window.state.set_dataset(Dataset.open(dataset))
        except LfError as exc:
            window.state.report_error("Open dataset", window_message(exc))
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
    try:
        return app.exec()
    finally:
        from lfstudio.gui.devices import wait_for_closing

        wait_for_closing(10.0)          # the window is gone: the devices' disconnects may end now
        restore_exception_hooks(reporter)
