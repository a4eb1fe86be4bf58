"""Temporary Bayer DNG writer for tests (until lfstudio.sim.dng lands on main)."""

from __future__ import annotations

import numpy as np
import tifffile


def write_bayer_dng(path, rgb_linear: np.ndarray, black: int = 512, white: int = 16383) -> None:
    """Write an RGGB Bayer DNG from a linear float RGB image in [0, 1] (h, w even)."""
    h, w, _ = rgb_linear.shape
    v = np.clip(rgb_linear, 0, 1) * (white - black) + black
    cfa = np.empty((h, w), np.uint16)
    cfa[0::2, 0::2] = v[0::2, 0::2, 0]
    cfa[0::2, 1::2] = v[0::2, 1::2, 1]
    cfa[1::2, 0::2] = v[1::2, 0::2, 1]
    cfa[1::2, 1::2] = v[1::2, 1::2, 2]
    ident = [(1, 1), (0, 1), (0, 1), (0, 1), (1, 1), (0, 1), (0, 1), (0, 1), (1, 1)]
    extratags = [
        (33421, "H", 2, (2, 2), True),
        (33422, "B", 4, (0, 1, 1, 2), True),
        (50706, "B", 4, (1, 4, 0, 0), True),
        (50707, "B", 4, (1, 1, 0, 0), True),
        (50708, "s", 0, "lfstudio test", True),
        (50714, "H", 1, black, True),
        (50717, "H", 1, white, True),
        (50721, "2i", 9, [x for pair in ident for x in pair], True),
        (50778, "H", 1, 21, True),
        (50728, "2I", 3, (1, 1, 1, 1, 1, 1), True),
    ]
    tifffile.imwrite(path, cfa, photometric=32803, extratags=extratags)
