"""Thumbnails of a dataset's views decoded off the GUI thread for the grid (:class:`ThumbLoader`: one
background thread, newest requests first, results handed to the GUI thread in batches)."""

from __future__ import annotations

import atexit
import threading
import weakref
from typing import Any

import numpy as np
from PySide6.QtCore import QObject, QSize, Signal
from PySide6.QtGui import QImage

from lfstudio.dataset import images
from lfstudio.gui.bridge import GuiInbox


def file_thumbnail(path: str, width_px: int) -> QImage:
    """A view's stored thumbnail (``thumbs/``) decoded small, or a thumbnail made from the view's own
    file (RAW or 16-bit image) and cached in the dataset."""
    from lfstudio.dataset.thumbs import cached_thumbnail
    from lfstudio.gui.imageutil import rgb_to_qimage

    try:
        stored = "/thumbs/" in path.replace("\\", "/")
        bgr = images.thumbnail_array(path, width_px) if stored else cached_thumbnail(path, width_px)
    except Exception:  # an unreadable file stays a coloured cell; the dataset check reports it
        return QImage()
    return QImage() if bgr is None else rgb_to_qimage(np.ascontiguousarray(bgr[..., ::-1]))


_LOADERS: "weakref.WeakSet[ThumbLoader]" = weakref.WeakSet()


@atexit.register
def _stop_loaders() -> None:
    """Let every loader finish its thumbnail before the interpreter ends: a daemon thread killed
    inside Qt's decoder aborts the process ("terminate called without an active exception")."""
    for loader in list(_LOADERS):
        try:
            loader.stop()
        except RuntimeError:        # its Qt object is gone already; so is the thread's work
            pass


class ThumbLoader(QObject):
    """Decodes thumbnails on one background thread; newest requests first.

    Decoded images reach the GUI thread in batches (:class:`~lfstudio.gui.bridge.GuiInbox`); ``ready``
    says some are waiting and the grid takes them all (:meth:`take`) once a frame: during a fast scan the
    GUI handles a batch, not one Python call (and one GIL hand-over) per thumbnail."""

    ready = Signal()

    def __init__(self, parent: QObject | None = None, batch_ms: int = 20):
        super().__init__(parent)
        _LOADERS.add(self)
        self._stack: list[tuple[Any, str, QSize]] = []
        self._queued: set[Any] = set()
        self._cond = threading.Condition()
        self._stop = False
        self._generation = 0
        self._done: list[tuple[Any, QImage]] = []       # arrived on the GUI thread, not taken yet
        self._inbox = GuiInbox(self._arrived, self, every_ms=batch_ms)   # the grid takes them once a frame
        self._thread = threading.Thread(target=self._run, name="thumb-loader", daemon=True)
        self._thread.start()

    def request(self, key: Any, path: str, size: QSize) -> None:
        self.request_many([(key, path, size)])

    def request_many(self, items: list[tuple[Any, str, QSize]]) -> None:
        """Queue several (key, path, size) at once (one lock, one wake-up)."""
        with self._cond:
            added = False
            for key, path, size in items:
                if key in self._queued:
                    continue
                self._queued.add(key)
                self._stack.append((key, path, size))
                added = True
            if added:
                self._cond.notify()

    def take(self) -> list[tuple[Any, QImage]]:
        """The thumbnails decoded since the last call (GUI thread), oldest first."""
        done, self._done = self._done, []
        return done

    def _arrived(self, items: list) -> None:
        """GUI thread (the inbox): keep the batch for :meth:`take` and say so once."""
        generation = self._generation
        self._done.extend((key, image) for g, key, image in items if g == generation)
        if self._done:
            self.ready.emit()

    def clear(self) -> None:
        with self._cond:
            self._stack.clear()
            self._queued.clear()
            self._generation += 1
        self._done.clear()

    def stop(self) -> None:
        with self._cond:
            self._stop = True
            self._stack.clear()
            self._cond.notify()
        self._thread.join(2)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._stop or self._stack)
                if self._stop:
                    return
                key, path, size = self._stack.pop()
                generation = self._generation
            image = file_thumbnail(path, max(size.width(), 1))
            with self._cond:
                self._queued.discard(key)
                if generation != self._generation or image.isNull():
                    continue
            self._inbox.post((generation, key, image))
