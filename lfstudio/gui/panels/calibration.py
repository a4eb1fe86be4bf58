"""The Calibration panel: the open dataset's calibration at a glance (angles with their 1σ, the error
at the image corners, warnings), and Dataset → Calibrate…. Reads ``calibration.json`` through
:mod:`lfstudio.calibration.model` only (JSON; no scipy/OpenCV import on the GUI thread)."""

from __future__ import annotations

from PySide6.QtGui import QAction, QKeySequence
from PySide6.QtWidgets import QLabel, QPushButton, QVBoxLayout, QWidget

from lfstudio.errors import LfError, window_message
from lfstudio.gui.widgets import calibration_warnings, readable_time
from lfstudio.jobs import count


class CalibrationPanel(QWidget):
    def __init__(self, state, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.wizard = None
        self.action: QAction | None = None      # Dataset → Calibrate…, made in install_menus
        self.summary = QLabel()
        self.summary.setWordWrap(True)
        self.summary.setObjectName("calibrationSummary")
        self.button = QPushButton("Calibrate…")
        self.button.setToolTip("Self-calibrate the camera orientation from this dataset's images (Ctrl+Shift+C)")
        self.button.clicked.connect(self.open_wizard)
        lay = QVBoxLayout(self)
        lay.addWidget(self.summary)
        lay.addWidget(self.button)
        lay.addStretch(1)
        state.datasetChanged.connect(self.refresh)
        self.refresh(state.dataset)

    def install_menus(self, window) -> None:
        self.action = QAction("&Calibrate…", window)
        self.action.setObjectName("actionCalibrate")
        self.action.setShortcut(QKeySequence("Ctrl+Shift+C"))
        self.action.setToolTip("Self-calibrate the camera orientation from the open dataset's images; "
                               "inspect residuals and EPIs, then save calibration.json")
        self.action.setStatusTip(self.action.toolTip())
        self.action.triggered.connect(self.open_wizard)
        window.menu("Dataset").addAction(self.action)
        self.action.setEnabled(self.state.dataset is not None)

    def refresh(self, dataset=None) -> None:
        dataset = self.state.dataset
        enabled = dataset is not None
        self.button.setEnabled(enabled)
        if self.action is not None:
            self.action.setEnabled(enabled)
        if dataset is None:
            self.summary.setText("No dataset open. Open or capture one, then calibrate it.")
            return
        from lfstudio.calibration.model import CalibrationUncertainty, load_calibration
        try:
            doc = load_calibration(dataset)
            if doc is not None:
                rx, ry, rz = doc["rotation_deg"]
                after, before = doc["residual_px"]["after"], doc["residual_px"]["before"]
        except LfError as exc:
            self.summary.setText(f"calibration.json is unreadable: {exc}")
            return
        except (KeyError, TypeError, ValueError) as exc:
            self.summary.setText(f"calibration.json is incomplete ({exc}); calibrate again")
            return
        if doc is None:
            self.summary.setText("<b>Not calibrated yet.</b> Views will not be rectified until you calibrate.")
            return
        u = CalibrationUncertainty.from_document(doc)
        if u is not None:
            from lfstudio.calibration.model import held_angles
            held = held_angles(doc)
            angles = "<br>".join(f"{key} {value:+.3f}° held (not determined by these views)" if key in held
                                 else f"{key} {value:+.3f}° ± {sd:.3f}°"
                                 for key, value, sd in zip(("rx", "ry", "rz"), (rx, ry, rz), u.rotation_std_deg)) \
                + " (1σ)"
        else:
            angles = f"rx {rx:+.3f}° ry {ry:+.3f}° rz {rz:+.3f}°"
        corners = ""
        if u is not None and u.corner_error_px:
            corners = (f"<br>at the image corners ≤ {u.corner_error_px[0]:.2f} px (1σ), "
                       f"≤ {u.corner_error_px[1]:.2f} px (2σ)")
        from lfstudio.calibration.model import rectification_decision, rotation_applied
        decided = rectification_decision(doc)
        if decided:          # short here (a narrow panel); the whole decision in the tooltip and the report
            corners += ("<br>Views rectified: the rotation is significant" if rotation_applied(doc) else
                        "<br>Views left unrotated: the rotation is not significant (every angle within 2σ of 0)")
        # an angle held because these views do not determine it is a note about the fit, not a problem
        warnings, notes = calibration_warnings(doc)
        warn = ""
        if warnings:
            warn += f"<br><span style='color:#b00020'>{count(len(warnings), 'warning')}</span>"
        if notes:
            warn += f"<br><span style='color:#5b6470'>{count(len(notes), 'note')}</span>"
        self.summary.setToolTip("\n".join([*(f"Warning: {w}" for w in warnings), *(f"Note: {n}" for n in notes),
                                           *([f"Rectification: {decided}"] if decided else [])]))
        self.summary.setText(f"<b>Calibrated</b> {readable_time(doc.get('created'))}<br>{angles}{corners}<br>"
                             f"residual RMS {before['rms']:.2f} → {after['rms']:.2f} px "
                             f"({count(len(doc.get('views_used', [])), 'view')}){warn}")

    def open_wizard(self) -> None:
        if self.state.dataset is None:
            self.state.report_error("Calibrate", "No dataset is open. Use File → Open dataset… first.")
            return
        from lfstudio.gui.dialogs.calibration_wizard import CalibrationWizard
        if self.wizard is not None and self.wizard.isVisible():
            self.wizard.raise_()
            return
        try:
            self.wizard = CalibrationWizard(self.state, self.window())
        except LfError as exc:
            self.state.report_error("Calibrate", window_message(exc))
            return
        self.wizard.show()

    def shutdown(self) -> None:
        if self.wizard is not None:
            self.wizard.shutdown()
