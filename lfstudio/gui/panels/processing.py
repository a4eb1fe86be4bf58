"""The Processing panel: what has been processed in the open dataset, and Dataset → Process…."""

from __future__ import annotations

import numpy as np
from PySide6.QtGui import QAction, QKeySequence
from PySide6.QtWidgets import QLabel, QPushButton, QVBoxLayout, QWidget

from lfstudio.dataset.manifest import processed_status


class ProcessingPanel(QWidget):
    def __init__(self, state, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.dialog = None
        self.summary = QLabel()
        self.summary.setObjectName("processingSummary")
        self.summary.setWordWrap(True)
        self.button = QPushButton("Process…")
        self.button.setToolTip("Open the processing dialog: profile, preview, run (Dataset → Process…)")
        self.button.clicked.connect(self.open_dialog)
        lay = QVBoxLayout(self)
        lay.addWidget(self.summary)
        lay.addWidget(self.button)
        lay.addStretch(1)
        self.action = QAction("&Process…", self)
        self.action.setShortcut(QKeySequence("Ctrl+Shift+P"))
        self.action.setToolTip("RAW captures → rectified 16-bit views (debayer, lens, colour, shading, "
                               "de-flicker, rectification, downsampling)")
        self.action.setStatusTip(self.action.toolTip())
        self.action.triggered.connect(self.open_dialog)
        state.datasetChanged.connect(self._refresh)
        self._refresh(state.dataset)

    def install_menus(self, window) -> None:
        menu = window.menu("Dataset")
        menu.addAction(self.action)

    def _refresh(self, ds) -> None:
        self.action.setEnabled(ds is not None)
        self.button.setEnabled(ds is not None)
        if ds is None:
            self.summary.setText("No dataset open. Open or scan a dataset, then process its views.")
            return
        views = ds.done_views()
        done = [v["processed"] for v in views if processed_status(v) == "done"]
        failed = sum(1 for v in views if processed_status(v) == "failed")
        text = f"<b>{len(done)}</b> of {len(views)} captured views processed"
        if failed:
            text += f", <span style='color:#c00'>{failed} failed</span>"
        if done:
            gains = np.array([d.get("gain", 1.0) for d in done])
            text += f"<br>de-flicker gains {gains.min():.3f} … {gains.max():.3f}"
            run = ds.manifest.get("processing") or {}
            if run.get("output_size_px"):
                w, h = run["output_size_px"]
                text += f"<br>output {w} × {h} px, {'rectified' if run.get('rectified') else 'not rectified'}"
        self.summary.setText(text)

    def open_dialog(self) -> None:
        if self.state.dataset is None:
            self.state.report_error("Process", "No dataset is open: open a dataset folder first (File → Open dataset…)")
            return
        from lfstudio.gui.dialogs.process_dialog import ProcessDialog

        if self.dialog is not None and self.dialog.isVisible():
            self.dialog.raise_()
            return
        self.dialog = ProcessDialog(self.state, self.window())
        self.dialog.open()

    def shutdown(self) -> None:
        if self.dialog is not None and self.dialog.runner.running:
            self.dialog.runner.cancel()
            self.dialog.runner.wait(30)
