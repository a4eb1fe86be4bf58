"""One coordinate system: calibration undistorts its features with the lens model processing applies,
records it, and processing refuses a calibration fitted under another lens model."""

import numpy as np

from lfstudio.calibration.calibrate import calibrate_dataset
from lfstudio.calibration.lens import OpenCVLens, green, lens_fingerprint, undistort_points
from lfstudio.calibration.model import save_calibration
from lfstudio.dataset.profile import LensStep, Profile
from tests.calibration.synthetic import make_layered_dataset


def test_undistort_points_inverts_the_lens_model():
    model = OpenCVLens(fx=800, fy=800, cx=400, cy=267, dist=(-0.12, 0.03, 0.0005, -0.0004, 0.0))
    rng = np.random.default_rng(0)
    truth = rng.uniform([0, 0], [800, 534], (200, 2))
    captured = np.column_stack(green(model, truth[:, 0], truth[:, 1]))
    assert np.abs(captured - truth).max() > 5.0                      # the lens really moves them
    assert np.abs(undistort_points(model, captured) - truth).max() < 1e-3


def test_the_calibration_records_its_lens_model_and_processing_refuses_another(tmp_path, run_cli):
    ds = make_layered_dataset(tmp_path / "ds", columns=2, rows=2, size_px=(400, 267), rotation_deg=(1.0, -1.0, 1.5))
    profile = Profile()
    profile.lens = LensStep(enabled=True, source="opencv", dist_coeffs=[-0.01, 0.0, 0.0, 0.0, 0.0], tca=False)
    profile.save(ds.root / "processing.toml")
    run = calibrate_dataset(ds, "all", max_width_px=None)
    recorded = run.document["lens_model"]
    assert recorded["model"] == "opencv" and recorded["sha256"] == lens_fingerprint(profile.lens)["sha256"]
    assert not run.document["radial_distortion"]          # the lens model corrects it: no radial term
    save_calibration(ds, run.document)
    profile.lens.dist_coeffs = [-0.05, 0.0, 0.0, 0.0, 0.0]   # processing now applies another model
    profile.save(ds.root / "processing.toml")
    proc = run_cli("process", ds.root, "--profile", ds.root / "processing.toml")
    assert proc.returncode == 2, proc.stderr
    assert "[lens]" in proc.stderr and "calibrate again" in proc.stderr and "Traceback" not in proc.stderr
    profile.lens.enabled = False                             # and with no lens model at all
    assert lens_fingerprint(profile.lens)["model"] == "none" != recorded["model"]
