"""Small reusable widgets, and :class:`WheelGuard`, the application-wide rule for the mouse wheel."""

from __future__ import annotations

import time

import numpy as np
from PySide6.QtCore import QEvent, QObject, QPointF, QRectF, QSize, Qt, QTimer, Signal
from PySide6.QtGui import (QAction, QColor, QFont, QGuiApplication, QPainter, QPen, QPixmap, QTextDocumentFragment,
                           QWheelEvent, QWindow)
from PySide6.QtWidgets import (QAbstractSpinBox, QApplication, QComboBox, QHBoxLayout, QLabel, QMessageBox,
                               QProgressBar, QPushButton, QScrollArea, QSizePolicy, QToolButton, QVBoxLayout,
                               QWidget)

from lfstudio.dataset.paths import view_stem
from lfstudio.gui.bridge import Pacer
from lfstudio.jobs import format_duration
from lfstudio.numbers import Number, Param


def readable_time(iso: str | None) -> str:
    """A timestamp from a file (ISO 8601, UTC, milliseconds: ``dataset.manifest.now_iso``) as a person
    reads it, in local time: "27 Nov 2026, 13:48" ("" when missing; the text itself when unreadable)."""
    if not iso:
        return ""
    from datetime import datetime

    try:
        moment = datetime.fromisoformat(str(iso).replace("Z", "+00:00"))
    except ValueError:
        return str(iso)
    if moment.tzinfo is not None:
        moment = moment.astimezone()
    return f"{moment.day} {moment:%b %Y, %H:%M}"


def calibration_warnings(doc: dict) -> tuple[list[str], list[str]]:
    """``(warnings, notes)`` of a calibration document: an angle held because the views do not
    determine it is a note about the fit (shown grey), the rest are warnings (shown red)."""
    held = {h.get("reason") for h in ((doc.get("observability") or {}).get("held") or [])}
    every = list(doc.get("warnings") or [])
    return [w for w in every if w not in held], [w for w in every if w in held]


def number_of(param: Param, name: str) -> Number:
    """The rules of the described number ``name`` that an editor is built from (RuntimeError when its
    description has none: the descriptions are the program's own tables, so that is a programming error)."""
    if param.number is None:
        raise RuntimeError(f"{name} is described without a number, but its editor needs one")
    return param.number


def bounds_of(param: Param, name: str) -> tuple[float, float]:
    """Both ends of the described number ``name``'s range, which its spin box needs (RuntimeError when
    the description leaves one open, as :func:`number_of`)."""
    number = number_of(param, name)
    if number.low is None or number.high is None:
        raise RuntimeError(f"{name} is described without both ends of its range, but its spin box needs them")
    return number.low, number.high


#: room left around a dialog for the window manager's frame and title bar
DIALOG_FRAME_PX = QSize(16, 48)


def screen_fitted(widget: QWidget, width_px: int, height_px: int) -> QSize:
    """The size ``width_px`` x ``height_px`` made no larger than the free room of the screen the widget
    (or its parent window) is on, frame included: a dialog opened on a 1366 x 768 laptop fits it."""
    screen = widget.screen() or QGuiApplication.primaryScreen()
    if screen is None:
        return QSize(width_px, height_px)
    free = screen.availableGeometry()
    return QSize(min(width_px, free.width() - DIALOG_FRAME_PX.width()),
                 min(height_px, free.height() - DIALOG_FRAME_PX.height()))


def set_progress_async(bar: QProgressBar, value: int, maximum: int | None = None) -> None:
    """Set a progress bar without the synchronous repaint ``QProgressBar.setValue`` does.

    That repaint flushes every pending paint of the window on the spot (e.g. a busy grid view),
    which stalls the GUI thread; with updates off it becomes an ordinary, coalesced update."""
    bar.setUpdatesEnabled(False)
    try:
        if maximum is not None and bar.maximum() != maximum:
            bar.setRange(0, maximum)
        bar.setValue(value)
    finally:
        bar.setUpdatesEnabled(True)
    bar.update()


def elide_to_width(text: str, metrics, width_px: int, lines: int = 1) -> tuple[str, str]:
    """``(shown, tooltip)``: ``text`` itself when it fits one line of ``width_px`` (or spans several
    lines, or the width is not known yet), else its plain words elided with "…" and the whole plain
    text as the tooltip, so no line is ever cut off mid-word without a sign."""
    if width_px <= 0 or not text:
        return text, ""
    plain = QTextDocumentFragment.fromHtml(text).toPlainText() if "<" in text else text
    room = width_px - 2
    if lines > 1:
        return _elide_lines(text, plain, metrics, room, lines)
    if metrics.horizontalAdvance(plain) <= room:
        return text, ""
    return metrics.elidedText(plain, Qt.TextElideMode.ElideRight, room), plain


def _wrapped_height(metrics, text: str, width_px: int) -> int:
    flags = int(Qt.TextFlag.TextWordWrap.value) | int(Qt.AlignmentFlag.AlignLeft.value)
    return metrics.boundingRect(0, 0, width_px, 1_000_000, flags, text).height()


def _elide_lines(text: str, plain: str, metrics, room: int, lines: int) -> tuple[str, str]:
    """``text`` when it wraps into ``lines`` lines of ``room`` px, else the longest start of its plain
    words that does, ending in "…" (the whole plain text as the tooltip): a third line is never cut
    through the middle of its letters."""
    most = lines * metrics.lineSpacing() + 1
    if _wrapped_height(metrics, plain, room) <= most:
        return text, ""
    words = plain.split()
    lo, hi = 0, len(words)                       # the longest prefix of words that fits with "…"
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if _wrapped_height(metrics, " ".join(words[:mid]) + " …", room) <= most:
            lo = mid
        else:
            hi = mid - 1
    if lo == 0:
        return metrics.elidedText(plain, Qt.TextElideMode.ElideRight, room), plain
    return " ".join(words[:lo]) + " …", plain


class ElidedLabel(QLabel):
    """A one-line label that never asks for the width of its text (it cannot widen a window) and,
    when narrower than its text, shows it elided with "…" (the whole text in the tooltip)."""

    def __init__(self, text: str = "", parent: QWidget | None = None):
        super().__init__(parent)
        self._full = ""
        self.setMinimumWidth(8)
        self.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)
        self.setText(text)

    def setText(self, text: str) -> None:   # noqa: N802 (QLabel's name)
        self._full = text
        shown, tip = elide_to_width(text, self.fontMetrics(), self.contentsRect().width())
        super().setText(shown)
        self.setToolTip(tip)

    def full_text(self) -> str:
        return self._full

    def resizeEvent(self, event) -> None:   # noqa: N802 (Qt name)
        super().resizeEvent(event)
        self.setText(self._full)


class WholeOrNothingLabel(QLabel):
    """A one-line label that gives way when room is short (it never widens a window) and then shows
    nothing rather than a cut-off part of its text (a legend: its tooltip says the same)."""

    def __init__(self, text: str = "", parent: QWidget | None = None):
        super().__init__(text, parent)
        self.setMinimumWidth(0)
        self.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)

    def is_whole(self) -> bool:
        return self.contentsRect().width() >= super().sizeHint().width() - 2 * self.margin()

    def paintEvent(self, event) -> None:   # noqa: N802 (Qt name)
        if self.is_whole():
            super().paintEvent(event)


def show_lock_note(note: QLabel, tips: list[tuple[QWidget | QAction, str]], reason: str, text: str) -> None:
    """A device taken by a scan (``reason`` not empty): ``note`` shows ``text`` and each control's
    tooltip (``tips``: the control and its own tooltip) ends with ``reason``; an empty ``reason``
    hides the note and gives every control its own tooltip back."""
    note.setText(text if reason else "")
    note.setVisible(bool(reason))
    for widget, tip in tips:
        widget.setToolTip(f"{tip}\n\n{reason}" if reason else tip)


def tab_after(anchor: QWidget, widget: QWidget) -> None:
    """Put the fields of ``widget`` (made after the rest of its window, e.g. a form built when first
    needed: Qt appends a widget's fields to the end of the tab order when it is added) right after
    ``anchor`` in the tab order, in the order they were made, the widgets that followed ``anchor``
    after them."""
    fields = [w for w in widget.findChildren(QWidget)
              if w.focusPolicy() & Qt.FocusPolicy.TabFocus and w.focusProxy() is None
              and w.window() is anchor.window()]             # not a combo box's popup list
    before = anchor
    for field in fields:
        QWidget.setTabOrder(before, field)
        before = field


def add_stop_button(dialog: QWidget, layout) -> QPushButton | None:
    """The main window's STOP (the action of its ``stopToolButton``) as a button at the top of a dialog big
    enough to cover the window's STOP toolbar (at 1366 x 768 the Process, Depth, Radiance, Export and
    calibration dialogs do): STOP stays in sight whatever window is in front. (Esc in a dialog closes the
    dialog, hence no "(Esc)" here.) ``layout``: the dialog's column (the button gets a row of its own on
    top) or one of its rows (the button first in it, for a dialog with no height to spare). None when the
    dialog has no such window above it."""
    top = dialog.parentWidget()
    while top is not None and top.parentWidget() is not None:
        top = top.parentWidget()
    window_stop = top.findChild(QToolButton, "stopToolButton") if top is not None else None
    if window_stop is None or window_stop.defaultAction() is None:
        return None
    action = window_stop.defaultAction()
    button = QPushButton("STOP all motion", dialog)
    button.setObjectName("dialogStopButton")
    button.setAutoDefault(False)
    button.setToolTip(window_stop.toolTip())
    button.setStyleSheet("QPushButton { color: white; background: #c62828; font-weight: bold; padding: 3px 12px; "
                         "border-radius: 3px; } QPushButton:disabled { background: #999; }")
    button.clicked.connect(action.trigger)
    button.setEnabled(action.isEnabled())
    action.changed.connect(lambda: button.setEnabled(action.isEnabled()))
    if isinstance(layout, QHBoxLayout):       # a row of the dialog's own (no height added): first in it
        layout.insertWidget(0, button)
        return button
    row = QHBoxLayout()
    row.setContentsMargins(0, 0, 0, 0)
    row.addStretch(1)
    row.addWidget(button)
    layout.insertLayout(0, row)
    return button


class PageStack(QWidget):
    """A stack of pages, one shown, that takes the room of the shown page only. QStackedWidget's
    layout answers the height for a width with the largest of all its pages (QStackedLayout::
    heightForWidth asks every page, shown or not): a short page (the Camera panel's gphoto2 text)
    stood above a gap as tall as the tallest word-wrapped page in the stack. Here the pages sit in
    a box layout and all but the current one are hidden, so the layout sees the current one only."""

    currentChanged = Signal(int)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self._pages: list[QWidget] = []
        self._current = -1
        self._box = QVBoxLayout(self)
        self._box.setContentsMargins(0, 0, 0, 0)

    def addWidget(self, page: QWidget) -> int:
        self._pages.append(page)
        self._box.addWidget(page)
        if self._current < 0:
            self.setCurrentIndex(0)
        else:
            page.setVisible(False)
        return len(self._pages) - 1

    def count(self) -> int:
        return len(self._pages)

    def widget(self, index: int) -> QWidget | None:
        return self._pages[index] if 0 <= index < len(self._pages) else None

    def indexOf(self, page: QWidget) -> int:
        return self._pages.index(page) if page in self._pages else -1

    def currentIndex(self) -> int:
        return self._current

    def currentWidget(self) -> QWidget | None:
        return self.widget(self._current)

    def setCurrentWidget(self, page: QWidget) -> None:
        self.setCurrentIndex(self.indexOf(page))

    def setCurrentIndex(self, index: int) -> None:
        if not 0 <= index < len(self._pages) or index == self._current:
            return
        self._current = index
        for i, page in enumerate(self._pages):
            page.setVisible(i == index)
        self.updateGeometry()
        self.currentChanged.emit(index)


class WheelGuard(QObject):
    """Spin boxes and combo boxes take the mouse wheel only when they have keyboard focus.

    Without focus the wheel goes on to what contains them (a scroll area scrolls), so scrolling a
    long form never changes a value the pointer happens to pass over; the wheel does not give them
    focus either (``Qt.WheelFocus`` becomes ``Qt.StrongFocus``: click or Tab first).

    It watches each top-level window (:func:`install_wheel_guard`), where every wheel turn arrives
    before Qt hands it to the widget under the pointer, and guards that widget the first time: from
    then on it filters the widget's own events. Not an application-wide filter: that called Python,
    and so took the GIL, for every one of the GUI thread's thousands of events a second, each wait for
    the GIL a stall while other threads run Python."""

    GUARDED = (QAbstractSpinBox, QComboBox)

    def __init__(self, parent: QObject | None = None):
        super().__init__(parent)
        self.looked_at = 0      # events this filter was called for (each a Python call on the GUI thread)

    def eventFilter(self, obj: QObject, event: QEvent) -> bool:   # noqa: N802 (Qt name)
        self.looked_at += 1
        if event.type() != QEvent.Type.Wheel or not isinstance(event, QWheelEvent):
            return False
        if isinstance(obj, QWindow):
            target = self._widget_under(obj, event.globalPosition().toPoint())
            while target is not None and not isinstance(target, self.GUARDED) and not target.isWindow():
                target = target.parentWidget()
            if isinstance(target, self.GUARDED):
                self.guard(target)          # before Qt delivers this wheel turn to it
            return False
        if isinstance(obj, self.GUARDED) and not obj.hasFocus():
            event.ignore()   # handled here, not accepted: Qt passes it on to the parent widgets
            return True
        return False

    def guard(self, widget: QWidget) -> None:
        if widget.focusPolicy() == Qt.FocusPolicy.WheelFocus:
            widget.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
        widget.installEventFilter(self)     # (installing it again only moves it to the front)

    def watch_windows(self) -> None:
        """Watch every top-level window there is (again: a window is watched once, however often)."""
        for window in QGuiApplication.topLevelWindows():
            window.installEventFilter(self)

    @staticmethod
    def _widget_under(window: QWindow, global_pos) -> QWidget | None:
        for top in QApplication.topLevelWidgets():
            if top.windowHandle() is window:
                return top.childAt(top.mapFromGlobal(global_pos)) or top
        return None


def install_wheel_guard(app: QApplication | None = None) -> WheelGuard:
    """Install the :class:`WheelGuard` (once; later calls return the same one): on the windows there
    are now and on every window that becomes active later (a new window is activated when shown)."""
    if app is None:
        instance = QApplication.instance()
        if not isinstance(instance, QApplication):
            raise RuntimeError("the wheel guard needs the QApplication: make it first")
        app = instance
    guard = app.findChild(WheelGuard, "wheelGuard")
    if guard is None:
        guard = WheelGuard(app)
        guard.setObjectName("wheelGuard")
        app.focusWindowChanged.connect(lambda: guard.watch_windows())   # (not the window: it may be closing)
    guard.watch_windows()
    return guard


class QuietLabel(QWidget):
    """A label whose text changes many times a second (a running scan's current view, ETA, counts)
    without re-laying out the window.

    ``QLabel.setText`` calls ``updateGeometry()``, and every layout it invalidates calls it again on
    its own widget, so each new text re-lays out the panel, its dock and the main window (whose
    animated docks make new QPropertyAnimations each time), and calls Python for every panel on the
    way. Here the QLabel (``label``, with the ``name`` given) sits in a widget without a layout whose
    size never depends on the text: a new text repaints the line (filled, so the panels under it are
    not repainted too), nothing else. The widget is ``lines`` lines high (word-wrapped when more than
    one) and as wide as the layout gives it; its size hint is the width of ``hint_text`` (default:
    the first text) and at least ``min_width_px``. With ``every_ms`` a new text is shown at most that
    often (the latest one; :meth:`text` returns it at once)."""

    def __init__(self, text: str = "", name: str = "", lines: int = 1, hint_text: str | None = None,
                 min_width_px: int = 8, every_ms: int = 0, parent: QWidget | None = None):
        super().__init__(parent)
        self.every_ms = every_ms
        self._pending: str | None = None
        self._pacer = Pacer(self._show_pending, every_ms, self)
        self.setAutoFillBackground(True)
        self.label = QLabel(text, self)
        if name:
            self.label.setObjectName(name)
            self.setObjectName(f"{name}Line")
        self._full, self._lines = text, lines
        self.label.setWordWrap(lines > 1)
        self.label.setAlignment(Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignTop if lines > 1 else Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignVCenter)
        metrics = self.label.fontMetrics()
        height = lines * metrics.lineSpacing() + (4 if lines > 1 else 2)
        self._hint = QSize(max(min_width_px, metrics.horizontalAdvance(text if hint_text is None else hint_text)),
                           height)
        self.setFixedHeight(height)
        self.setMinimumWidth(min_width_px)
        self.setSizePolicy(QSizePolicy.Policy.Preferred, QSizePolicy.Policy.Fixed)

    def setText(self, text: str) -> None:   # noqa: N802 (QLabel's name)
        if not self.every_ms:
            self._show(text)
            return
        self._pending = text
        self._pacer.request()

    def text(self) -> str:
        return self._pending if self._pending is not None else self._full

    def shown_text(self) -> str:
        """The text on screen: the whole text, or (one line too narrow for it) its plain words elided
        with "…" (the whole text is then the tooltip)."""
        return self.label.text()

    def _show_pending(self) -> None:
        text, self._pending = self._pending, None
        if text is not None:
            self._show(text)

    def _show(self, text: str) -> None:
        self._full = text
        shown, tip = elide_to_width(text, self.label.fontMetrics(), self.width(), self._lines)
        self.label.setText(shown)
        self.label.setToolTip(tip)

    def sizeHint(self) -> QSize:   # noqa: N802 (Qt name)
        return self._hint

    def resizeEvent(self, event) -> None:   # noqa: N802 (Qt name)
        self.label.setFixedSize(self.size())     # fixed: its updateGeometry() on a new text does nothing
        self._show(self._full)


def confirm_cancel_running(parent: QWidget, runner, title: str, question: str) -> bool:
    """For a dialog's ``done()``: True when it may close — no job runs, or the operator said Yes to
    ``question`` and the job has been asked to cancel."""
    if not runner.running:
        return True
    if QMessageBox.question(parent, title, question) != QMessageBox.StandardButton.Yes:
        return False
    runner.cancel()
    return True


class JobProgressWidget(QWidget):
    """Progress bar + ETA + Cancel for a :class:`lfstudio.gui.bridge.JobRunner` (reset by its ``started``).

    The ETA counts down every second between progress reports (a slow item does not freeze it) and
    turns to "–" when the estimate has passed and the job still runs; when the job ends it gives way to how long the job took, or to "cancelled" / "failed"."""

    def __init__(self, runner, parent: QWidget | None = None):
        super().__init__(parent)
        self.runner = runner
        self.bar = QProgressBar()
        self.bar.setTextVisible(True)
        self.eta_label = QLabel("ETA –")
        self.eta_label.setMinimumWidth(110)
        self.message_label = ElidedLabel("")     # a long message never widens the dialog or panel
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setToolTip("Stop the running job at the next safe point")
        self.cancel_button.setEnabled(False)
        lay = QHBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.bar, 3)
        lay.addWidget(self.eta_label)
        lay.addWidget(self.message_label, 2)
        lay.addWidget(self.cancel_button)
        self.cancel_button.clicked.connect(self._cancel)
        self._started_at = 0.0
        self._eta_at: float | None = None     # time.monotonic() when the job should end, if known
        self._tick = QTimer(self)
        self._tick.setInterval(1000)
        self._tick.timeout.connect(self._show_eta)
        runner.started.connect(self.started)
        runner.progress.connect(self._on_progress)
        runner.finished.connect(lambda _result: self._on_end(f"took {format_duration(self._elapsed_s())}"))
        runner.failed.connect(lambda _message: self._on_end("failed"))
        runner.cancelled.connect(lambda: self._on_end("cancelled", "Cancelled"))

    def started(self) -> None:
        self.bar.setRange(0, 0)
        self._started_at, self._eta_at = time.monotonic(), None
        self.eta_label.setText("ETA –")
        self.message_label.setText("")
        self.cancel_button.setEnabled(True)
        self._tick.start()

    def _elapsed_s(self) -> float:
        return time.monotonic() - self._started_at

    def _cancel(self) -> None:
        self.cancel_button.setEnabled(False)
        self.message_label.setText("Cancelling…")
        self.runner.cancel()

    def _on_progress(self, done: int, total: int, message: str, eta_s: float) -> None:
        set_progress_async(self.bar, done, max(total, 1))
        self._eta_at = None if eta_s < 0 else time.monotonic() + eta_s
        self._show_eta()
        if self.cancel_button.isEnabled():     # keep "Cancelling…" until the job stops
            self.message_label.setText(message)

    def _show_eta(self) -> None:
        left = None if self._eta_at is None else self._eta_at - time.monotonic()
        if left is not None and left < -0.5:
            left = None             # past the estimate and still working: unknown, not "0 s"
        self.eta_label.setText(f"ETA {format_duration(None if left is None else max(0.0, left))}")

    def _on_end(self, outcome: str, message: str | None = None) -> None:
        self._tick.stop()
        self._eta_at = None
        self.eta_label.setText(outcome)
        if message is not None:
            self.message_label.setText(message)
        self.cancel_button.setEnabled(False)
        if self.bar.maximum() == 0:
            self.bar.setRange(0, 1)


class GridPicker(QWidget):
    """The capture grid as cells; click a captured view to add it to / remove it from the selection.

    ``cellClicked(row, column)`` is emitted for every click on a captured view; with
    ``toggle_on_click=False`` the selection is left to the owner (e.g. "click sets the centre").
    ``marked`` (a view or None) is drawn with a dark outline.
    """

    selectionChanged = Signal()
    cellClicked = Signal(int, int)

    def __init__(self, columns: int, rows: int, available: set[tuple[int, int]], parent: QWidget | None = None,
                 tooltip: str = "Click captured views (grey) to select or deselect them; blue = used for calibration"):
        super().__init__(parent)
        self.columns, self.rows = max(1, columns), max(1, rows)
        self.available = set(available)
        self.selected: set[tuple[int, int]] = set()
        self.marked: tuple[int, int] | None = None
        self.toggle_on_click = True
        self.base_tooltip = tooltip
        self.setMinimumSize(300, 120)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.setToolTip(tooltip)
        self.setMouseTracking(True)

    def sizeHint(self) -> QSize:
        return QSize(min(900, 12 * self.columns + 40), min(420, 16 * self.rows + 40))

    def set_selected(self, views) -> None:
        self.selected = {v for v in views if v in self.available}
        self.update()
        self.selectionChanged.emit()

    def _geometry(self) -> tuple[float, float, float]:
        margin = 28.0
        cell = min((self.width() - margin - 6) / self.columns, (self.height() - margin - 6) / self.rows)
        return max(cell, 1.0), margin, margin

    def cell_at(self, pos) -> tuple[int, int] | None:
        cell, x0, y0 = self._geometry()
        c, r = int((pos.x() - x0) // cell), int((pos.y() - y0) // cell)
        if 0 <= r < self.rows and 0 <= c < self.columns:
            return r, c
        return None

    def cell_center(self, row: int, column: int) -> QPointF:
        """Where the cell of (row, column) is drawn (widget coordinates), e.g. to click it in a test."""
        cell, x0, y0 = self._geometry()
        return QPointF(x0 + (column + 0.5) * cell, y0 + (row + 0.5) * cell)

    def mousePressEvent(self, event) -> None:
        v = self.cell_at(event.position())
        if v is not None and v in self.available:
            if self.toggle_on_click:
                self.selected ^= {v}
                self.update()
                self.selectionChanged.emit()
            self.cellClicked.emit(*v)

    def mouseMoveEvent(self, event) -> None:
        v = self.cell_at(event.position())
        self.setToolTip(f"{view_stem(*v)}{'' if v in self.available else ' (not captured)'}" if v else
                        self.base_tooltip)

    def paintEvent(self, event) -> None:
        p = QPainter(self)
        p.fillRect(self.rect(), self.palette().window())
        cell, x0, y0 = self._geometry()
        gap = 1.0 if cell > 4 else 0.0
        for r in range(self.rows):
            for c in range(self.columns):
                v = (r, c)
                color = QColor(40, 110, 220) if v in self.selected else \
                    QColor(185, 185, 185) if v in self.available else QColor(245, 245, 245)
                p.fillRect(QRectF(x0 + c * cell, y0 + r * cell, cell - gap, cell - gap), color)
        if self.marked is not None:
            r, c = self.marked
            p.setPen(QPen(QColor(20, 20, 20), 2.0))
            p.drawRect(QRectF(x0 + c * cell + 1, y0 + r * cell + 1, cell - gap - 2, cell - gap - 2))
        p.setPen(QPen(QColor(90, 90, 90)))
        f = QFont(self.font())
        f.setPointSizeF(max(7.0, f.pointSizeF() - 1))
        p.setFont(f)
        step_c = max(1, int(np.ceil(40 / cell)))
        for c in range(0, self.columns, step_c):
            p.drawText(QPointF(x0 + c * cell, y0 - 6), str(c))
        step_r = max(1, int(np.ceil(16 / cell)))
        for r in range(0, self.rows, step_r):
            p.drawText(QPointF(2, y0 + r * cell + min(cell, 14) - 2), str(r))
        p.end()


class FitImageView(QScrollArea):
    """A picture shown whole, scaled to the room (``fit``, the default), or at its own size with
    scroll bars (1:1). :meth:`pixmap` is the picture at its own size; ``label`` shows it (named
    ``name``); :meth:`fit_button` makes a checkable Fit button that switches the two."""

    def __init__(self, name: str = "", parent: QWidget | None = None):
        super().__init__(parent)
        self.label = QLabel()
        if name:
            self.label.setObjectName(name)
            self.setObjectName(f"{name}View")
        self.label.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.setWidget(self.label)
        self._pixmap = QPixmap()
        self._fitted: QPixmap | None = None
        self.fit = True
        self._set_mode()

    def pixmap(self) -> QPixmap:
        return self._pixmap

    def set_pixmap(self, pixmap: QPixmap, fitted: QPixmap | None = None) -> None:
        """Show ``pixmap``. ``fitted``: the same picture already scaled to :meth:`fitted_size` (made
        off the GUI thread), used while it fits the room; else the view scales it itself."""
        self._pixmap = pixmap
        self._fitted = fitted
        self._show()

    def fitted_size(self, size: QSize) -> QSize:
        """The size a picture of ``size`` is shown at when fitted to the room now."""
        return size.scaled(self.viewport().size(), Qt.AspectRatioMode.KeepAspectRatio)

    def clear(self) -> None:
        self._pixmap = QPixmap()
        self._fitted = None
        self.label.clear()

    def setText(self, text: str) -> None:   # noqa: N802 (QLabel's name)
        self.clear()
        self.label.setText(text)

    def set_fit(self, fit: bool) -> None:
        self.fit = bool(fit)
        self._set_mode()
        self._show()

    def fit_button(self, parent: QWidget | None = None) -> QPushButton:
        button = QPushButton("Fit", parent)
        button.setObjectName(f"{self.label.objectName() or 'image'}FitButton")
        button.setCheckable(True)
        button.setChecked(self.fit)
        button.setToolTip("Fit: the whole picture in the window (its colour bar too); off: 1:1, each pixel "
                          "of the map on a screen pixel, with scroll bars")
        button.toggled.connect(self.set_fit)
        return button

    def _set_mode(self) -> None:
        self.setWidgetResizable(self.fit)
        policy = QSizePolicy.Policy.Ignored if self.fit else QSizePolicy.Policy.Preferred
        self.label.setSizePolicy(policy, policy)

    def _show(self) -> None:
        if self._pixmap.isNull():
            return
        if self.fit:
            room = self.viewport().size()
            if room.width() < 2 or room.height() < 2:
                return
            fitted = self._fitted
            if fitted is not None and fitted.size() == self.fitted_size(self._pixmap.size()):
                self.label.setPixmap(fitted)
                return
            self.label.setPixmap(self._pixmap.scaled(room, Qt.AspectRatioMode.KeepAspectRatio,
                                                     Qt.TransformationMode.SmoothTransformation))
        else:
            self.label.setPixmap(self._pixmap)
            self.label.adjustSize()

    def shown_size(self) -> QSize:
        """The size the picture has on the screen now."""
        shown = self.label.pixmap()
        return QSize(0, 0) if shown is None or shown.isNull() else shown.size()

    def resizeEvent(self, event) -> None:   # noqa: N802 (Qt name)
        super().resizeEvent(event)
        if self.fit:
            self._show()


class ColourBar(QWidget):
    """A false-colour map's key at screen resolution (TURBO, near = red, as
    :func:`lfstudio.quality.pictures.disparity_picture` paints): the colours from ``lo`` to ``hi`` px
    with five ticks labelled in px and, with ``depth_scale_m_px`` (depth = scale / disparity), in m;
    ``title`` on the left names what the values are (and their reference)."""

    TICKS = (0.0, 0.25, 0.5, 0.75, 1.0)

    def __init__(self, name: str = "", parent: QWidget | None = None):
        super().__init__(parent)
        if name:
            self.setObjectName(name)
        self.range_px: tuple[float, float] | None = None
        self.depth_scale_m_px: float | None = None
        self.title = ""
        self._colours: list[QColor] = []
        lines = 3
        self.setMinimumHeight(14 + 6 + lines * self.fontMetrics().height() + 4)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Fixed)

    def set_range(self, lo: float, hi: float, depth_scale_m_px: float | None = None, title: str = "") -> None:
        self.range_px, self.depth_scale_m_px, self.title = (float(lo), float(hi)), depth_scale_m_px, title
        self.setToolTip(title)
        self.update()

    def labels(self) -> list[str]:
        """The tick labels, left to right (px, and m when a depth scale is set)."""
        if self.range_px is None:
            return []
        lo, hi = self.range_px
        out = []
        for t in self.TICKS:
            v = lo + t * (hi - lo)
            text = f"{v:.2f} px"
            if self.depth_scale_m_px and v > 0:
                text += f"\n{self.depth_scale_m_px / v:.2f} m"
            out.append(text)
        return out

    def _lut(self) -> list[QColor]:
        if not self._colours:
            import cv2

            lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8).reshape(1, -1), cv2.COLORMAP_TURBO)[0]
            self._colours = [QColor(int(r), int(g), int(b)) for b, g, r in lut]
        return self._colours

    def paintEvent(self, event) -> None:   # noqa: N802 (Qt name)
        if self.range_px is None:
            return
        p = QPainter(self)
        fm = p.fontMetrics()
        left, right = 8, self.width() - 8
        width = max(1, right - left)
        colours = self._lut()
        for x in range(width):
            p.fillRect(left + x, 2, 1, 14, colours[min(255, x * 256 // width)])
        p.setPen(QColor("#30343a"))
        texts = self.labels()
        for t, text in zip(self.TICKS, texts):
            x = left + round(t * (width - 1))
            p.drawLine(x, 17, x, 21)
            lines = text.split("\n")
            w = max(fm.horizontalAdvance(line) for line in lines)
            x0 = min(max(0, x - w // 2), self.width() - w)
            for i, line in enumerate(lines):
                p.drawText(x0, 24 + fm.ascent() + i * fm.height(), line)
        p.end()
