"""A minimal Bayer DNG writer (uncompressed, one IFD) that rawpy/LibRaw reads back bit-exact.

The simulated camera writes its RAW files with it (:mod:`lfstudio.sim.dng` makes its mosaics), and
the scan's store stage writes the Bayer frames of array cameras (GenICam) with it
(:mod:`lfstudio.dataset.frames`); the processing stage reads them with rawpy like any camera's RAW.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from lfstudio.dataset.atomic import atomic_write_with

#: linear sRGB (D65) -> XYZ
SRGB_TO_XYZ = np.array([[0.4124564, 0.3575761, 0.1804375],
                        [0.2126729, 0.7151522, 0.0721750],
                        [0.0193339, 0.1191920, 0.9503041]])
#: DNG ColorMatrix1 (XYZ -> camera) of a camera whose native space is linear sRGB primaries
XYZ_TO_SRGB = np.linalg.inv(SRGB_TO_XYZ)

#: channel sensitivities of the simulated sensor (R, G, B), relative to green; also AsShotNeutral
DEFAULT_NEUTRAL = (0.52, 1.0, 0.71)

CFA_COLOURS = {"R": 0, "G": 1, "B": 2}

# DNG / TIFF-EP tag codes
_MAKE = 271
_MODEL = 272
_ORIENTATION = 274
_CFA_REPEAT_PATTERN_DIM = 33421
_CFA_PATTERN = 33422
_EXPOSURE_TIME = 33434
_FNUMBER = 33437
_ISO = 34855
_DNG_VERSION = 50706
_DNG_BACKWARD_VERSION = 50707
_UNIQUE_CAMERA_MODEL = 50708
_BLACK_LEVEL = 50714
_WHITE_LEVEL = 50717
_COLOR_MATRIX1 = 50721
_AS_SHOT_NEUTRAL = 50728
_CALIBRATION_ILLUMINANT1 = 50778
_PHOTOMETRIC_CFA = 32803


def _rational(values: Iterable[float], denominator: int = 10000) -> list[int]:
    out: list[int] = []
    for v in values:
        out += [int(round(float(v) * denominator)), denominator]
    return out


def write_dng(path: str | os.PathLike, mosaic: np.ndarray, *, black_level: int = 512,
              white_level: int = 16383, bits_per_sample: int = 14, pattern: str = "RGGB",
              color_matrix1: np.ndarray | None = None, as_shot_neutral: Sequence[float] = DEFAULT_NEUTRAL,
              camera_model: str = "lfstudio Virtual Studio", make: str = "lfstudio",
              exposure_s: float | None = None, f_number: float | None = None, iso: int | None = None,
              description: str | None = None, orientation: int | None = None) -> Path:
    """Write ``mosaic`` (H x W uint16 Bayer data) as an uncompressed DNG at ``path``, atomically.

    ``color_matrix1`` is the DNG ColorMatrix1 (XYZ -> camera, D65); default: a camera whose native
    primaries are linear sRGB. ``as_shot_neutral`` is the camera-space colour of a neutral grey.
    ``orientation``: the TIFF Orientation tag (e.g. 6: display rotated 90 degrees clockwise).
    The samples are stored in 16-bit words (``bits_per_sample`` only bounds the levels): packed
    14-bit TIFF strips are not written by tifffile. Returns the path.
    """
    import tifffile

    mosaic = np.asarray(mosaic)
    if mosaic.ndim != 2:
        raise ValueError(f"mosaic must be a 2-D array, got shape {mosaic.shape}")
    if mosaic.dtype != np.uint16:
        raise ValueError(f"mosaic must be uint16, got {mosaic.dtype}")
    if not 0 <= black_level < white_level < 2 ** bits_per_sample:
        raise ValueError(f"need 0 <= black_level < white_level < 2**{bits_per_sample}, "
                         f"got {black_level}, {white_level}")
    cm = XYZ_TO_SRGB if color_matrix1 is None else np.asarray(color_matrix1, dtype=float)
    cfa = bytes(CFA_COLOURS[c] for c in pattern.upper())
    tags = [
        (_MAKE, "s", 0, make, True),
        (_MODEL, "s", 0, camera_model, True),
        (_CFA_REPEAT_PATTERN_DIM, "H", 2, (2, 2), True),
        (_CFA_PATTERN, "B", 4, cfa, True),
        (_DNG_VERSION, "B", 4, (1, 4, 0, 0), True),
        (_DNG_BACKWARD_VERSION, "B", 4, (1, 1, 0, 0), True),
        (_UNIQUE_CAMERA_MODEL, "s", 0, camera_model, True),
        (_BLACK_LEVEL, "I", 1, (int(black_level),), True),
        (_WHITE_LEVEL, "I", 1, (int(white_level),), True),
        (_COLOR_MATRIX1, "2i", 9, _rational(cm.ravel()), True),
        (_CALIBRATION_ILLUMINANT1, "H", 1, (21,), True),          # D65
        (_AS_SHOT_NEUTRAL, "2I", 3, _rational(as_shot_neutral), True),
    ]
    if orientation is not None:
        tags.append((_ORIENTATION, "H", 1, (int(orientation),), True))
    if exposure_s is not None:
        tags.append((_EXPOSURE_TIME, "2I", 1, _rational([exposure_s], 1_000_000), True))
    if f_number is not None:
        tags.append((_FNUMBER, "2I", 1, _rational([f_number], 100), True))
    if iso is not None:
        tags.append((_ISO, "H", 1, (int(iso),), True))

    def _write(tmp: Path) -> None:
        tifffile.imwrite(tmp, mosaic, photometric=_PHOTOMETRIC_CFA,
                         compression=None, metadata=None, software="lfstudio",
                         description=description, extratags=tags)

    return atomic_write_with(path, _write)
