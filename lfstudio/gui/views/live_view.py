"""Live view dock: the camera's preview frames (or the last test shot) with zoom and pan, a
sharpness readout for focusing, and an RGB histogram with clipping warnings.

While a scan owns the camera (``AppState.scan_owns_camera``) Live is off and disabled, with a
tooltip saying why; it can be started again when the scan ends or is paused."""

from __future__ import annotations

from typing import Any

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QEvent, Qt, QTimer
from PySide6.QtGui import QAction, QKeySequence
from PySide6.QtWidgets import (QCheckBox, QHBoxLayout, QLabel, QPushButton, QSizePolicy, QSpinBox, QVBoxLayout,
                               QWidget)

from lfstudio.gui.settings import read_bool, read_int, settings
from lfstudio.gui.state import AppState
from lfstudio.rig.preview import clipping_overlay, frame_stats, histograms

CLIP_WARN_FRACTION = 0.001     # warn when more than 0.1 % of the pixels clip


class LiveView(QWidget):
    """``Live`` polls ``camera.preview()`` through the camera's device worker (never on the GUI
    thread), one frame in flight at a time. Test shots arrive through ``state.cameraFrame``."""

    def __init__(self, state: AppState, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.frame: np.ndarray | None = None
        self.caption = ""
        self.peak_sharpness = 0.0
        self.stats = None
        self._last_caption = ""
        self._in_flight = False
        self._timer = QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.timeout.connect(self._request_frame)

        self.live_button = QPushButton("Live")
        self.live_button.setCheckable(True)
        self.live_button.setToolTip("Show the camera's live preview continuously (Ctrl+L)")
        self.live_button.toggled.connect(self.set_live)
        self.fit_button = QPushButton("Fit")
        self.fit_button.setToolTip("Zoom to show the whole frame (wheel: zoom, drag: pan)")
        self.fit_button.clicked.connect(self.fit)
        self.one_button = QPushButton("1:1")
        self.one_button.setToolTip("One screen pixel per image pixel, at the centre (for focusing)")
        self.one_button.clicked.connect(self.one_to_one)
        self.clip_check = QCheckBox("Show clipping")
        self.clip_check.setToolTip("Paint blown highlights red and crushed shadows blue")
        self.clip_check.setChecked(read_bool("liveview/clipping", True))
        self.clip_check.toggled.connect(lambda on: (settings().setValue("liveview/clipping", on), self._redraw()))
        self.fps_spin = QSpinBox()
        self.fps_spin.setRange(1, 15)
        self.fps_spin.setValue(read_int("liveview/fps", 4))
        self.fps_spin.setSuffix(" fps")
        self.fps_spin.setToolTip("Live-view frame rate asked of the camera")
        self.fps_spin.valueChanged.connect(lambda v: settings().setValue("liveview/fps", v))
        bar = QHBoxLayout()
        for w in (self.live_button, self.fit_button, self.one_button, self.clip_check, self.fps_spin):
            bar.addWidget(w)
        bar.addStretch(1)

        self.graphics = pg.GraphicsLayoutWidget()
        self.graphics.setBackground("#202020")
        self.viewbox = self.graphics.ci.addViewBox(lockAspect=True, invertY=True, enableMenu=False)
        self.image_item = pg.ImageItem(axisOrder="row-major")
        self.viewbox.addItem(self.image_item)
        # what to do next, over the picture area: word-wrapped to its width (never clipped), centred
        self.message = QLabel(self.graphics)
        self.message.setObjectName("liveViewMessage")
        self.message.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.message.setWordWrap(True)
        self.message.setAttribute(Qt.WidgetAttribute.WA_TransparentForMouseEvents)
        self.message.setStyleSheet("color: #d0d0d0; background: rgba(32, 32, 32, 200); border-radius: 6px; "
                                   "padding: 8px;")
        self.graphics.installEventFilter(self)

        hist_item = pg.PlotItem()           # made here, so its view box is at hand (PlotWidget's item is optional)
        self.hist = pg.PlotWidget(plotItem=hist_item)
        self.hist.setMenuEnabled(False)
        self.hist.setMouseEnabled(False, False)
        self.hist.hideAxis("left")
        hist_item.getViewBox().setXRange(0, 255, padding=0.01)
        self.hist.setMinimumHeight(110)
        self.hist.setMaximumHeight(160)
        self.hist.setToolTip("Histogram of the frame (R, G, B); pixels at the right edge are clipped")
        self.hist_curves = [self.hist.plot(pen=pg.mkPen(c, width=1.5), fillLevel=0, brush=pg.mkBrush(*rgb, 50))
                            for c, rgb in (("#e04040", (224, 64, 64)), ("#40c040", (64, 192, 64)),
                                           ("#4080ff", (64, 128, 255)))]

        self.sharp_label = QLabel("Sharpness: –")
        self.sharp_label.setToolTip("Variance of the Laplacian, whole frame and centre third; turn the focus "
                                    "ring for the highest value (compare values of the same scene only)")
        font = self.sharp_label.font()
        font.setPointSizeF(font.pointSizeF() * 1.2)
        font.setBold(True)
        self.sharp_label.setFont(font)
        self.clip_label = QLabel("")
        self.clip_label.setWordWrap(True)
        self.caption_label = QLabel("")
        self.caption_label.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)
        readout = QVBoxLayout()
        readout.addWidget(self.sharp_label)
        readout.addWidget(self.clip_label)
        readout.addWidget(self.caption_label)
        readout.addStretch(1)
        bottom = QHBoxLayout()
        bottom.addWidget(self.hist, 3)
        bottom.addLayout(readout, 2)

        layout = QVBoxLayout(self)
        layout.addLayout(bar)
        layout.addWidget(self.graphics, 1)
        layout.addLayout(bottom)

        self.live_action = QAction("&Live view", self)
        self.live_action.setCheckable(True)
        self.live_action.setShortcut(QKeySequence("Ctrl+L"))
        self.live_action.setToolTip("Start/stop the camera's live preview")
        self.live_action.toggled.connect(self.live_button.setChecked)
        self.live_button.toggled.connect(self.live_action.setChecked)

        self._live_tips = [(w, w.toolTip()) for w in (self.live_button, self.live_action)]
        state.cameraFrame.connect(self.show_frame)
        state.devicesChanged.connect(self._devices_changed)
        state.scanStateChanged.connect(self._scan_state_changed)
        self._set_message(self._placeholder())

    def _placeholder(self) -> str:
        """The empty view's line: what the operator can do now."""
        if self._camera() is None:
            return "No camera connected: connect one in the Camera panel, then press Live or take a test shot."
        return "Camera connected: press Live (Ctrl+L) for its preview, or take a test shot in the Camera panel."

    def eventFilter(self, obj: Any, event: Any) -> bool:
        if obj is self.graphics and event.type() == QEvent.Type.Resize:
            self._place_message()
        return False

    def _place_message(self) -> None:
        area = self.graphics.rect()
        width = max(60, min(area.width() - 24, 560))
        height = min(self.message.heightForWidth(width), max(20, area.height() - 8))
        self.message.setGeometry((area.width() - width) // 2, max(4, (area.height() - height) // 2), width, height)

    def install_menus(self, window: Any) -> None:
        window.menu("Rig").addAction(self.live_action)

    # -- live polling --------------------------------------------------------------------------------
    def _camera(self) -> Any:
        return self.state.devices.get("camera")

    def set_live(self, on: bool) -> None:
        if on and self._camera() is None:
            # uncheck after this toggled() delivery, not inside it
            QTimer.singleShot(0, lambda: self.live_button.setChecked(False))
            self.state.show_status("Live view: connect a camera in the Camera panel first")
            self._set_message("No camera connected: connect one in the Camera panel")
            return
        if on:
            self._request_frame()
        else:
            self._timer.stop()

    def _request_frame(self) -> None:
        device = self._camera()
        if not self.live_button.isChecked() or device is None or self._in_flight:
            return
        if device.busy:                       # a capture or setting change is running: try again soon
            self._timer.start(int(1000 / self.fps_spin.value()))
            return
        self._in_flight = True
        device.run("preview", timeout_s=10, on_result=self._live_frame, on_error=self._live_failed)

    def _live_frame(self, frame: Any) -> None:
        self._in_flight = False
        if frame is None:
            self.live_button.setChecked(False)
            self._set_message("This camera has no live view over USB; take test shots instead")
            return
        self.show_frame(frame, "live")
        if self.live_button.isChecked():
            self._timer.start(int(1000 / self.fps_spin.value()))

    def _live_failed(self, message: str) -> None:
        self._in_flight = False
        self.live_button.setChecked(False)
        self._set_message(f"Live view stopped: {message}")

    def _scan_state_changed(self, _scan_state: Any) -> None:
        """A scan taking the camera ends the live view (its frames would be refused); giving it back
        enables Live again."""
        reason = self.state.camera_lock_reason()
        if reason:
            self.live_button.setChecked(False)
        for widget, tip in self._live_tips:
            widget.setEnabled(not reason)
            widget.setToolTip(f"{tip}\n\n{reason}" if reason else tip)

    def _devices_changed(self, name: str) -> None:
        if name != "camera":
            return
        if self._camera() is None:
            self.live_button.setChecked(False)
            self._in_flight = False
        if self.frame is None:                  # the empty view says what can be done with this camera now
            self._set_message(self._placeholder())

    # -- display -------------------------------------------------------------------------------------
    def _set_message(self, text: str) -> None:
        self.message.setText(text)
        self.message.setVisible(bool(text))
        if text:
            self._place_message()
            self.message.raise_()

    def show_frame(self, frame: np.ndarray, caption: str = "") -> None:
        """Show an RGB uint8 frame and update the sharpness, histogram and clipping readouts."""
        first = self.frame is None or self.frame.shape[:2] != frame.shape[:2]
        self.frame = np.ascontiguousarray(frame)
        self.caption = caption
        self._set_message("")
        self._redraw()
        if first:
            self.fit()
        stats = frame_stats(self.frame)
        self.stats = stats
        if caption != "live" or self._last_caption != "live":
            self.peak_sharpness = 0.0               # a new series of frames (resolution may differ)
        self._last_caption = caption
        self.peak_sharpness = max(self.peak_sharpness, stats.sharpness_centre)
        self.sharp_label.setText(f"Sharpness: {stats.sharpness:.0f}  ·  centre {stats.sharpness_centre:.0f}"
                                 f"  (peak {self.peak_sharpness:.0f})")
        x, hists = histograms(self.frame)
        for curve, h in zip(self.hist_curves, hists):
            curve.setData(x, h)
        warnings = []
        if stats.clipped_high > CLIP_WARN_FRACTION:
            warnings.append(f"{stats.clipped_high * 100:.1f} % highlights clipped: shorten the exposure or "
                            "close the aperture")
        if stats.clipped_low > CLIP_WARN_FRACTION * 10:
            warnings.append(f"{stats.clipped_low * 100:.1f} % shadows crushed: lengthen the exposure")
        if warnings:
            self.clip_label.setText("⚠ " + "; ".join(warnings))
            self.clip_label.setStyleSheet("color: #d03030; font-weight: bold;")
        else:
            self.clip_label.setText(f"Exposure OK (mean level {stats.mean:.0f} of 255)")
            self.clip_label.setStyleSheet("color: #308030;")
        h, w = self.frame.shape[:2]
        self.caption_label.setText(f"{caption} · {w} × {h} px" if caption else f"{w} × {h} px")

    def _redraw(self) -> None:
        if self.frame is None:
            return
        img = clipping_overlay(self.frame) if self.clip_check.isChecked() else self.frame
        self.image_item.setImage(img, levels=(0, 255), autoLevels=False)

    def fit(self) -> None:
        if self.frame is not None:
            h, w = self.frame.shape[:2]
            self.viewbox.setRange(xRange=(0, w), yRange=(0, h), padding=0.02)

    def one_to_one(self) -> None:
        if self.frame is None:
            return
        h, w = self.frame.shape[:2]
        vw = self.viewbox.width() or w
        vh = self.viewbox.height() or h
        self.viewbox.setRange(xRange=(w / 2 - vw / 2, w / 2 + vw / 2), yRange=(h / 2 - vh / 2, h / 2 + vh / 2),
                              padding=0)

    def shutdown(self) -> None:
        self._timer.stop()
        self.live_button.setChecked(False)
