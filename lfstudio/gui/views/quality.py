"""The grid view's quality tools: run the dataset check, show its verdicts, compare a flagged view
with its neighbours, show the disparity map, check views during a scan.

* :class:`QualityBar` — "Check dataset" (``lfstudio.quality.check_dataset`` through a
  :class:`~lfstudio.gui.bridge.JobRunner`: off the GUI thread, progress, ETA, Cancel), the heat-map
  overlay choice (:data:`lfstudio.quality.pictures.HEATMAPS`), "Select flagged", "Disparity map…" and
  "Check during scan";
* :class:`LiveQuality` — a :class:`lfstudio.quality.live.LiveCheckerProcess` (the checker in a process
  of its own: its work never holds the GUI's GIL) whose verdicts arrive on the GUI thread as a Qt
  signal, a list at a time;
* :class:`NeighboursDialog` — a flagged view in the middle of its 8 neighbours, with the reasons and
  a "Re-capture this view" button; :class:`DisparityDialog` — the centre view's disparity map.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

from PySide6.QtCore import QObject, QRect, QSize, Qt, Signal
from PySide6.QtGui import QColor, QImage, QLinearGradient, QPainter, QPixmap
from PySide6.QtWidgets import (QCheckBox, QComboBox, QDialog, QGridLayout, QHBoxLayout, QLabel, QPushButton,
                               QSizePolicy, QStackedWidget, QVBoxLayout, QWidget)

from lfstudio.dataset.manifest import is_done
from lfstudio.dataset.paths import view_label
from lfstudio.gui.bridge import GuiInbox, JobRunner
from lfstudio.gui.settings import read_bool, settings
from lfstudio.gui.widgets import JobProgressWidget, QuietLabel, screen_fitted
from lfstudio.jobs import count

LIVE_KEY = "quality/check_during_scan"
OVERLAY_KEY = "quality/overlay"
VERDICT_COLOURS = {"warn": "#c89b00", "fail": "#e63c3c", "pass": "#46b45a", "n/a": "#8a8f98"}


def run_check(root: str, *, progress, cancel) -> dict[str, Any]:
    """The ``Check dataset`` job: a fresh read of the dataset, checked and written (worker thread)."""
    from lfstudio.dataset import Dataset
    from lfstudio.quality import check_dataset

    return check_dataset(Dataset.open(root), progress=progress, cancel=cancel).document


class LiveQuality(QObject):
    """Checks the views of a running scan; ``verdicts(entries)`` arrive on the GUI thread, in order,
    as many together as came in since the last (one call per turn of the event loop)."""

    verdicts = Signal(object)

    def __init__(self, dataset, parent: QObject | None = None):
        super().__init__(parent)
        from lfstudio.quality.live import LiveCheckerProcess

        self.root = Path(dataset.root)
        self.checker = LiveCheckerProcess(dataset)
        self._inbox = GuiInbox(self.verdicts.emit, self, every_ms=50)   # the grid shows them every VERDICT_MS
        self.checker.subscribe(self._inbox.post)      # called on the checker's reader thread

    def on_event(self, event: Any) -> None:
        self.checker.on_event(event)

    def document(self) -> dict[str, Any]:
        return self.checker.document()

    def shutdown(self) -> None:
        """Stop checking (views still queued are dropped); never waits on the GUI thread."""
        self.checker.close(timeout_s=0.0, drain=False)


class HeatLegend(QWidget):
    """The colour scale of the grid's heat map: its name, the low end, the colours, the high end and the
    unit (the same scale as the report's heat maps); hidden without a heat map."""

    BAR_PX = 90

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.setObjectName("heatLegend")
        self.key, self.low, self.high, self.unit, self.title = "", 0.0, 1.0, "", ""
        self._colours: list[QColor] = []
        self.setFixedHeight(self.fontMetrics().height() + 4)
        self.setVisible(False)

    def set_map(self, doc: dict | None, key: str) -> None:
        from lfstudio.quality.pictures import HEATMAPS, heatmap_colour

        if not key or doc is None or key not in HEATMAPS:
            self.key = ""
            self.setVisible(False)
            return
        h = HEATMAPS[key]
        try:
            self.low, self.high = h.range(doc)
        except (KeyError, TypeError, ValueError):
            self.key = ""
            self.setVisible(False)
            return
        self.key, self.unit, self.title = key, h.unit, h.title.split(" (")[0]
        steps = 32
        self._colours = [QColor(*heatmap_colour(doc, key, self.low + (self.high - self.low) * i / (steps - 1)))
                         for i in range(steps)]
        self.setToolTip(f"{h.title}: colours from {self._number(self.low)} to {self._number(self.high)} {self.unit} "
                        "(beyond: the end colours; no colour: not measured)")
        self.updateGeometry()
        self.setVisible(True)
        self.update()

    @staticmethod
    def _number(v: float) -> str:
        return f"{v:.3g}"

    def texts(self) -> tuple[str, str]:
        return f"{self.title} {self._number(self.low)}", f"{self._number(self.high)} {self.unit}".rstrip()

    def sizeHint(self) -> QSize:   # noqa: N802 (Qt name)
        left, right = self.texts()
        fm = self.fontMetrics()
        return QSize(fm.horizontalAdvance(left) + self.BAR_PX + fm.horizontalAdvance(right) + 16, self.height())

    def minimumSizeHint(self) -> QSize:   # noqa: N802 (Qt name)
        return self.sizeHint()

    def paintEvent(self, event) -> None:   # noqa: N802 (Qt name)
        if not self.key:
            return
        left, right = self.texts()
        fm = self.fontMetrics()
        p = QPainter(self)
        p.setPen(self.palette().windowText().color())
        h = self.height()
        x = 0
        p.drawText(QRect(x, 0, fm.horizontalAdvance(left), h), Qt.AlignmentFlag.AlignVCenter, left)
        x += fm.horizontalAdvance(left) + 8
        gradient = QLinearGradient(x, 0, x + self.BAR_PX, 0)
        for i, colour in enumerate(self._colours):
            gradient.setColorAt(i / max(1, len(self._colours) - 1), colour)
        p.fillRect(QRect(x, 3, self.BAR_PX, h - 6), gradient)
        x += self.BAR_PX + 8
        p.drawText(QRect(x, 0, fm.horizontalAdvance(right), h), Qt.AlignmentFlag.AlignVCenter, right)
        p.end()


class QualityBar(QWidget):
    """The quality row of the grid view's toolbar (see the module docstring)."""

    overlayChanged = Signal(str)          # "" or a HEATMAPS key
    selectFlagged = Signal()
    showDisparity = Signal()

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        from lfstudio.quality.pictures import HEATMAPS

        self.setObjectName("qualityBar")
        self.runner = JobRunner(self)
        self.check_button = QPushButton("Check")
        self.check_button.setObjectName("checkButton")
        self.check_button.setToolTip("Check dataset: judge every view from its pixels — sharpness, exposure, "
                                     "position, track residual — and the scene's depth and disparity map "
                                     "(writes quality.json and quality/report.html)")
        self.overlay = QComboBox()
        self.overlay.setObjectName("overlayCombo")
        self.overlay.addItem("No heat map", "")
        for key, h in HEATMAPS.items():
            self.overlay.addItem(h.title.split(" (")[0], key)
        self.overlay.setSizeAdjustPolicy(QComboBox.SizeAdjustPolicy.AdjustToMinimumContentsLengthWithIcon)
        self.overlay.setMinimumContentsLength(12)      # the longest heat-map name is elided, not widening the bar
        self.overlay.setToolTip("Colour the grid by one measured figure (the same scale as the report's heat maps)")
        self.overlay.currentIndexChanged.connect(lambda i: self.overlayChanged.emit(self.overlay.itemData(i)))
        self.select_button = QPushButton("Select flagged")
        self.select_button.setObjectName("selectFlaggedButton")
        self.select_button.setToolTip("Select every view the check flagged (then Re-capture selected)")
        self.select_button.clicked.connect(self.selectFlagged)
        self.disparity_button = QPushButton("Disparity…")
        self.disparity_button.setObjectName("disparityButton")
        self.disparity_button.setToolTip("Disparity map: the centre view's disparity in false colour (from the "
                                         "last check)")
        self.disparity_button.clicked.connect(self.showDisparity)
        self.live_box = QCheckBox("During scan")
        self.live_box.setObjectName("liveCheckBox")
        self.live_box.setToolTip("Check during the scan: judge each view as the scan captures it (on a "
                                 "process of its own; the scan never waits for it) and flag failing views at once")
        self.live_box.setChecked(read_bool(LIVE_KEY, True))
        self.live_box.toggled.connect(lambda on: settings().setValue(LIVE_KEY, bool(on)))
        self.summary = QuietLabel("", name="qualitySummary", every_ms=500,    # changes with each batch of verdicts
                                  hint_text="2121 views checked during the scan: 2121 fail · 2121 warn")
        self.progress = JobProgressWidget(self.runner)
        # rows: the tools; "During scan" (the grid view adds its zoom tools and Re-capture at the end);
        # the verdicts, or while a check runs its progress in their place (the same row: a check never
        # asks the window for more width or height, which would be taken from the docks)
        self.status = QStackedWidget()
        self.status.setObjectName("qualityStatus")
        self.legend = HeatLegend()
        verdicts = QWidget()
        row = QHBoxLayout(verdicts)
        row.setContentsMargins(0, 0, 0, 0)
        row.addWidget(self.summary, 1)
        row.addWidget(self.legend)
        self._verdicts = verdicts
        self.status.addWidget(verdicts)
        self.status.addWidget(self.progress)
        self.status.setSizePolicy(QSizePolicy.Policy.Preferred, QSizePolicy.Policy.Fixed)
        self.runner.started.connect(lambda: self.status.setCurrentWidget(self.progress))
        for sig in (self.runner.finished, self.runner.failed, self.runner.cancelled):
            sig.connect(lambda *a: self.status.setCurrentWidget(self._verdicts))
        lay = QVBoxLayout(self)
        lay.setContentsMargins(4, 0, 4, 2)
        lay.setSpacing(2)
        tools, line = QHBoxLayout(), QHBoxLayout()
        self.line = line
        for w in (self.check_button, self.overlay, self.select_button, self.disparity_button, self.live_box):
            w.setSizePolicy(QSizePolicy.Policy.Fixed, QSizePolicy.Policy.Fixed)
            (line if w is self.live_box else tools).addWidget(w)
        tools.addStretch(1)
        line.addStretch(1)
        lay.addLayout(tools)
        lay.addLayout(line)
        lay.addWidget(self.status)
        self.set_available(False, False)

    def set_available(self, dataset: bool, report: bool) -> None:
        self.check_button.setEnabled(dataset and not self.runner.running)
        self.disparity_button.setEnabled(report)

    def set_summary(self, entries: dict, live: bool) -> None:
        fail = sum(1 for e in entries.values() if e["verdict"] == "fail")
        warn = sum(1 for e in entries.values() if e["verdict"] == "warn")
        if not entries:
            self.summary.setText("")
            return
        where = "checked during the scan" if live else "checked"
        text = f"{count(len(entries), 'view')} {where}: "
        text += (f"<span style='color:{VERDICT_COLOURS['fail']}'>{fail} fail</span> · "
                 f"<span style='color:{VERDICT_COLOURS['warn']}'>{warn} warn</span>") if fail or warn else \
            f"<span style='color:{VERDICT_COLOURS['pass']}'>all pass</span>"
        self.summary.setText(text)
        self.select_button.setEnabled(bool(fail or warn))

    def shutdown(self) -> None:
        self.runner.stop(5.0)


class _Decoder(QObject):
    """Decodes small previews of view files on a thread; ``decoded(cell, QImage)``."""

    decoded = Signal(object, QImage)

    def __init__(self, parent: QObject | None = None):
        super().__init__(parent)
        self._inbox = GuiInbox(lambda done: [self.decoded.emit(cell, image) for cell, image in done], self)

    def start(self, jobs: list[tuple[tuple[int, int], Path]], width_px: int) -> None:
        threading.Thread(target=self._run, args=(jobs, width_px), daemon=True, name="neighbour-decode").start()

    def _run(self, jobs, width_px: int) -> None:
        import numpy as np

        from lfstudio.gui.imageutil import rgb_to_qimage
        from lfstudio.dataset.images import thumbnail_array

        for cell, path in jobs:
            try:
                bgr = thumbnail_array(path, width_px)
            except Exception:
                bgr = None
            self._inbox.post((cell, QImage() if bgr is None else rgb_to_qimage(np.ascontiguousarray(bgr[..., ::-1]))))


class NeighboursDialog(QDialog):
    """A flagged view in the middle of its 8 neighbours, with why it was flagged."""

    recaptureRequested = Signal(object)     # [(row, column)]

    TILE_PX = 300

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.setObjectName("neighboursDialog")
        self.setWindowTitle("View and its neighbours")
        self.cell: tuple[int, int] | None = None
        self.tiles: dict[tuple[int, int], QLabel] = {}
        self.grid = QGridLayout()
        self.grid.setSpacing(4)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                label = QLabel()
                label.setAlignment(Qt.AlignmentFlag.AlignCenter)
                label.setMinimumSize(self.TILE_PX // 2, self.TILE_PX // 3)
                label.setStyleSheet("background:#202226;color:#9aa0a8")
                self.grid.addWidget(label, dr + 1, dc + 1)
                self.tiles[(dr, dc)] = label
        self.reasons = QLabel("")
        self.reasons.setObjectName("neighboursReasons")
        self.reasons.setWordWrap(True)
        self.reasons.setTextFormat(Qt.TextFormat.RichText)
        self.recapture_button = QPushButton("Re-capture this view")
        self.recapture_button.setObjectName("recaptureThisButton")
        self.recapture_button.setToolTip("Queue this view for capture again (Scan panel)")
        self.recapture_button.clicked.connect(lambda: self.cell and self.recaptureRequested.emit([self.cell]))
        close = QPushButton("Close")
        close.clicked.connect(self.close)
        buttons = QHBoxLayout()
        buttons.addStretch(1)
        buttons.addWidget(self.recapture_button)
        buttons.addWidget(close)
        lay = QVBoxLayout(self)
        lay.addLayout(self.grid, 1)
        lay.addWidget(self.reasons)
        lay.addLayout(buttons)
        self.decoder = _Decoder(self)
        self.decoder.decoded.connect(self._on_decoded)
        self.resize(3 * self.TILE_PX + 40, 2 * self.TILE_PX + 160)

    def show_view(self, dataset, cell: tuple[int, int], entry: dict | None) -> None:
        """Show ``cell`` of ``dataset`` among its neighbours (``entry``: its quality verdict or None)."""
        self.cell = cell
        r, c = cell
        self.setWindowTitle(f"View {view_label(r, c)} and its neighbours")
        jobs = []
        for (dr, dc), label in self.tiles.items():
            label.setPixmap(QPixmap())
            n = (r + dr, c + dc)
            try:
                v = dataset.view(*n)
            except KeyError:
                label.setText("")
                continue
            if not is_done(v):
                label.setText(f"{view_label(n[0], n[1])}\n{v.get('status')}")
                continue
            label.setText(f"{view_label(n[0], n[1])}\nloading…")
            try:
                jobs.append((n, dataset.path_of(v)))
            except Exception as exc:
                label.setText(f"{view_label(n[0], n[1])}\n{exc}")
        self.tiles[(0, 0)].setStyleSheet("background:#202226;color:#9aa0a8;border:3px solid "
                                         f"{VERDICT_COLOURS.get((entry or {}).get('verdict', 'n/a'))}")
        if entry:
            colour = VERDICT_COLOURS.get(entry["verdict"], "#ccc")
            lines = "".join(f"<li>{r_}</li>" for r_ in entry.get("reasons", [])) or "<li>no check flagged it</li>"
            self.reasons.setText(f"<b style='color:{colour}'>{entry['verdict'].upper()}</b> — {view_label(r, c)}"
                                 f"<ul>{lines}</ul>")
        else:
            self.reasons.setText(f"{view_label(r, c)}: not checked yet")
        self.decoder.start(jobs, self.TILE_PX)

    def _on_decoded(self, cell, image: QImage) -> None:
        if self.cell is None:
            return
        d = (cell[0] - self.cell[0], cell[1] - self.cell[1])
        label = self.tiles.get(d)
        if label is None:
            return
        if image.isNull():
            label.setText(f"{view_label(cell[0], cell[1])}\ncannot be decoded")
            return
        label.setPixmap(QPixmap.fromImage(image.scaledToWidth(self.TILE_PX, Qt.TransformationMode.SmoothTransformation)))
        label.setToolTip(f"row {cell[0]}, column {cell[1]}")


class DisparityDialog(QDialog):
    """The disparity map of the centre view from the last check (``quality/disparity.png``)."""

    def __init__(self, path: Path, info: dict | None, parent: QWidget | None = None, depth: dict | None = None):
        super().__init__(parent)
        self.setObjectName("disparityDialog")
        self.setWindowTitle("Disparity map of the centre view")
        self.resize(screen_fitted(self, 1040, 800))
        from lfstudio.gui.widgets import FitImageView

        self.image = FitImageView("disparityImage")     # whole, with its colour bar; Fit off: 1:1
        from lfstudio.dataset.images import read_picture
        from lfstudio.gui.imageutil import rgb_to_qimage

        bgr = read_picture(path)
        if bgr is None:
            self.image.setText(f"{path}: cannot be read; run Check dataset again")
        else:
            self.image.set_pixmap(QPixmap.fromImage(rgb_to_qimage(bgr[..., ::-1].copy())))
        text = QLabel(self._caption(info, depth))
        text.setObjectName("disparityCaption")
        self.caption = text
        text.setWordWrap(True)
        bar = QHBoxLayout()
        bar.addWidget(self.image.fit_button())
        bar.addStretch(1)
        lay = QVBoxLayout(self)
        lay.addLayout(bar)
        lay.addWidget(self.image, 1)
        lay.addWidget(text)

    @staticmethod
    def _caption(info: dict | None, depth: dict | None = None) -> str:
        """The map's figures in the check's one wording (lfstudio.quality.summaries.disparity_map_summary)."""
        if not info:
            return ""
        from lfstudio.quality.summaries import disparity_map_summary

        return (f"Disparity map (near = red), full-resolution px: {disparity_map_summary(info, depth)}; "
                + ("rectified" if info.get("rectified") else "not rectified (no calibration)"))
