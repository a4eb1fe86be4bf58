"""The depth tests' datasets: tiny virtual light fields with an exact calibration.json."""

from __future__ import annotations

import pytest

from lfstudio.calibration.model import rectifying_homography
from lfstudio.dataset import Dataset
from lfstudio.dataset.atomic import atomic_write_json
from lfstudio.sim.virtual_dataset import load_ground_truth

PP_OFFSET_PX = (8.0, -5.0)


def calibrated_tiny(make_tiny_dataset, **kw) -> Dataset:
    """The tiny 5 x 3 virtual dataset (``make_tiny_dataset`` options) with the studio's own camera
    written as its calibration.json: the exact rotation, focal length and principal point."""
    ds = make_tiny_dataset("png", pp_offset_px=PP_OFFSET_PX, **kw)
    t = load_ground_truth(ds.root)
    w, h = t["image_size_px"]
    pp = [(w - 1) / 2 + PP_OFFSET_PX[0], (h - 1) / 2 + PP_OFFSET_PX[1]]
    atomic_write_json(ds.root / "calibration.json", {
        "format": "lfstudio-calibration", "version": 1, "rotation_deg": list(t["rotation_deg"]),
        "image_size_px": [w, h], "focal_length_px": t["focal_length_px"], "principal_point_px": pp,
        "principal_point_estimated": True,
        "homography": rectifying_homography(t["rotation_deg"], t["focal_length_px"], (w, h), pp).tolist()})
    return Dataset.open(ds.root)


@pytest.fixture
def calibrated(make_tiny_dataset):
    """The tiny 5 x 3 dataset (640 px) with an exact calibration.json."""
    return calibrated_tiny(make_tiny_dataset)


@pytest.fixture
def calibrated_1000(make_tiny_dataset):
    """A 5 x 3 virtual dataset at 1000 px with an exact calibration.json."""
    return calibrated_tiny(make_tiny_dataset, width_px=1000)
