"""Fixtures for the processing tests: small real datasets of DNG (or PNG) captures on disk."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from lfstudio.dataset import Dataset
from lfstudio.sim.dng import mosaic_from_rgb, write_dng


def write_bayer_dng(path, rgb_linear: np.ndarray) -> None:
    """A 14-bit RGGB DNG of a linear RGB image (1 = clipping), through the simulated camera's writer."""
    write_dng(path, mosaic_from_rgb(rgb_linear), as_shot_neutral=(0.52, 1.0, 0.71))


def scene(w: int, h: int, seed: int = 0) -> np.ndarray:
    """A smooth, textured linear RGB test scene in [0.1, 0.7] (float32, (h, w, 3))."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    img = np.empty((h, w, 3), np.float32)
    img[..., 0] = 0.4 + 0.2 * np.sin(xx / 7.0 + 0.3) * np.cos(yy / 9.0)
    img[..., 1] = 0.4 + 0.2 * np.cos(xx / 11.0) * np.sin(yy / 5.0 + 1.0)
    img[..., 2] = 0.4 + 0.2 * np.sin((xx + yy) / 8.0)
    blobs = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 3)
    img += (blobs - blobs.mean())[..., None] * 0.5
    return np.clip(img, 0.1, 0.7)


def warp_to_capture(img: np.ndarray, H: np.ndarray) -> np.ndarray:
    """The capture whose rectification by H (capture pixel -> rectified pixel) gives ``img``."""
    h, w = img.shape[:2]
    return cv2.warpPerspective(img, np.linalg.inv(H), (w, h), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REFLECT)


@pytest.fixture
def make_dataset(tmp_path):
    """``make_dataset(rows, cols, w, h, gains={(r, c): g}, H=None, fmt="dng", vignette=None)`` -> Dataset.

    Every view shows the same scene (so per-view answers are known) times its gain, times an
    optional vignetting factor map, optionally warped so that ``H`` rectifies it.
    """

    def make(rows=1, cols=3, w=96, h=64, gains=None, H=None, fmt="dng", vignette=None, name="ds",
             scene_img=None):
        root = tmp_path / name
        ds = Dataset.create(root, camera={"name": "Test Cam", "sensor_px": [w, h], "pixel_pitch_um": 4.0},
                            lens={"name": "Test 50mm", "focal_length_mm": 50.0},
                            grid={"columns": cols, "rows": rows, "spacing_mm": [4.0, 6.0], "order": "row-meander"})
        base = scene(w, h) if scene_img is None else scene_img
        if vignette is not None:
            base = base * vignette[..., None]
        if H is not None:
            base = warp_to_capture(base, np.asarray(H, float))
            (root / "calibration.json").write_text(json.dumps(
                {"homography": np.asarray(H, float).tolist(), "image_size_px": [w, h], "rotation_deg": [0, 0, 0],
                 "principal_point_px": [(w - 1) / 2, (h - 1) / 2], "focal_length_px": 1000.0}))
        for v in ds.views:
            g = (gains or {}).get((v["row"], v["column"]), 1.0)
            img = base * g
            if fmt == "dng":
                rel = ds.raw_name(v["row"], v["column"], ".dng")
                write_bayer_dng(ds.root / rel, img)
            else:
                rel = ds.raw_name(v["row"], v["column"], ".png")
                u16 = (np.clip(img, 0, 1) * 65535 + 0.5).astype(np.uint16)
                cv2.imwrite(str(ds.root / rel), cv2.cvtColor(u16, cv2.COLOR_RGB2BGR))
            v.update(file=rel, status="done", sha256=None)
        ds.save()
        return Dataset.open(root)

    return make
