"""Test helper: render small views of a layered, textured scene with a known orientation error.

Each layer is a fronto-parallel textured plane at a depth (rig frame: x right, y down, z into the
scene); a view is composed back to front with cv2.warpPerspective. The camera model is the one of
``lfstudio.calibration.model``: p ~ K_true · R · (X − C).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from lfstudio.calibration.model import intrinsics, nominal_principal_point, rotation_matrix
from lfstudio.dataset import Dataset


def texture(rng: np.random.Generator, size: int) -> np.ndarray:
    img = np.zeros((size, size), np.float32)
    for cell in (3, 9, 27, 81):
        noise = rng.random((size // cell + 2, size // cell + 2)).astype(np.float32)
        img += cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC)[:size, :size] * cell ** 0.5
    img -= img.min()
    return (img / img.max() * 235 + 10).astype(np.uint8)


class LayeredScene:
    def __init__(self, seed: int = 0, depths_m=(4.0, 2.6, 1.8), half_width_m=(2.6, 1.6, 1.0), texels=900):
        rng = np.random.default_rng(seed)
        self.layers = []
        for i, (z, hw) in enumerate(zip(depths_m, half_width_m)):
            tex = texture(rng, texels)
            mask = np.full((texels, texels), 255, np.uint8)
            if i > 0:  # nearer layers are a few blobs, so deeper ones show through
                mask[:] = 0
                for _ in range(5):
                    c = rng.integers(100, texels - 100, 2)
                    cv2.circle(mask, (int(c[0]), int(c[1])), int(rng.integers(60, 160)), 255, -1)
            self.layers.append((float(z), float(hw), tex, mask))

    def render(self, centre_m, rotation_deg, focal_length_px, size_px, pp_offset_px=(0.0, 0.0)) -> np.ndarray:
        w, h = size_px
        K = intrinsics(focal_length_px, nominal_principal_point(size_px) + np.asarray(pp_offset_px, float))
        R = rotation_matrix(rotation_deg)
        C = np.asarray(centre_m, float)
        out = np.zeros((h, w), np.float32)
        for z, hw, tex, mask in self.layers:
            n = tex.shape[0]
            s = 2 * hw / n
            # texel (i, j) centre -> world (x0 + (i+0.5)s, y0 + (j+0.5)s, z)
            x0 = y0 = -hw
            A = np.array([[s, 0, x0 + 0.5 * s - C[0]], [0, s, y0 + 0.5 * s - C[1]], [0, 0, z - C[2]]])
            Ht = K @ R @ A
            col = cv2.warpPerspective(tex, Ht, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            alpha = cv2.warpPerspective(mask, Ht, (w, h), flags=cv2.INTER_LINEAR,
                                        borderMode=cv2.BORDER_CONSTANT).astype(np.float32) / 255.0
            out = out * (1 - alpha) + col.astype(np.float32) * alpha
        return np.clip(out, 0, 255).astype(np.uint8)


def make_layered_dataset(root: Path, columns=3, rows=2, spacing_mm=(100.0, 60.0), size_px=(800, 534),
                         rotation_deg=(1.0, -1.5, 2.0), pp_offset_px=(0.0, 0.0), position_noise_um=0.0,
                         seed=0, scene: LayeredScene | None = None, fmt="png") -> Dataset:
    """A dataset of rendered PNG views (focal length 50 mm, pitch chosen so f ≈ 1111 px at 800 px)."""
    w, h = size_px
    pitch_um = 45.0 * 800 / w
    camera = {"name": "synthetic", "sensor_px": [w, h], "pixel_pitch_um": pitch_um,
              "sensor_mm": [w * pitch_um / 1000, h * pitch_um / 1000]}
    lens = {"name": "synthetic 50", "focal_length_mm": 50.0}
    grid = {"columns": columns, "rows": rows, "spacing_mm": list(spacing_mm), "order": "row-meander"}
    ds = Dataset.create(root, camera=camera, lens=lens, grid=grid,
                        ground_truth={"rotation_deg": list(rotation_deg), "pp_offset_px": list(pp_offset_px)})
    f = 50.0 / (pitch_um / 1000.0)
    scene = scene or LayeredScene(seed)
    rng = np.random.default_rng(seed + 1)
    for v in ds.views:
        r, c = v["row"], v["column"]
        centre = np.array([c * spacing_mm[0], r * spacing_mm[1], 0.0]) / 1000.0
        centre[:2] += rng.normal(0.0, position_noise_um * 1e-6, 2)
        img = scene.render(centre, rotation_deg, f, size_px, pp_offset_px)
        name = ds.raw_name(r, c, "." + fmt)
        cv2.imwrite(str(ds.root / name), img)
        v.update(file=name, status="done", commanded_mm=[c * spacing_mm[0], r * spacing_mm[1]])
    ds.save()
    return ds
