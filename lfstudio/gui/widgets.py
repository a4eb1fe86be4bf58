"""Small reusable widgets."""

from __future__ import annotations

from PySide6.QtWidgets import QHBoxLayout, QLabel, QProgressBar, QPushButton, QWidget

from lfstudio.jobs import format_duration


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


class JobProgressWidget(QWidget):
    """Progress bar + ETA + Cancel for a :class:`lfstudio.gui.bridge.JobRunner`."""

    def __init__(self, runner, parent: QWidget | None = None):
        super().__init__(parent)
        self.runner = runner
        self.bar = QProgressBar()
        self.bar.setTextVisible(True)
        self.eta_label = QLabel("ETA –")
        self.eta_label.setMinimumWidth(110)
        self.message_label = QLabel("")
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
        runner.progress.connect(self._on_progress)
        for sig in (runner.finished, runner.failed, runner.cancelled):
            sig.connect(self._on_end)

    def started(self) -> None:
        self.bar.setRange(0, 0)
        self.eta_label.setText("ETA –")
        self.cancel_button.setEnabled(True)

    def _cancel(self) -> None:
        self.cancel_button.setEnabled(False)
        self.message_label.setText("Cancelling…")
        self.runner.cancel()

    def _on_progress(self, done: int, total: int, message: str, eta_s: float) -> None:
        set_progress_async(self.bar, done, max(total, 1))
        self.eta_label.setText(f"ETA {format_duration(None if eta_s < 0 else eta_s)}")
        self.message_label.setText(message)

    def _on_end(self, *args) -> None:
        self.cancel_button.setEnabled(False)
        if self.bar.maximum() == 0:
            self.bar.setRange(0, 1)
