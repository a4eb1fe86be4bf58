"""Conversions between QImage and numpy arrays (always copies: a QImage's buffer dies with it)."""

from __future__ import annotations

import numpy as np
from PySide6.QtGui import QImage


def qimage_to_rgb(image: QImage) -> np.ndarray:
    """An (h, w, 3) uint8 RGB copy of ``image``."""
    img = image.convertToFormat(QImage.Format.Format_RGB888)
    h, w, bpl = img.height(), img.width(), img.bytesPerLine()
    buf = np.frombuffer(img.constBits(), np.uint8, bpl * h).reshape(h, bpl)
    return buf[:, : w * 3].reshape(h, w, 3).copy()


def rgb_to_qimage(array: np.ndarray) -> QImage:
    """A QImage (owning its own copy) from an (h, w) or (h, w, 3) uint8 array."""
    a = np.ascontiguousarray(array)
    if a.dtype != np.uint8:
        raise TypeError(f"expected uint8, got {a.dtype}")
    if a.ndim == 2:
        h, w = a.shape
        return QImage(a.data, w, h, a.strides[0], QImage.Format.Format_Grayscale8).copy()
    h, w, _ = a.shape
    return QImage(a.data, w, h, a.strides[0], QImage.Format.Format_RGB888).copy()
