"""Frames a camera hands back as pixel arrays (machine-vision cameras), and the files they are stored as.

An *array camera* (:class:`lfstudio.rig.camera.ArrayCamera`; e.g. the GenICam driver) does not write
files: each capture returns a :class:`Frame` (the pixels and what the camera said about them), and the
scan's store stage writes it with :func:`write_frame` next to where a file camera would have put its
file, then checksums and journals it like any capture:

- a **Bayer** mosaic as a DNG (:mod:`lfstudio.dataset.dng`; white level = the camera's largest value,
  black level 0, the mosaic's own CFA pattern), so the RAW pipeline develops it unchanged;
- **mono** and **RGB** frames as 16-bit PNG (``.png``, fast zlib level), each value scaled so that the
  camera's largest value is 65535 (8-bit: × 257; 12-bit: × 65535/4095, rounded). Not TIFF: LibRaw opens
  an uncompressed 16-bit TIFF as if it were a camera RAW, and lfstudio decides what a file is by what
  opens it (:mod:`lfstudio.dataset.images`), so processing would have demosaiced a mono picture.

A frame whose layout or sample type is not one of these is refused with :class:`UnstorableFrame`
before anything is written.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lfstudio.dataset.atomic import atomic_write_with
from lfstudio.errors import InputError

LAYOUTS = ("mono", "bayer", "rgb")
PATTERNS = ("RGGB", "GRBG", "GBRG", "BGGR")


class UnstorableFrame(InputError):
    """A frame lfstudio cannot store (its layout, sample type or shape)."""

    kind = "unstorable-frame"


@dataclass(frozen=True)
class Frame:
    """One picture as pixels: ``pixels`` H x W (mono, bayer) or H x W x 3 (rgb, R G B order), uint8 or
    uint16 holding ``bits`` significant bits; ``pattern``: a Bayer mosaic's 2 x 2 colours from its top
    left ("RGGB", ...). ``pixel_format``: the camera's own name of it ("BayerRG8", "Mono12");
    ``timestamp_ns``: the camera's clock when the frame was taken, ``system_timestamp_ns``: this
    computer's (time.time_ns) when it arrived; ``frame_id``: the camera's count; ``lost``: frames or
    packets lost and taken again before this one (reported, never stored); ``settings``: the exposure
    settings as the camera reported them for this frame (exposure_s, gain, ...); ``identity``: model,
    serial, ... for the view's record."""

    pixels: np.ndarray
    layout: str
    bits: int
    pattern: str = ""
    pixel_format: str = ""
    exposure_s: float | None = None
    timestamp_ns: int | None = None
    system_timestamp_ns: int | None = None
    frame_id: int | None = None
    lost: int = 0
    settings: dict[str, Any] = field(default_factory=dict)
    identity: dict[str, Any] = field(default_factory=dict)

    @property
    def size_px(self) -> tuple[int, int]:
        return int(self.pixels.shape[1]), int(self.pixels.shape[0])

    def record(self) -> dict[str, Any]:
        """The view record's ``camera_frame``: when and how the frame was taken (JSON-safe)."""
        rec: dict[str, Any] = {"pixel_format": self.pixel_format or self.layout, "bits": int(self.bits),
                               "size_px": list(self.size_px)}
        for key in ("timestamp_ns", "system_timestamp_ns", "frame_id"):
            value = getattr(self, key)
            if value is not None:
                rec[key] = int(value)
        if self.pattern:
            rec["pattern"] = self.pattern
        if self.lost:
            rec["lost_before"] = int(self.lost)
        return rec


def suffix_for(frame: Frame) -> str:
    """The file suffix :func:`write_frame` uses for ``frame``."""
    return ".dng" if frame.layout == "bayer" else ".png"


def check_frame(frame: Frame, what: str = "frame") -> None:
    """UnstorableFrame naming what is wrong, when :func:`write_frame` could not store ``frame``."""
    px = frame.pixels
    name = frame.pixel_format or frame.layout
    if frame.layout not in LAYOUTS:
        raise UnstorableFrame(what, f"pixel layout {frame.layout!r} ({name}) cannot be stored",
                              "mono, Bayer or RGB frames")
    if px.dtype not in (np.uint8, np.uint16):
        raise UnstorableFrame(what, f"{name}: {px.dtype} samples cannot be stored", "8- or 16-bit samples")
    if not 1 <= int(frame.bits) <= 8 * px.dtype.itemsize:
        raise UnstorableFrame(what, f"{name}: {frame.bits} significant bits in {px.dtype} samples",
                              f"1 … {8 * px.dtype.itemsize} bits")
    want = 3 if frame.layout == "rgb" else 2
    if px.ndim != want or (want == 3 and px.shape[2] != 3) or px.shape[0] < 2 or px.shape[1] < 2:
        raise UnstorableFrame(what, f"{name}: pixel array of shape {px.shape} does not fit its layout "
                              f"{frame.layout}", "H x W x 3 for RGB, H x W for mono and Bayer")
    if frame.layout == "bayer":
        if frame.pattern not in PATTERNS:
            raise UnstorableFrame(what, f"{name}: Bayer pattern {frame.pattern!r} is not known", ", ".join(PATTERNS))
        if px.shape[0] % 2 or px.shape[1] % 2:
            raise UnstorableFrame(what, f"{name}: a Bayer mosaic of {px.shape[1]} x {px.shape[0]} px",
                                  "an even width and height (set the camera's region)")


def to_16_bit(pixels: np.ndarray, bits: int) -> np.ndarray:
    """``pixels`` scaled so that the largest ``bits``-bit value is 65535 (rounded; exact for 8 and 16 bits)."""
    top = (1 << int(bits)) - 1
    if top == 65535:
        return np.ascontiguousarray(pixels, dtype=np.uint16)
    if top == 255 and pixels.dtype == np.uint8:
        return pixels.astype(np.uint16) * np.uint16(257)
    scaled = np.rint(np.minimum(pixels, top).astype(np.float32) * np.float32(65535.0 / top))
    return scaled.astype(np.uint16)


def write_frame(frame: Frame, stem: str | os.PathLike, *, model: str = "", make: str = "") -> Path:
    """Write ``frame`` as ``stem`` + its suffix (see the module docstring), atomically; the path."""
    check_frame(frame)
    stem = Path(stem)
    path = stem.with_name(stem.name + suffix_for(frame))
    if frame.layout == "bayer":
        from lfstudio.dataset.dng import write_dng

        white = (1 << int(frame.bits)) - 1
        return write_dng(path, np.ascontiguousarray(frame.pixels, dtype=np.uint16), black_level=0,
                         white_level=white, bits_per_sample=int(frame.bits),
                         pattern=frame.pattern, as_shot_neutral=(1.0, 1.0, 1.0),
                         camera_model=model or frame.pixel_format or "array camera", make=make or "lfstudio",
                         exposure_s=frame.exposure_s)
    data = to_16_bit(frame.pixels, frame.bits)
    if frame.layout == "rgb":
        data = np.ascontiguousarray(data[:, :, ::-1])          # OpenCV writes B, G, R

    def _write(tmp: Path) -> None:
        import cv2

        if not cv2.imwrite(str(tmp), data, [cv2.IMWRITE_PNG_COMPRESSION, 1]):
            raise OSError(f"{path}: the frame could not be written")

    return atomic_write_with(path, _write)


def preview_rgb(frame: Frame) -> np.ndarray:
    """An RGB picture of ``frame`` for its thumbnail, without decoding its file: mono repeated in three
    channels, a Bayer mosaic at half size (one pixel per 2 x 2 cell, its greens averaged); 8-bit samples
    as they are, others scaled to 16 bits."""
    px = frame.pixels if frame.pixels.dtype == np.uint8 and frame.bits == 8 else to_16_bit(frame.pixels, frame.bits)
    if frame.layout == "mono":
        return np.dstack([px, px, px])
    if frame.layout == "bayer":
        h, w = (px.shape[0] // 2) * 2, (px.shape[1] // 2) * 2
        cells = {frame.pattern[i]: [] for i in range(4)}
        for i, colour in enumerate(frame.pattern):
            dy, dx = divmod(i, 2)
            cells[colour].append(px[dy:h:2, dx:w:2].astype(np.uint32))
        out = [sum(cells[c]) // len(cells[c]) for c in "RGB"]
        return np.dstack(out).astype(px.dtype)
    return px
