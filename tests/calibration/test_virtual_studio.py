"""Self-calibration on virtual-studio datasets with known orientation (lfstudio.sim)."""

import json

import numpy as np
import pytest

from lfstudio.calibration.calibrate import calibrate_dataset
from lfstudio.calibration.fit import PairMatches, fit_rectification
from lfstudio.calibration.model import rotation_angle_deg, rotation_matrix
from lfstudio.calibration.model import load_calibration as processing_load_calibration
from lfstudio.sim.virtual_dataset import make_virtual_dataset

ROT = (1.2, -2.0, 2.5)


def _truth(ds):
    return json.loads((ds.root / "ground_truth.json").read_text())


def _error(doc, ds):
    return rotation_angle_deg(rotation_matrix(doc["rotation_deg"]), rotation_matrix(_truth(ds)["rotation_deg"]))


@pytest.fixture(scope="module")
def spread_exact(tmp_path_factory):
    """The paper's 2 × 3 subsample as its own grid: columns 200 mm apart (0, 50, 100 × 4 mm),
    rows 120 mm apart (0, 20 × 6 mm); exact camera positions."""
    root = tmp_path_factory.mktemp("spread") / "ds"
    return make_virtual_dataset(root, 3, 2, spacing_mm=(200.0, 120.0), width_px=960, rotation_deg=ROT, seed=2,
                                fmt="png")


@pytest.fixture(scope="module")
def spread_exact_run(spread_exact):
    return calibrate_dataset(spread_exact, "all", max_width_px=None)


def test_exact_positions_recover_the_rotation_within_002_deg(spread_exact, spread_exact_run):
    doc = spread_exact_run.document
    assert _error(doc, spread_exact) < 0.02
    assert doc["residual_px"]["after"]["rms"] < 0.3 < 3.0 < doc["residual_px"]["before"]["rms"]
    assert not doc["warnings"]
    # the homography agrees with the ground truth's on the image (sub-pixel)
    H_true = np.array(_truth(spread_exact)["H"])
    H = np.array(doc["homography"])
    w, h = doc["image_size_px"]
    corners = np.array([[0, 0, 1], [w - 1, 0, 1], [0, h - 1, 1], [w - 1, h - 1, 1]], float).T
    a, b = H @ corners, H_true @ corners
    assert np.max(np.abs(a[:2] / a[2] - b[:2] / b[2])) < 1.0


def test_thirty_percent_wrong_matches_still_give_the_rotation(spread_exact, spread_exact_run):
    rng = np.random.default_rng(0)
    w, h = spread_exact_run.document["image_size_px"]
    corrupted = []
    for m in spread_exact_run.matches:
        b = m.xy_b.copy()
        k = int(0.3 * len(b) / 0.7)          # wrong matches are 30 % of the result
        wrong_a = rng.uniform(0, [w - 1, h - 1], (k, 2))
        wrong_b = rng.uniform(0, [w - 1, h - 1], (k, 2))
        corrupted.append(PairMatches(m.view_a, m.view_b, m.direction, np.vstack([m.xy_a, wrong_a]),
                                     np.vstack([b, wrong_b])))
    fit = fit_rectification(corrupted, spread_exact_run.fit.focal_length_px, (w, h))
    err = rotation_angle_deg(rotation_matrix(fit.rotation_deg), rotation_matrix(ROT))
    assert err < 0.03


def test_repeatability_noise_stays_within_its_floor(tmp_path):
    ds = make_virtual_dataset(tmp_path / "noisy", 3, 2, spacing_mm=(200.0, 120.0), width_px=640, rotation_deg=ROT,
                              seed=5, fmt="png", position_noise_um=(80.0, 50.0))
    doc = calibrate_dataset(ds, "all", max_width_px=None).document
    assert _error(doc, ds) < 0.06


def test_dng_views_and_the_processing_stage_reads_the_result(tiny_dataset_dng, run_cli):
    proc = run_cli("calibrate", tiny_dataset_dng.root)
    assert proc.returncode == 0, proc.stderr
    cal = processing_load_calibration(tiny_dataset_dng.root)
    truth = _truth(tiny_dataset_dng)
    assert cal["image_size_px"] == list(truth["image_size_px"])
    # 4–6 mm baselines: roll is well determined, pan/tilt less so (tiny disparities)
    assert abs(cal["rotation_deg"][2] - truth["rotation_deg"][2]) < 0.05
    assert cal["residual_px"]["after"]["rms"] < cal["residual_px"]["before"]["rms"]
    assert (tiny_dataset_dng.root / "cache" / "features").is_dir()
