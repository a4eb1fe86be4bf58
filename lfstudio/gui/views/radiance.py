"""Dataset → HDR radiance of a view…: a bracketed view's merged linear radiance (``hdr/rRR_cCCC.exr`` or
``.tif``, written by Process: :mod:`lfstudio.processing.hdr`) under an exposure slider.

The float image is read and reduced to the screen's size off the GUI thread; the slider scales it by
2^EV around the dataset's key (0 EV: the merged view's log-average luminance shown as 18 % grey) and
shows it through the sRGB curve, so highlights the middle frame clipped come back as the slider goes
down and shadows as it goes up. The figures under it are the radiance's own (the merge's units: the
reference frame's developed 0…1 scale at its exposure time).

The picture at a slider position is made off the GUI thread too (:class:`Exposer`, one thread per
dialog): first from a preview-sized copy (:data:`PREVIEW_PX`, at once), then at the shown size; the
latest position wins (positions passed meanwhile are never made, a newer one stops the refinement).
The GUI thread only puts the finished picture on the screen."""

from __future__ import annotations

import threading
from typing import Any, Callable

import numpy as np
from PySide6.QtCore import QSize, Qt
from PySide6.QtGui import QAction, QImage, QPixmap
from PySide6.QtWidgets import QDialog, QHBoxLayout, QLabel, QLineEdit, QPushButton, QSlider, QVBoxLayout, QWidget

from lfstudio.errors import LfError
from lfstudio.gui.bridge import GuiInbox, Pacer, run_off_gui
from lfstudio.gui.widgets import FitImageView, add_stop_button, screen_fitted

EV_RANGE = (-8.0, 8.0)          # the slider's exposure, in stops around the key
EV_STEP = 0.1
SHOWN_MAX_PX = 2000             # the radiance is reduced to at most this width for the screen
PREVIEW_PX = 400                # ... and a copy to this width, made first at each slider position


def merged_views(dataset) -> list[tuple[int, int]]:
    """The views of ``dataset`` whose bracket was merged (their radiance file recorded)."""
    from lfstudio.dataset.manifest import hdr_merged

    return [(int(v["row"]), int(v["column"])) for v in dataset.done_views() if hdr_merged(v) is not None]


def load_radiance(dataset, view: tuple[int, int]) -> dict[str, Any]:
    """A merged view's radiance reduced for the screen, its key and figures (Qt-free; worker thread)."""
    import cv2

    from lfstudio.dataset.manifest import hdr_merged
    from lfstudio.dataset.paths import view_stem
    from lfstudio.processing.hdr import log_average, read_radiance

    record = hdr_merged(dataset.view(*view))
    if record is None:
        raise LfError(f"{view_stem(*view)} has no merged radiance yet: Process the dataset (a bracketed scan's "
                      "frames are merged after its views)")
    path = dataset.root / record["file"]
    if not path.is_file():
        raise LfError(f"{record['file']}: not found in the dataset; Process again with Redo finished views")
    radiance = read_radiance(path)
    h, w = radiance.shape[:2]
    if w > SHOWN_MAX_PX:
        radiance = cv2.resize(radiance, (SHOWN_MAX_PX, round(h * SHOWN_MAX_PX / w)), interpolation=cv2.INTER_AREA)
    lum = radiance.mean(axis=2)
    fin = lum[np.isfinite(lum)]
    figures = {"file": record["file"], "size": (w, h), "min": float(fin.min()) if fin.size else 0.0,
               "median": float(np.median(fin)) if fin.size else 0.0, "max": float(fin.max()) if fin.size else 0.0,
               "clipped_merged": (record.get("clipped_fraction") or {}).get("merged")}
    radiance = np.ascontiguousarray(radiance, dtype=np.float32)
    sh, sw = radiance.shape[:2]
    preview = radiance if sw <= PREVIEW_PX else cv2.resize(
        radiance, (PREVIEW_PX, max(1, round(sh * PREVIEW_PX / sw))), interpolation=cv2.INTER_AREA)
    return {"radiance": radiance, "preview": np.ascontiguousarray(preview, dtype=np.float32),
            "key": max(log_average(radiance), 1e-9), "figures": figures}


def exposed(radiance: np.ndarray, key: float, ev: float) -> np.ndarray:
    """8-bit sRGB of ``radiance`` at ``ev`` stops around ``key`` (0 EV: ``key`` shown as 18 % grey)."""
    x = radiance * np.float32(0.18 / key * 2.0 ** ev)
    np.clip(x, 0.0, 1.0, out=x)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4, dtype=np.float32) - 0.055)
    return (srgb * 255.0 + 0.5).astype(np.uint8)


class Exposer:
    """:func:`exposed` on a thread of its own, the latest request winning. :meth:`request` (any
    thread, returns at once) replaces a request not yet started; each request gives ``deliver(seq,
    ev, image, final)`` (on the worker thread) a preview first (``data["preview"]`` exposed, and
    enlarged to the picture's size when ``enlarge``: a picture shown 1:1 keeps its size; fitted to
    the room, the view scales the small one for less; ``final`` False) unless it is as large as the
    picture, then the picture (``final`` True), skipped when a newer request is waiting by then.
    ``image`` is a QImage (made here, not on the GUI thread); with ``fit`` (width, height) in the
    request, ``fitted`` is the picture scaled to it too (None without), so that the view need not
    scale a 2000 px picture on the GUI thread.

    ``deliver(seq, ev, image, fitted, final)``."""

    def __init__(self, deliver: Callable[[int, float, QImage, QImage | None, bool], None],
                 name: str = "radiance-exposer"):
        self._deliver = deliver
        self._cond = threading.Condition()
        self._want: tuple[int, dict[str, Any], float, bool, tuple[int, int] | None] | None = None
        self._seq = 0
        self._closed = False
        self.made: list[tuple[float, bool]] = []        # (ev, final) of each picture made, in order
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def request(self, data: dict[str, Any], ev: float, enlarge: bool = True,
                fit: tuple[int, int] | None = None) -> int:
        with self._cond:
            self._seq += 1
            self._want = (self._seq, data, float(ev), bool(enlarge), fit)
            self._cond.notify()
            return self._seq

    def _newer_waiting(self) -> bool:
        with self._cond:
            return self._want is not None or self._closed

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._want = None
            self._cond.notify()

    @staticmethod
    def _fitted(rgb: np.ndarray, fit: tuple[int, int] | None, full_width: int) -> QImage | None:
        """``rgb`` scaled to ``fit`` (the size a picture ``full_width`` wide is shown at), or None."""
        import cv2

        from lfstudio.gui.imageutil import rgb_to_qimage

        if fit is None or fit[0] < 2 or fit[1] < 2:
            return None
        if rgb.shape[1] != full_width:       # a preview shown in place of the picture: the view scales it
            return None
        smaller = fit[0] < rgb.shape[1]
        return rgb_to_qimage(cv2.resize(rgb, fit, interpolation=cv2.INTER_AREA if smaller else cv2.INTER_LINEAR))

    def _run(self) -> None:
        import cv2

        from lfstudio.gui.imageutil import rgb_to_qimage

        while True:
            with self._cond:
                while self._want is None and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                assert self._want is not None
                seq, data, ev, enlarge, fit = self._want
                self._want = None
            radiance, preview = data["radiance"], data.get("preview")
            h, w = radiance.shape[:2]
            try:
                if preview is not None and preview.shape[1] < w:
                    small = exposed(preview, data["key"], ev)
                    if enlarge:
                        small = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
                    self.made.append((ev, False))
                    self._deliver(seq, ev, rgb_to_qimage(small), self._fitted(small, fit, w), False)
                    if self._newer_waiting():
                        continue
                rgb = exposed(radiance, data["key"], ev)
                self.made.append((ev, True))
                self._deliver(seq, ev, rgb_to_qimage(rgb), self._fitted(rgb, fit, w), True)
            except Exception:  # noqa: BLE001 - a broken picture must not end the dialog's worker
                import logging

                logging.getLogger(__name__).exception("exposing the radiance at %+.1f EV failed", ev)


class RadianceDialog(QDialog):
    """A merged view's radiance with an exposure slider (module docstring)."""

    def __init__(self, state, parent: QWidget | None = None, view: tuple[int, int] | None = None):
        super().__init__(parent)
        self.state = state
        self.dataset = state.dataset
        self.setObjectName("radianceDialog")
        self.setWindowTitle("HDR radiance of a view")
        self.resize(screen_fitted(self, 1040, 820))
        from lfstudio.dataset.paths import view_stem

        merged = merged_views(self.dataset)
        self.view = view or (merged[len(merged) // 2] if merged else (0, 0))
        self.view_edit = QLineEdit(view_stem(*self.view))
        self.view_edit.setObjectName("radianceViewEdit")
        self.view_edit.setToolTip("The view, by its name: r07_c042 is row 7, column 42")
        self.view_edit.setMaximumWidth(120)
        self.show_button = QPushButton("Show")
        self.slider = QSlider(Qt.Orientation.Horizontal)
        self.slider.setObjectName("exposureSlider")
        self.slider.setRange(round(EV_RANGE[0] / EV_STEP), round(EV_RANGE[1] / EV_STEP))
        self.slider.setValue(0)
        self.slider.setToolTip("Exposure of the picture, in stops (EV) around the view's average brightness: "
                               "left brings back the highlights, right the shadows. The radiance itself is "
                               "not changed.")
        self.ev_label = QLabel("")
        self.ev_label.setObjectName("exposureLabel")
        self.ev_label.setMinimumWidth(self.ev_label.fontMetrics().horizontalAdvance("Exposure −8.0 EV") + 8)
        reset = QPushButton("0 EV")
        reset.setToolTip("Back to the view's average brightness")
        reset.clicked.connect(lambda: self.slider.setValue(0))
        self.image = FitImageView("radianceImage")
        top = QHBoxLayout()
        top.addWidget(QLabel("View"))
        top.addWidget(self.view_edit)
        top.addWidget(self.show_button)
        top.addWidget(self.image.fit_button())
        top.addSpacing(12)
        top.addWidget(self.ev_label)
        top.addWidget(self.slider, 1)
        top.addWidget(reset)
        self.caption = QLabel("")
        self.caption.setObjectName("radianceCaption")
        self.caption.setWordWrap(True)
        lay = QVBoxLayout(self)
        lay.addLayout(top)
        lay.addWidget(self.image, 1)
        lay.addWidget(self.caption)
        add_stop_button(self, lay)      # STOP in sight while this dialog covers the window's
        self._data: dict[str, Any] | None = None
        self._loader = None
        self.pictures_shown = 0
        self._shown_seq = 0
        self._asked: tuple | None = None            # what the exposer was asked for last
        self._pictures = GuiInbox(self._show_pictures, self)
        self.exposer = Exposer(lambda *picture: self._pictures.post(picture))
        self.finished.connect(lambda _r: self.exposer.close())
        self.destroyed.connect(self.exposer.close)
        self._pacer = Pacer(self._expose, 40, self)        # the slider dragged: at most 25 pictures a second
        self.slider.valueChanged.connect(lambda _v: self._pacer.request())
        self.show_button.clicked.connect(self.show_view)
        self.view_edit.returnPressed.connect(self.show_view)
        self._show_ev()
        self.show_view()

    @property
    def ev(self) -> float:
        return self.slider.value() * EV_STEP

    def _show_ev(self) -> None:
        self.ev_label.setText(f"Exposure {self.ev:+.1f} EV".replace("-", "−"))

    def show_view(self) -> None:
        from lfstudio.dataset.paths import parse_view_stem

        try:
            view = parse_view_stem(self.view_edit.text().strip())
        except (ValueError, LfError):
            self.caption.setText(f"{self.view_edit.text().strip()!r} is not a view name; write it like r01_c004")
            return
        self.view = view
        self.caption.setText("Reading the radiance…")
        self._loader = run_off_gui(self, lambda: load_radiance(self.dataset, view), self._loaded,
                                   lambda message: self.caption.setText(message))

    def _loaded(self, data: dict[str, Any]) -> None:
        self._data = data
        self._expose()

    def _expose(self) -> None:
        """The slider moved (paced): the picture at its position is asked of the exposer (off the GUI
        thread); :meth:`_show_pictures` puts it on the screen."""
        self._show_ev()
        data = self._data
        if data is not None:
            fit = None
            if self.image.fit:
                h, w = data["radiance"].shape[:2]
                size = self.image.fitted_size(QSize(w, h))
                fit = (size.width(), size.height())
            asked = (id(data), self.ev, self.image.fit, fit)
            if asked != self._asked:                # the same picture again (a late paced call): nothing to do
                self._asked = asked
                self.exposer.request(data, self.ev, enlarge=not self.image.fit, fit=fit)

    def _show_pictures(self, items: list[tuple[int, float, QImage, QImage | None, bool]]) -> None:
        seq, ev, image, fitted, final = items[-1]   # the latest made; older ones are never shown
        if seq < self._shown_seq or self._data is None:
            return
        self._shown_seq = seq
        self.image.set_pixmap(QPixmap.fromImage(image), None if fitted is None else QPixmap.fromImage(fitted))
        if not final:
            return
        fig = self._data["figures"]
        clipped = fig.get("clipped_merged")
        self.caption.setText(
            f"{fig['file']} ({fig['size'][0]} × {fig['size'][1]} px, linear float): radiance {fig['min']:.3g} … "
            f"{fig['max']:.3g}, median {fig['median']:.3g} (the reference frame's 0…1 scale); "
            + (f"{clipped:.2%} of pixels clipped in every frame; " if isinstance(clipped, (int, float)) else "")
            + f"shown at {ev:+.1f} EV through the sRGB curve")
        self.pictures_shown += 1

    def closeEvent(self, event) -> None:  # noqa: N802 (Qt name)
        self.exposer.close()
        super().closeEvent(event)


def install_menus(window) -> None:
    """Dataset → HDR radiance of a view… (enabled when the open dataset has merged views)."""
    state = window.state
    action = QAction("HDR radiance of a view…", window)
    action.setObjectName("actionRadiance")
    action.setToolTip("A bracketed view's merged radiance (after Process) under an exposure slider")

    def refresh(*_args) -> None:
        ds = state.dataset
        action.setEnabled(ds is not None and bool(ds.manifest.get("bracket")) and bool(merged_views(ds)))

    def open_dialog() -> None:
        if state.dataset is None:
            return
        window.radiance_dialog = RadianceDialog(state, window)
        window.radiance_dialog.show()

    action.triggered.connect(open_dialog)
    state.datasetChanged.connect(refresh)
    refresh()
    window.menu("Dataset").addAction(action)
