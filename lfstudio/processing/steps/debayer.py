"""Step 1: RAW → linear 16-bit RGB with rawpy (LibRaw); ordinary PNG/TIFF images are read as they are.

Linear output: ``gamma=(1, 1)``, ``no_auto_bright``, ``output_bps=16``; the RAW's white level maps
to 65535. The RAW's orientation tag is applied, as the calibration does when it reads the views.

Demosaic ``auto`` (the default) lets the worker demosaic at the resolution the output needs: when
the output is at most half the capture's size and the RAW is an RGB Bayer mosaic, :func:`read_bayer`
gives the mosaic with LibRaw's black level, white balance and scaling applied (LibRaw unpacks it,
we scale it: same numbers as LibRaw's own output), the luminance comes from OpenCV's edge-aware
demosaic at full resolution and the colour differences (R − G, B − G) from the Bayer sites
themselves at half resolution (see :mod:`lfstudio.processing.worker`). Measured against the virtual
studio's ground truth this is at least as close as LibRaw's AHD and ~4× faster
(``benchmarks/processing_quality.py``). A full-resolution decode (:func:`decode`) with ``auto`` is
LibRaw's AHD.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from lfstudio.errors import DatasetError
from lfstudio.processing.profile import DebayerStep

RAW_SUFFIXES = frozenset({".dng", ".arw", ".cr2", ".cr3", ".nef", ".nrw", ".raf", ".orf", ".rw2",
                          ".pef", ".srw", ".raw", ".3fr", ".iiq", ".erf", ".mos", ".x3f"})


#: the LibRaw algorithm a full-resolution decode uses for each profile choice that is not one
FULL_SIZE_DEMOSAIC = {"auto": "AHD"}


def is_raw(path: str | Path) -> bool:
    return Path(path).suffix.lower() in RAW_SUFFIXES


def processing_scale(path: str | Path, step: DebayerStep) -> float:
    """Size of the decoded image relative to the full-resolution capture (0.5 with half_size RAW)."""
    return 0.5 if step.enabled and step.half_size and is_raw(path) else 1.0


def _params(step: DebayerStep):
    import rawpy

    # adjust_maximum_thr=0: scale by the RAW's white level, never by the image's own maximum (LibRaw's
    # default rescales images with clipped pixels: a brightness jump between views of one scene)
    kw = dict(gamma=(1, 1), no_auto_bright=True, output_bps=16, adjust_maximum_thr=0.0,
              half_size=step.half_size,
              output_color=rawpy.ColorSpace.raw if step.color_space == "raw" else rawpy.ColorSpace.sRGB,
              demosaic_algorithm=getattr(rawpy.DemosaicAlgorithm, FULL_SIZE_DEMOSAIC.get(step.demosaic, step.demosaic)))
    if step.white_balance == "camera":
        kw["use_camera_wb"] = True
    elif step.white_balance == "fixed":
        kw["user_wb"] = [float(v) for v in step.wb_multipliers]
    return rawpy.Params(**kw)


def full_size_px(path: str | Path) -> tuple[int, int]:
    """(width, height) of the full-resolution image the file decodes to (without half_size)."""
    path = Path(path)
    if is_raw(path):
        import rawpy

        try:
            with rawpy.imread(str(path)) as raw:
                w, h = int(raw.sizes.width), int(raw.sizes.height)
                return (h, w) if raw.sizes.flip in (5, 6) else (w, h)  # portrait orientation tag
        except Exception as exc:
            raise DatasetError(f"{path}: cannot be read as a RAW file ({exc}); re-capture or remove the view") from None
    img = read_image(path)
    return int(img.shape[1]), int(img.shape[0])


def read_image(path: str | Path) -> np.ndarray:
    """A PNG/TIFF/JPEG as (h, w, 3) uint16 RGB (8-bit images scaled by 257)."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DatasetError(f"{path}: cannot be read as an image; check the file or re-capture the view")
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    else:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    if img.dtype == np.uint8:
        img = img.astype(np.uint16) * 257
    elif img.dtype != np.uint16:
        img = np.clip(img.astype(np.float64) * (65535.0 if img.dtype.kind == "f" else 1.0), 0, 65535) \
            .astype(np.uint16)
    return img


def decode(path: str | Path, step: DebayerStep) -> np.ndarray:
    """(h, w, 3) uint16 linear RGB of one capture."""
    path = Path(path)
    if not is_raw(path):
        return read_image(path)
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:
            return raw.postprocess(_params(step))
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot be decoded as a RAW file ({type(exc).__name__}: {exc}); "
                           "re-capture the view or remove it from the dataset") from None


# -- the mosaic itself (demosaic at the resolution the output needs) ---------------------------------
#: OpenCV's edge-aware Bayer conversion to RGB for each 2 x 2 pattern (top-left colours, R G B);
#: OpenCV names a pattern by its second row's second and third pixels
_EA_CODES = {"RGGB": cv2.COLOR_BayerBG2RGB_EA, "BGGR": cv2.COLOR_BayerRG2RGB_EA,
             "GRBG": cv2.COLOR_BayerGB2RGB_EA, "GBRG": cv2.COLOR_BayerGR2RGB_EA}
#: LibRaw's orientation codes we turn the mosaic for (3: 180 degrees, 5: 90 counter-clockwise, 6: 90 clockwise)
_ROTATIONS = {3: cv2.ROTATE_180, 5: cv2.ROTATE_90_COUNTERCLOCKWISE, 6: cv2.ROTATE_90_CLOCKWISE}


@dataclass
class Bayer:
    """An RGB Bayer mosaic in display orientation, black level subtracted, white-balanced and
    scaled as LibRaw scales its 16-bit output (uint16, saturated), plus what it takes to finish it."""

    mosaic: np.ndarray       # (h, w) uint16
    pattern: str             # colours of the top-left 2 x 2 block, row by row: "RGGB", "GRBG", ...
    rgb_cam: np.ndarray      # 3 x 3: camera RGB -> output RGB (identity for color_space "raw")

    def site(self, colour: str) -> tuple[int, int]:
        """(dy, dx) of ``colour`` ("R" or "B") in the 2 x 2 block."""
        return divmod(self.pattern.index(colour), 2)

    @property
    def ea_code(self) -> int:
        return _EA_CODES[self.pattern]


def _white_balance(raw, step: DebayerStep) -> np.ndarray:
    """LibRaw's channel multipliers (R G B G2) for the profile's white balance setting."""
    if step.white_balance == "fixed":
        mul = np.array(step.wb_multipliers, np.float64)
    else:
        mul = np.array(raw.daylight_whitebalance, np.float64)
        if step.white_balance == "camera":
            cam = np.array(raw.camera_whitebalance, np.float64)
            if cam[0] > 0 and cam[1] > 0 and cam[2] > 0:
                mul = cam
    if mul[1] <= 0:
        mul[1] = 1.0
    if mul[3] <= 0:
        mul[3] = mul[1]
    return mul


def read_bayer(path: str | Path, step: DebayerStep, out: np.ndarray | None = None) -> Bayer | None:
    """The capture's :class:`Bayer` mosaic, written into ``out`` when it has the right shape (a
    buffer reused across views); None when the file is not an RGB Bayer RAW this can handle (then
    decode it with LibRaw, :func:`decode`)."""
    path = Path(path)
    if not is_raw(path):
        return None
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:
            desc = raw.color_desc.decode("ascii", "replace")
            pattern_idx = np.asarray(raw.raw_pattern)
            if raw.raw_type != rawpy.RawType.Flat or desc not in ("RGBG", "RGB") or pattern_idx.shape != (2, 2) \
                    or raw.sizes.pixel_aspect != 1.0 or raw.sizes.flip not in (0, *_ROTATIONS):
                return None
            pattern = "".join("RGBG"[int(i)] for i in pattern_idx.ravel())
            if pattern not in _EA_CODES:
                return None
            visible = raw.raw_image_visible
            h, w = visible.shape
            if h % 2 or w % 2:
                return None
            black = np.asarray(raw.black_level_per_channel, np.float64)
            white = float(raw.white_level)
            mul = _white_balance(raw, step)
            # LibRaw's scale_colors (highlight mode clip): (raw - black_c) * mul_c / min(mul) * 65535 / (white - black)
            scale = mul / mul.min() * 65535.0 / max(white - black.min(), 1.0)
            rgb_cam = np.eye(3) if step.color_space == "raw" else np.asarray(raw.color_matrix, np.float64)[:, :3]
            flip = raw.sizes.flip
            mosaic = out if flip == 0 and out is not None and out.shape == (h, w) and out.dtype == np.uint16 \
                else np.empty((h, w), np.uint16)
            pairs_in = visible.reshape(h, w // 2, 2)          # (even column, odd column) as two channels
            pairs_out = mosaic.reshape(h, w // 2, 2)
            for dy in (0, 1):
                c0, c1 = (int(pattern_idx[dy, dx]) for dx in (0, 1))
                M = np.array([[scale[c0], 0.0, -black[c0] * scale[c0]], [0.0, scale[c1], -black[c1] * scale[c1]]])
                cv2.transform(pairs_in[dy::2], M, dst=pairs_out[dy::2])   # rounded, saturated to 0..65535
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot be decoded as a RAW file ({type(exc).__name__}: {exc}); "
                           "re-capture the view or remove it from the dataset") from None
    if flip:
        mosaic = cv2.rotate(mosaic, _ROTATIONS[flip])
        pattern = _rotate_pattern(pattern, flip)
    return Bayer(mosaic, pattern, rgb_cam)


def demosaic_ea(bayer: Bayer, dst: np.ndarray | None = None) -> np.ndarray:
    """Full-resolution camera RGB (uint16) of ``bayer`` by OpenCV's edge-aware demosaic."""
    return cv2.cvtColor(bayer.mosaic, bayer.ea_code, dst=dst)


def output_rgb(camera_rgb: np.ndarray, rgb_cam: np.ndarray) -> np.ndarray:
    """Camera RGB (uint16) through the colour matrix, rounded and saturated (what LibRaw outputs)."""
    if np.allclose(rgb_cam, np.eye(3)):
        return camera_rgb
    return cv2.transform(camera_rgb, np.asarray(rgb_cam, np.float64))


def _rotate_pattern(pattern: str, flip: int) -> str:
    block = np.array(list(pattern)).reshape(2, 2)
    turned = {3: np.rot90(block, 2), 5: np.rot90(block, 1), 6: np.rot90(block, -1)}[flip]
    return "".join(turned.ravel())
