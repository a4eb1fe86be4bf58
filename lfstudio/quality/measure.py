"""What one view's own pixels say: focus energy, brightness, clipping, and the corners to track.

A view is read once (:func:`read_luminance`: a RAW file's white-balanced Bayer mosaic averaged over
each 2 x 2 block — LibRaw's half-size resolution, no demosaicing —; PNG/TIFF/JPEG as the processing
stage reads them) and measured:

* **focus** — the energy of the Laplacian of the lightly smoothed, brightness-normalised
  ``sqrt(luminance)`` image in a grid of tiles (:data:`TILES`), at the read resolution (at most
  ``focus_max_width_px`` wide). Dividing by the image's median brightness makes it independent of
  exposure; comparing tiles with the same tiles of the neighbouring views (which see nearly the
  same scene) makes it independent of scene content (:func:`sharpness_ratio`);
* **brightness** — the median linear luminance (0 … 1 of full scale), and the de-flicker step's
  small luminance image for the gain against the reference view;
* **clipping** — the fraction of pixels at ≥ 98 % of full scale after white balance (RAW: of the
  mosaic's pixels, as LibRaw clips them; images: with a colour channel there), and of crushed pixels
  (≤ 0.2 % of full scale);
* **corners** for tracking: ``cv2.goodFeaturesToTrack`` on an 8-bit working image (``sqrt``
  luminance stretched between its 0.5 and 99.8 percentiles, so a brighter view looks the same)
  at most ``work_width_px`` wide.

Coordinates of the working image relate to the full-resolution capture by ``work_scale`` (full
pixels per working pixel; pixel centres at integers: ``x_full = (x_work + 0.5)·s − 0.5``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from lfstudio.dataset import images
from lfstudio.dataset.manifest import FrameRecord
from lfstudio.dataset.profile import DebayerStep, DeflickerStep
from lfstudio.processing.steps import deflicker

#: focus tiles across and down
TILES = (8, 6)
DEFAULT_WORK_WIDTH_PX = 1000
DEFAULT_FOCUS_MAX_WIDTH_PX = 4000
MAX_CORNERS = 600
CLIP_LEVEL = 0.98
CRUSH_LEVEL = 0.002
_LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)
_DEFLICKER = DeflickerStep()


@dataclass
class ViewMeasures:
    """One view's pixel measurements and its working image (``grey8``, dropped once tracked)."""

    row: int
    column: int
    full_size_px: tuple[int, int]      # (w, h) of the full-resolution capture
    work_scale: float                  # full-resolution pixels per working pixel
    focus_tiles: np.ndarray            # TILES[1] x TILES[0] focus energy
    level: float                       # median linear luminance, 0 … 1
    clipped_fraction: float
    crushed_fraction: float
    small_luminance: np.ndarray | None  # de-flicker step's reduced luminance (dropped once used)
    corners: np.ndarray                # (n, 2) float32, working-image pixels
    grey8: np.ndarray | None           # working image (uint8)
    #: an exposure-bracketed view: each frame's (exposure s, clipped share, crushed share), frame order
    frames: list[tuple[float, float, float]] | None = None

    @property
    def cell(self) -> tuple[int, int]:
        return self.row, self.column

    @property
    def work_size_px(self) -> tuple[int, int]:
        assert self.grey8 is not None
        return int(self.grey8.shape[1]), int(self.grey8.shape[0])


@dataclass
class Luminance:
    """A view's linear luminance (0 … 1 of full scale) and its clipping, from one read of the file."""

    image: np.ndarray                  # (h, w) float32; RAW: one value per 2 x 2 Bayer block
    full_size_px: tuple[int, int]      # (w, h) of the full-resolution capture
    clipped_fraction: float
    crushed_fraction: float


#: how RAW views are read: camera white balance, camera colours (no matrix: luminance only)
_BAYER = DebayerStep(color_space="raw", half_size=True)


def _rgb_luminance(rgb16: np.ndarray, full_size_px: tuple[int, int]) -> Luminance:
    peak = cv2.max(cv2.max(rgb16[..., 0], rgb16[..., 1]), rgb16[..., 2])   # numpy's max(axis=2) is 10x slower
    clipped = float(np.count_nonzero(peak >= int(CLIP_LEVEL * 65535))) / peak.size
    crushed = float(np.count_nonzero(peak <= int(CRUSH_LEVEL * 65535))) / peak.size
    lum = rgb16.astype(np.float32) @ (_LUMA / np.float32(65535.0))
    return Luminance(lum, full_size_px, clipped, crushed)


def _raw_luminance(path: Path) -> Luminance:
    bayer = images.read_bayer(path, _BAYER)
    if bayer is None:            # not an RGB Bayer mosaic: LibRaw develops it at half size
        return _rgb_luminance(images.develop(path, _BAYER), images.full_size_px(path))
    mosaic = bayer.mosaic
    h, w = mosaic.shape
    clipped = float(np.count_nonzero(mosaic >= int(CLIP_LEVEL * 65535))) / mosaic.size
    # the mean of each white-balanced 2 x 2 Bayer block (R + 2 G + B) / 4: luminance without demosaicing
    quads = cv2.resize(mosaic, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    lum = quads.astype(np.float32) * np.float32(1.0 / 65535.0)
    crushed = float(np.count_nonzero(quads <= int(CRUSH_LEVEL * 65535))) / quads.size
    return Luminance(lum, (w, h), clipped, crushed)


def read_luminance(path: str | Path) -> Luminance:
    """Linear luminance of a view file. RAW: the processing stage's white-balanced Bayer mosaic
    (:func:`lfstudio.dataset.images.read_bayer`) averaged over each 2 x 2 block — the
    resolution of LibRaw's half-size mode, no demosaicing —; PNG/TIFF/JPEG as the processing stage
    reads them, Rec. 709 luminance."""
    path = Path(path)
    if images.is_raw(path):
        return _raw_luminance(path)
    rgb16 = images.read_image(path)
    return _rgb_luminance(rgb16, (int(rgb16.shape[1]), int(rgb16.shape[0])))


def _resize_to_width(img: np.ndarray, width_px: int) -> np.ndarray:
    h, w = img.shape[:2]
    if w <= width_px:
        return img
    return cv2.resize(img, (int(width_px), max(1, int(round(h * width_px / w)))), interpolation=cv2.INTER_AREA)


def focus_tiles(root_luminance: np.ndarray) -> np.ndarray:
    """Tile energies of the Laplacian of ``root_luminance`` (``sqrt`` of linear luminance)."""
    g = root_luminance
    med = float(np.median(g[::4, ::4]))
    g = g * np.float32(1.0 / max(med, 1e-4))
    lap = cv2.Laplacian(cv2.GaussianBlur(g, (0, 0), 0.8), cv2.CV_32F, ksize=1)
    return cv2.resize(lap * lap, TILES, interpolation=cv2.INTER_AREA).astype(np.float64)


def working_grey8(root_luminance: np.ndarray) -> np.ndarray:
    sub = root_luminance[::4, ::4]
    lo, hi = (float(x) for x in np.percentile(sub, (0.5, 99.8)))
    if hi <= lo:
        hi = lo + 1e-3
    out = (root_luminance - np.float32(lo)) * np.float32(255.0 / (hi - lo))
    return np.clip(out, 0.0, 255.0, out=out).astype(np.uint8)


def detect_corners(grey8: np.ndarray, max_corners: int = MAX_CORNERS) -> np.ndarray:
    min_distance = max(4.0, grey8.shape[1] / 125.0)
    c = cv2.goodFeaturesToTrack(grey8, maxCorners=int(max_corners), qualityLevel=0.01, minDistance=min_distance,
                                blockSize=7)
    if c is None:
        return np.zeros((0, 2), np.float32)
    return c.reshape(-1, 2).astype(np.float32)


def measure_view(path: str | Path, row: int, column: int, *, work_width_px: int = DEFAULT_WORK_WIDTH_PX,
                 focus_max_width_px: int = DEFAULT_FOCUS_MAX_WIDTH_PX) -> ViewMeasures:
    """Decode the view at ``path`` and measure it (raises :class:`lfstudio.errors.DatasetError`
    naming the file when it cannot be read)."""
    lum = read_luminance(path)
    full = lum.full_size_px
    image = _resize_to_width(lum.image, focus_max_width_px)
    level = float(np.median(image[::4, ::4]))
    small = deflicker.small_luminance(image * np.float32(65535.0), _DEFLICKER.size_px)
    root = np.sqrt(np.maximum(image, 0.0), dtype=np.float32)
    tiles = focus_tiles(root)
    grey8 = working_grey8(_resize_to_width(root, work_width_px))
    return ViewMeasures(row=int(row), column=int(column), full_size_px=(int(full[0]), int(full[1])),
                        work_scale=float(full[0]) / float(grey8.shape[1]), focus_tiles=tiles, level=level,
                        clipped_fraction=lum.clipped_fraction, crushed_fraction=lum.crushed_fraction,
                        small_luminance=small, corners=detect_corners(grey8), grey8=grey8)


def bracket_frames(frames: Sequence[FrameRecord] | None, path_of: Callable[[str], Path | str]
                   ) -> list[tuple[float, Path]]:
    """An exposure-bracketed view's frames as (exposure s, path), capture order, from its manifest
    record's ``frames`` (``file``, the ``exposure_s`` the camera reported, else the ``shutter_s`` set);
    ``path_of(file)`` resolves a file inside the dataset. [] for a view of one picture."""
    frames = frames or ()
    if len(frames) < 2:
        return []
    return [(float(f.get("exposure_s") or f.get("shutter_s") or 0.0), Path(path_of(f["file"]))) for f in frames]


def with_frames(m: ViewMeasures, frames: list[tuple[float, Path]], view_path: str | Path) -> ViewMeasures:
    """``m`` (the view's reference frame, read from ``view_path``) with each frame's clipped and
    crushed shares (``m.frames``), so the clipping check judges what the HDR merge keeps
    (:func:`lfstudio.quality.verdicts.bracket_clipping`). The one implementation for ``lfstudio
    check`` and the scan-time check; the reference frame is not read twice."""
    if not frames:
        return m
    out = []
    for t, p in frames:
        if Path(p) == Path(view_path):
            shares = (m.clipped_fraction, m.crushed_fraction)
        else:
            lum = read_luminance(p)
            shares = (lum.clipped_fraction, lum.crushed_fraction)
        out.append((t, *shares))
    m.frames = out
    return m


def sharpness_ratio(view: ViewMeasures, neighbours: list[ViewMeasures]) -> float | None:
    """The view's focus energy relative to its neighbours' (1 = as sharp; 0.5 = half the detail
    energy), over the tiles where the neighbours hold more detail than the median tile; None
    without neighbours."""
    if not neighbours:
        return None
    ref = np.median(np.stack([n.focus_tiles for n in neighbours]), axis=0)
    textured = ref >= np.median(ref)
    if not textured.any() or float(ref[textured].sum()) <= 0:
        return None
    ratios = view.focus_tiles[textured] / np.maximum(ref[textured], 1e-12)
    return float(np.median(ratios))


def exposure_ratio(view: ViewMeasures, neighbours: list[ViewMeasures]) -> float | None:
    """The view's median luminance over its neighbours' median (1 = as bright)."""
    levels = [n.level for n in neighbours if n.level > 0]
    if not levels or view.level <= 0:
        return None
    return float(view.level / np.median(levels))


def deflicker_gain(reference: ViewMeasures, view: ViewMeasures, step: DeflickerStep = _DEFLICKER) -> float:
    """The gain the processing stage's de-flicker ``step`` would apply to ``view`` (both must still
    hold their reduced luminance)."""
    if reference.small_luminance is None or view.small_luminance is None:
        raise ValueError(f"de-flicker gain of row {view.row}, column {view.column}: a reduced luminance was "
                         "already dropped")
    return float(deflicker.gain(reference.small_luminance, view.small_luminance, step)[0])
