"""Central placeholder shown until a dataset is open."""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QLabel, QVBoxLayout, QWidget


class WelcomeView(QWidget):
    def __init__(self, state, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        label = QLabel(
            "<h2>lfstudio</h2>"
            "<p>1. <b>Plan</b> the scene in the Planner panel.<br>"
            "2. <b>Connect</b> the rig and camera (the simulated studio is ready).<br>"
            "3. <b>Scan</b>, then <b>calibrate</b>, <b>process</b> and <b>export</b> from the Dataset menu.</p>"
            "<p>File → Open dataset… opens an existing capture.</p>")
        label.setAlignment(Qt.AlignmentFlag.AlignCenter)
        label.setObjectName("welcomeText")
        lay = QVBoxLayout(self)
        lay.addWidget(label)
