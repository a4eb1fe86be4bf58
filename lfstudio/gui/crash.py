"""Unhandled exceptions in the GUI: logged with their traceback, shown in a dialog, never fatal.

:func:`install_exception_hooks` replaces ``sys.excepthook`` (exceptions escaping Qt slots and event
handlers land there) and ``threading.excepthook`` (background threads); :func:`restore_exception_hooks`
puts back the ones it found. Each exception is written
to the log file with its traceback, then a non-modal :class:`CrashDialog` says what happened, where
the log is, and offers "Copy details" (traceback + versions) for a bug report. The application keeps
running: scans run on their own threads and their views are in the dataset journal as they are
captured, so nothing of a running scan is lost.
"""

from __future__ import annotations

import logging
import sys
from html import escape
import threading
import traceback

from PySide6.QtCore import QObject, Qt
from PySide6.QtGui import QFontDatabase, QGuiApplication
from PySide6.QtWidgets import (QDialog, QDialogButtonBox, QHBoxLayout, QLabel, QPlainTextEdit, QPushButton,
                               QStyle, QVBoxLayout, QWidget)

from lfstudio.gui.bridge import GuiInbox

log = logging.getLogger(__name__)

#: at most this many dialogs stay open; later exceptions are logged and counted in the last one
MAX_OPEN_DIALOGS = 3


def format_details(exc_type, exc, tb, where: str) -> str:
    from lfstudio.support.versions import report_text

    text = "".join(traceback.format_exception(exc_type, exc, tb))
    return f"{where}\n\n{text}\n{report_text()}\n"


class CrashDialog(QDialog):
    """What happened, where the log is, the details (folded away) and "Copy details"."""

    def __init__(self, summary: str, details: str, log_path: str, parent: QWidget | None = None):
        super().__init__(parent)
        self.setObjectName("crashDialog")
        self.setWindowTitle("lfstudio: unexpected error")
        self.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        self.details = details
        self.repeats = 0

        icon = QLabel()
        icon.setPixmap(self.style().standardIcon(QStyle.StandardPixmap.SP_MessageBoxWarning).pixmap(40, 40))
        self.message = QLabel(
            f"<b>Something went wrong inside lfstudio.</b><p>{escape(summary, quote=False)}</p>"
            "<p>lfstudio keeps running. A running scan continues; every view already captured is "
            "saved in the dataset. If something no longer works, save your work and restart lfstudio.</p>"
            f"<p>The details are in the log file:<br><code>{escape(log_path, quote=False)}</code><br>"
            "Please send it (or the copied details) with a short note of what you were doing.</p>")
        self.message.setWordWrap(True)
        self.message.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.message.setObjectName("crashMessage")
        top = QHBoxLayout()
        top.addWidget(icon, 0, Qt.AlignmentFlag.AlignTop)
        top.addWidget(self.message, 1, Qt.AlignmentFlag.AlignTop)

        self.text = QPlainTextEdit(details)
        self.text.setReadOnly(True)
        self.text.setFont(QFontDatabase.systemFont(QFontDatabase.SystemFont.FixedFont))
        self.text.setObjectName("crashDetails")
        self.text.setVisible(False)
        self.text.setMinimumHeight(220)

        buttons = QDialogButtonBox()
        self.copy_button = QPushButton("&Copy details")
        self.copy_button.setObjectName("copyDetails")
        self.copy_button.setToolTip("Copy the error, its traceback and the component versions to the clipboard")
        self.copy_button.clicked.connect(self.copy_details)
        self.show_button = QPushButton("Show &details")
        self.show_button.setCheckable(True)
        self.show_button.setToolTip("Show the traceback and component versions")
        self.show_button.toggled.connect(self._toggle_details)
        folder_button = QPushButton("Open log &folder")
        folder_button.setToolTip(f"Open {log_path} in the file manager")
        folder_button.clicked.connect(lambda: open_log_folder())
        buttons.addButton(self.copy_button, QDialogButtonBox.ButtonRole.ActionRole)
        buttons.addButton(self.show_button, QDialogButtonBox.ButtonRole.ActionRole)
        buttons.addButton(folder_button, QDialogButtonBox.ButtonRole.ActionRole)
        close = buttons.addButton(QDialogButtonBox.StandardButton.Close)
        close.setToolTip("Close this message; lfstudio keeps running")
        buttons.rejected.connect(self.reject)

        lay = QVBoxLayout(self)
        lay.addLayout(top)
        lay.addWidget(self.text, 1)
        lay.addStretch(0)
        lay.addWidget(buttons)
        self.setMinimumWidth(600)
        self.resize(600, 270)       # word-wrapped labels do not grow a dialog by themselves

    def _toggle_details(self, on: bool) -> None:
        self.text.setVisible(on)
        self.show_button.setText("Hide &details" if on else "Show &details")
        self.resize(self.width(), 270 + (320 if on else 0))

    def copy_details(self) -> None:
        QGuiApplication.clipboard().setText(self.details)
        self.copy_button.setText("Copied")

    def add_repeat(self, details: str) -> None:
        """Another exception while this dialog is open: append it instead of opening more windows."""
        self.repeats += 1
        self.details += f"\n--- and {self.repeats} more ---\n{details}"
        self.text.setPlainText(self.details)
        self.setWindowTitle(f"lfstudio: unexpected error (+{self.repeats} more)")


def open_log_folder() -> bool:
    """Open the log folder in the desktop's file manager; False when there is no desktop to ask."""
    from PySide6.QtCore import QUrl
    from PySide6.QtGui import QDesktopServices

    from lfstudio.support.logs import log_dir

    folder = log_dir()
    folder.mkdir(parents=True, exist_ok=True)
    return QDesktopServices.openUrl(QUrl.fromLocalFile(str(folder)))


class ExceptionReporter(QObject):
    """Receives exceptions from any thread and shows them on the GUI thread."""

    def __init__(self, parent_widget: QWidget | None = None):
        super().__init__()
        self.parent_widget = parent_widget
        self.dialogs: list[CrashDialog] = []
        self.count = 0
        self._replaced: tuple | None = None     # (sys.excepthook, threading.excepthook) before install
        self._inbox = GuiInbox(self._show_all, self)     # (summary, details), from any thread

    def report(self, exc_type, exc, tb, where: str) -> None:
        """Log and (queued) show one exception; callable from any thread, never raises."""
        try:
            from lfstudio.support.logs import flush_logs

            self.count += 1
            log.error("unhandled exception %s", where, exc_info=(exc_type, exc, tb))
            flush_logs()
            summary = f"{exc_type.__name__}: {exc}" if str(exc) else exc_type.__name__
            self._inbox.post((f"{summary} ({where})", format_details(exc_type, exc, tb, where)))
        except Exception:  # noqa: BLE001 - the reporter itself must never raise into Qt
            traceback.print_exc(file=sys.__stderr__)

    def _show_all(self, reports: list[tuple[str, str]]) -> None:
        for summary, details in reports:
            self._show(summary, details)

    def _show(self, summary: str, details: str) -> None:
        from lfstudio.support.logs import log_file

        self.dialogs = [d for d in self.dialogs if _alive(d)]
        if len(self.dialogs) >= MAX_OPEN_DIALOGS:
            self.dialogs[-1].add_repeat(details)
            return
        parent = self.parent_widget if _alive(self.parent_widget) else None
        dialog = CrashDialog(summary, details, str(log_file()), parent)
        dialog.finished.connect(lambda _=0, d=dialog: self.dialogs.remove(d) if d in self.dialogs else None)
        self.dialogs.append(dialog)
        dialog.show()                    # non-modal: the event loop (and a running scan's GUI) goes on


def _alive(widget) -> bool:
    if widget is None:
        return False
    try:
        import shiboken6

        return shiboken6.isValid(widget)
    except ImportError:
        return True


def install_exception_hooks(parent_widget: QWidget | None = None) -> ExceptionReporter:
    """Route unhandled exceptions (GUI thread and other threads) to the log and a crash dialog."""
    reporter = ExceptionReporter(parent_widget)

    def gui_hook(exc_type, exc, tb):
        if issubclass(exc_type, KeyboardInterrupt):
            sys.__excepthook__(exc_type, exc, tb)
            return
        reporter.report(exc_type, exc, tb, "in the application window")

    def thread_hook(args):
        if args.exc_type is SystemExit:
            return
        name = args.thread.name if args.thread is not None else "a background thread"
        reporter.report(args.exc_type, args.exc_value, args.exc_traceback, f"in thread {name}")

    reporter._replaced = (sys.excepthook, threading.excepthook)
    sys.excepthook = gui_hook
    threading.excepthook = thread_hook
    return reporter


def restore_exception_hooks(reporter: ExceptionReporter) -> None:
    """Put back the hooks :func:`install_exception_hooks` replaced for ``reporter`` (each install
    keeps the ones it found, so nested installs unwind in order, as napari's do). The window calls
    it when the application quits; an embedding program or a test gets its own hooks back."""
    replaced, reporter._replaced = reporter._replaced, None
    if replaced is not None:
        sys.excepthook, threading.excepthook = replaced
