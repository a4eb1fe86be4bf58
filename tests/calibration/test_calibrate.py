import json

import cv2
import numpy as np
import pytest

from lfstudio.calibration.calibrate import calibrate_dataset
from lfstudio.calibration.model import load_calibration, save_calibration
from lfstudio.calibration.fit import CalibrationError
from lfstudio.calibration.model import rotation_angle_deg, rotation_matrix
from lfstudio.dataset import Dataset
from tests.calibration.synthetic import make_layered_dataset

ROT = (3.0, -2.0, 4.0)


@pytest.fixture(scope="module")
def layered(tmp_path_factory):
    return make_layered_dataset(tmp_path_factory.mktemp("cal") / "ds", rotation_deg=ROT)


def test_calibrate_recovers_the_orientation_and_saves_the_document(layered):
    run = calibrate_dataset(layered, "all", max_width_px=None)
    err = rotation_angle_deg(rotation_matrix(run.document["rotation_deg"]), rotation_matrix(ROT))
    assert err < 0.15
    doc = run.document
    assert doc["residual_px"]["after"]["rms"] < 0.5 < doc["residual_px"]["before"]["rms"]
    assert len(doc["pairs"]) == 9 and all(p["inliers"] >= 20 for p in doc["pairs"])
    assert {"mean", "median", "rms", "p99"} <= set(doc["residual_px"]["after"]["horizontal"])
    assert doc["image_size_px"] == [800, 534] and np.array(doc["homography"]).shape == (3, 3)
    assert [v["view"] for v in doc["views"]] == doc["views_used"] and len(doc["views_used"]) == 6
    path = save_calibration(layered, doc)
    again = load_calibration(Dataset.open(layered.root))
    assert path.name == "calibration.json" and again["rotation_deg"] == doc["rotation_deg"]
    assert Dataset.open(layered.root).manifest["calibration"]["file"] == "calibration.json"


def test_too_few_matches_names_the_views(tmp_path):
    ds = make_layered_dataset(tmp_path / "flat", columns=2, rows=2, size_px=(320, 214))
    for v in ds.views:   # featureless views
        cv2.imwrite(str(ds.path_of(v)), np.full((214, 320), 128, np.uint8))
    with pytest.raises(CalibrationError, match="too few feature matches.*r00_c000–r00_c001"):
        calibrate_dataset(ds, "all")


def test_cli_calibrate_writes_json_and_reports(layered, run_cli):
    proc = run_cli("calibrate", layered.root, "--views", "array:3x2", "--json", "--work-width-px", "0")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert {"rotation_deg", "principal_point_px", "focal_length_px", "homography", "residual_px", "pairs"} <= set(doc)
    assert (layered.root / "calibration.json").is_file()
    assert "calibrate [" in proc.stderr            # progress on stderr
    text = run_cli("calibrate", layered.root, "--no-save", "--estimate-principal-point")
    assert text.returncode == 0 and "rotation" in text.stdout and "r00_c000–r00_c001" in text.stdout


def test_cli_calibrate_options(layered, run_cli):
    proc = run_cli("calibrate", layered.root, "--views", "all", "--pairs", "neighbours", "--principal-point", "centre",
                   "--position-sigma-um", "20,10", "--json", "--no-save")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert len(doc["pairs"]) == 2 * 2 + 3 and doc["settings"]["pair_set"] == "neighbours"
    assert doc["uncertainty"]["position_sigma_um"][1] >= 10.0 and doc["settings"]["position_sigma_um"] == [20, 10]
    assert not doc["principal_point_estimated"] and "not requested" in doc["principal_point_reason"]
    assert len(doc["uncertainty"]["covariance"]) == 5 and doc["uncertainty"]["corner_error_px"][1] > 0
    text = run_cli("calibrate", layered.root, "--no-save")
    assert "uncertainty rx ±" in text.stdout and "at corners" in text.stdout


def test_cli_calibrate_bad_input(layered, run_cli, tmp_path):
    proc = run_cli("calibrate", layered.root, "--views", "r09_c009")
    assert proc.returncode == 2 and "--views" in proc.stderr and "Traceback" not in proc.stderr
    proc = run_cli("calibrate", layered.root, "--position-sigma-um", "eighty")
    assert proc.returncode == 2 and "--position-sigma-um" in proc.stderr and "Traceback" not in proc.stderr
    proc = run_cli("calibrate", tmp_path)
    assert proc.returncode == 2 and "dataset.json" in proc.stderr
