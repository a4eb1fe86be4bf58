"""The whole chain on a virtual-studio DNG dataset with known flicker, vignetting and orientation."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from lfstudio.dataset import Dataset
from lfstudio.processing.pipeline import process_dataset
from lfstudio.dataset.profile import Profile
from lfstudio.sim.studio import VirtualStudio
from lfstudio.sim.virtual_dataset import load_ground_truth


def test_virtual_studio_views_come_out_rectified_flat_and_deflickered(make_tiny_dataset):
    ds = make_tiny_dataset("dng", flicker=0.05, vignetting=0.2)
    truth = load_ground_truth(ds.root)
    (ds.root / "calibration.json").write_text(json.dumps(
        {"homography": truth["H"].tolist(), "image_size_px": truth["image_size_px"],
         "rotation_deg": truth["rotation_deg"], "focal_length_px": truth["focal_length_px"],
         "principal_point_px": [(truth["image_size_px"][0] - 1) / 2, (truth["image_size_px"][1] - 1) / 2]}))
    profile = Profile()
    profile.color.enabled = False          # compare linear values with the ideal rendering
    profile.shading.enabled = True
    profile.shading.mode = "model"
    profile.shading.coefficients = [-0.2]  # the simulated sensor's falloff
    report = process_dataset(ds.root, profile, workers=0)
    assert report.ok and report.processed == 15

    gains = {(v["row"], v["column"]): v["gain"] for v in truth["views"]}
    ref_gain = gains[(1, 2)]               # the middle view is the reference
    for key, g in report.gains.items():    # de-flicker undid each shot's illumination gain
        assert g * gains[key] == pytest.approx(ref_gain, rel=0.01), key

    studio = VirtualStudio(width_px=640, rotation_deg=tuple(truth["rotation_deg"]),
                           pp_offset_px=tuple(truth["pp_offset_px"]),
                           view_region_mm=tuple(truth["view_region_mm"]), seed=truth["seed"],
                           near_m=truth["near_m"], far_m=truth["far_m"])
    ds = Dataset.open(ds.root)
    for r, c in ((1, 2), (0, 0), (2, 4)):
        x_mm, y_mm = ds.view(r, c)["commanded_mm"]
        out = cv2.imread(str(ds.root / ds.view(r, c)["processed"]["file"]), cv2.IMREAD_UNCHANGED)
        out = cv2.cvtColor(out, cv2.COLOR_BGR2RGB).astype(np.float64) / 65535
        w, h = out.shape[1], out.shape[0]
        assert (w, h) == (320, 213)
        ideal = cv2.resize(studio.render(x_mm, y_mm, ideal=True), (w, h), interpolation=cv2.INTER_AREA)
        captured = cv2.resize(studio.render(x_mm, y_mm), (w, h), interpolation=cv2.INTER_AREA)
        inner = (slice(20, -20), slice(25, -25))
        err = np.abs(out[inner] - ideal[inner] * ref_gain).mean() / ideal[inner].mean()
        err_unrectified = np.abs(captured[inner] - ideal[inner]).mean() / ideal[inner].mean()
        assert err < 0.05 and err < err_unrectified / 3, (r, c, err, err_unrectified)
