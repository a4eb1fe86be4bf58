"""The quality check judges views from their pixels: exactly the faulty views are flagged, figures
match the virtual studio's ground truth (displacement within 20 %, depth range within 5 %)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from lfstudio.dataset import Dataset
from lfstudio.dataset.store import sha256_file
from lfstudio.quality import check_dataset, load_quality
from lfstudio.sim.studio import ViewFault, motion_blur
from lfstudio.sim.virtual_dataset import load_ground_truth, true_disparity_px


def _flagged(report) -> dict[tuple[int, int], dict]:
    return {(v["row"], v["column"]): v for v in report.views if v["verdict"] != "pass"}


def _failing_checks(view: dict) -> set[str]:
    return {name for name, c in view["checks"].items() if c["verdict"] == "fail"}


def test_a_clean_render_passes_every_check_and_measures_the_scene(quality_dataset):
    ds = quality_dataset("clean")
    report = check_dataset(ds)
    doc = report.document
    assert _flagged(report) == {}
    assert doc["verdict"] == "pass" and doc["summary"] == {"views": 25, "pass": 25, "warn": 0, "fail": 0, "flagged": []}
    for v in report.views:
        assert {"sharpness", "exposure", "clipping", "position", "residual"} == set(v["checks"])
        assert all(c["verdict"] == "pass" for c in v["checks"].values()), v
    truth = load_ground_truth(ds.root)
    depth = doc["depth_range"]
    assert depth["verdict"] == "pass"
    assert depth["near_m"] == pytest.approx(truth["near_m"], rel=0.05)
    assert depth["far_m"] == pytest.approx(truth["far_m"], rel=0.05)
    # the measured neighbour disparity range against what the exports write for the planned range
    assert depth["disparity_min_px"] == pytest.approx(depth["export_disp_min_px"], rel=0.05)
    assert depth["disparity_max_px"] == pytest.approx(depth["export_disp_max_px"], rel=0.05)
    # every position within a few micrometres: nothing was displaced
    assert doc["repeatability"]["rms_um"] < 20
    # written: quality.json (the same document) and the pictures
    saved = load_quality(ds)
    assert saved["summary"] == doc["summary"] and saved["views"][7]["checks"]["sharpness"]["value"] == \
        pytest.approx(report.views[7]["checks"]["sharpness"]["value"])
    for key in ("heatmaps", "disparity", "histograms", "report"):
        assert (ds.root / saved["pictures"][key]).is_file(), key
    heat = cv2.imread(str(ds.root / saved["pictures"]["heatmaps"]))
    assert heat is not None and heat.shape[0] > 200
    assert "Verdict: pass" in (ds.root / saved["pictures"]["report"]).read_text(encoding="utf-8")


def test_the_disparity_map_of_the_centre_view_matches_the_ground_truth(quality_dataset):
    ds = quality_dataset("clean")
    report = check_dataset(ds, write=False)
    d = report.disparity
    assert d is not None and d.cell == (2, 2)
    truth = true_disparity_px(ds.root, 2, 2, (d.disparity_px.shape[1], d.disparity_px.shape[0]), rectified=False)
    valid = np.isfinite(d.disparity_px)
    assert valid.mean() > 0.9
    error = np.abs(d.disparity_px[valid] - truth[valid])
    assert float(np.median(error)) < 0.08          # px between neighbours; the scene spans 0.75 … 2.1 px here
    # the far background (most of the picture) and the scene's range
    background = valid & (truth < truth.min() + 1e-3)
    assert float(np.median(d.disparity_px[background])) == pytest.approx(float(truth.min()), rel=0.1)
    assert report.document["disparity_map"]["p99_px"] == pytest.approx(float(np.percentile(truth, 99)), rel=0.1)


FAULTS = {
    "blurred": (ViewFault("blur", 1, 3, blur_px=6.0), "sharpness"),
    "brighter": (ViewFault("luminance", 3, 1, gain=1.25), "exposure"),
    "darker": (ViewFault("luminance", 0, 0, gain=0.8), "exposure"),
    "displaced": (ViewFault("displaced", 2, 2, offset_mm=(1.0, 0.0)), "position"),
    "displaced-down": (ViewFault("displaced", 4, 3, offset_mm=(0.0, 1.0)), "position"),
    "skipped": (ViewFault("skipped", 2, 3), "position"),
}


@pytest.mark.parametrize("name", list(FAULTS))
def test_each_injected_fault_flags_its_view_and_only_it(quality_dataset, name):
    fault, check = FAULTS[name]
    ds = quality_dataset(name, faults=[fault])
    report = check_dataset(ds, write=False)
    flagged = _flagged(report)
    assert set(flagged) == {fault.cell}, {k: v["reasons"] for k, v in flagged.items()}
    view = flagged[fault.cell]
    assert view["verdict"] == "fail" and check in _failing_checks(view)
    assert any(r.startswith(check) for r in view["reasons"])
    if fault.kind in ("displaced", "skipped"):
        truth = load_ground_truth(ds.root)
        true = next(v for v in truth["views"] if (v["row"], v["column"]) == fault.cell)
        injected = np.subtract(true["true_mm"], true["commanded_mm"])
        measured = np.array(view["checks"]["position"]["error_mm"])
        assert np.linalg.norm(measured - injected) < 0.2 * np.linalg.norm(injected), (measured, injected)


def test_a_view_edited_after_capture_with_its_checksum_updated_is_still_flagged(quality_dataset):
    ds = quality_dataset("clean")
    view = ds.view(3, 2)
    path = ds.path_of(view)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.float32) / 65535.0
    cv2.imwrite(str(path), np.rint(np.clip(motion_blur(img, 6.0), 0, 1) * 65535).astype(np.uint16))
    ds.record_view(3, 2, sha256=sha256_file(path))          # the edit covers its tracks
    ds.save()
    ds = Dataset.open(ds.root)
    assert ds.view(3, 2)["sha256"] == sha256_file(path)
    report = check_dataset(ds, write=False)
    assert set(_flagged(report)) == {(3, 2)}
    assert "sharpness" in _failing_checks(_flagged(report)[(3, 2)])


def test_a_missing_view_is_reported_and_its_neighbours_still_judged(quality_dataset):
    ds = quality_dataset("clean")
    ds.record_view(1, 1, status="failed", file=None, sha256=None)
    ds.save()
    report = check_dataset(Dataset.open(ds.root), write=False)
    flagged = _flagged(report)
    assert set(flagged) == {(1, 1)}
    assert flagged[(1, 1)]["verdict"] == "fail" and "not captured" in flagged[(1, 1)]["reasons"][0]
    assert report.document["summary"]["views"] == 25


def test_only_the_chosen_views_are_judged(quality_dataset):
    fault, _ = FAULTS["blurred"]
    ds = quality_dataset("blurred", faults=[fault])
    report = check_dataset(ds, "r01_c003,r04_c004", write=False)
    assert [(v["row"], v["column"]) for v in report.views] == [(1, 3), (4, 4)]
    assert [v["verdict"] for v in report.views] == ["fail", "pass"]


def test_a_calibrated_dataset_is_checked_in_the_rectified_frame(quality_dataset):
    from lfstudio.calibration.calibrate import calibrate_dataset
    from lfstudio.calibration.model import save_calibration

    fault, _ = FAULTS["displaced"]
    ds = quality_dataset("displaced", faults=[fault])
    save_calibration(ds, calibrate_dataset(ds, "array:3x2").document)
    report = check_dataset(ds, write=False)
    assert report.document["calibration"]["used"] is True
    assert set(_flagged(report)) == {(2, 2)}
    measured = report.views[12]["checks"]["position"]["error_mm"]
    assert measured[0] == pytest.approx(1.0, rel=0.2) and abs(measured[1]) < 0.2
    assert report.document["disparity_map"]["rectified"] is True


@pytest.mark.slow
def test_the_measured_repeatability_matches_the_rigs_position_noise(tmp_path):
    from lfstudio.sim.virtual_dataset import make_virtual_dataset

    ds = make_virtual_dataset(tmp_path / "noisy", 7, 7, width_px=800, fmt="png", rotation_deg=(1.0, -1.5, 0.7),
                              position_noise_um=(80.0, 80.0), seed=2, workers=2)
    report = check_dataset(ds, disparity=False, write=False)
    rep = report.document["repeatability"]
    assert rep["views"] >= 45
    assert rep["rms_um"] == pytest.approx(80.0, rel=0.2)
    assert rep["x_um"] == pytest.approx(80.0, rel=0.2) and rep["y_um"] == pytest.approx(80.0, rel=0.2)
    # and per view: the measured errors follow the true ones
    truth = {(v["row"], v["column"]): np.subtract(v["true_mm"], v["commanded_mm"])
             for v in load_ground_truth(ds.root)["views"]}
    meas = np.array([v["checks"]["position"]["error_mm"] for v in report.views])
    true = np.array([truth[(v["row"], v["column"])] for v in report.views])
    true -= true.mean(axis=0)
    assert np.corrcoef(meas[:, 0], true[:, 0])[0, 1] > 0.95 and np.corrcoef(meas[:, 1], true[:, 1])[0, 1] > 0.95


def test_lfstudio_check_prints_json_and_exits_0_with_flagged_views(quality_dataset, run_cli):
    fault, _ = FAULTS["skipped"]
    ds = quality_dataset("skipped", faults=[fault])
    res = run_cli("check", ds.root, "--json", "--no-save")
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    verdicts = {(v["row"], v["column"]): v["verdict"] for v in doc["views"]}
    assert len(verdicts) == 25 and verdicts[(2, 3)] == "fail"
    assert [cell for cell, v in verdicts.items() if v != "pass"] == [(2, 3)]
    assert isinstance(doc["views"][0]["checks"]["sharpness"]["value"], float)
    assert not (ds.root / "quality.json").exists()
    text = run_cli("check", ds.root)
    assert text.returncode == 0 and "r02_c003  FAIL  position:" in text.stdout
    assert (ds.root / "quality.json").is_file() and (ds.root / "quality" / "report.html").is_file()


def test_lfstudio_check_names_the_problem_without_a_traceback(tmp_path, run_cli):
    res = run_cli("check", tmp_path / "nothing-here")
    assert res.returncode == 2 and "Traceback" not in res.stderr   # a DATASET that does not exist: bad input
    assert "nothing-here" in res.stderr
    res = run_cli("check", tmp_path, "--work-width-px", "50")
    assert res.returncode == 2 and "--work-width-px" in res.stderr


def test_an_unreadable_view_fails_and_the_others_are_still_checked(quality_dataset):
    ds = quality_dataset("clean")
    ds.path_of(ds.view(2, 4)).write_bytes(b"not an image")
    report = check_dataset(ds, write=False)
    flagged = _flagged(report)
    assert set(flagged) == {(2, 4)}
    assert flagged[(2, 4)]["verdict"] == "fail" and flagged[(2, 4)]["reasons"][0].startswith("cannot be read")
    assert "r02_c004" in flagged[(2, 4)]["reasons"][0]


def test_raw_dng_views_are_judged_too(quality_dataset):
    faults = [ViewFault("blur", 1, 3, blur_px=6.0), ViewFault("luminance", 3, 1, gain=1.3)]
    ds = quality_dataset("dng", fmt="dng", faults=faults)
    report = check_dataset(ds, write=False)
    flagged = _flagged(report)
    assert set(flagged) == {(1, 3), (3, 1)}, {k: v["reasons"] for k, v in flagged.items()}
    assert "sharpness" in _failing_checks(flagged[(1, 3)]) and "exposure" in _failing_checks(flagged[(3, 1)])
    assert flagged[(3, 1)]["checks"]["exposure"]["value"] == pytest.approx(1.3, rel=0.03)
    assert report.document["depth_range"]["near_m"] == pytest.approx(1.77, rel=0.05)


@pytest.mark.parametrize("columns, rows, fault", [
    (7, 1, ViewFault("displaced", 0, 3, offset_mm=(1.0, 0.0))),
    (1, 7, ViewFault("displaced", 3, 0, offset_mm=(0.0, 1.0))),
])
def test_a_single_row_or_column_is_checked_too(tmp_path, columns, rows, fault):
    from lfstudio.sim.virtual_dataset import make_virtual_dataset

    ds = make_virtual_dataset(tmp_path / "line", columns, rows, width_px=480, fmt="png", seed=1, faults=[fault])
    report = check_dataset(ds, write=False)
    assert set(_flagged(report)) == {fault.cell}
    error = _flagged(report)[fault.cell]["checks"]["position"]["error_mm"]
    assert np.hypot(*error) == pytest.approx(1.0, rel=0.2)


def test_a_single_view_writes_a_report_without_position_checks(tmp_path):
    from lfstudio.sim.virtual_dataset import make_virtual_dataset

    ds = make_virtual_dataset(tmp_path / "one", 1, 1, width_px=320, fmt="png", seed=1)
    report = check_dataset(ds)
    assert report.views[0]["verdict"] == "pass"
    assert report.views[0]["checks"]["position"]["verdict"] == "n/a"
    assert load_quality(ds)["summary"]["views"] == 1
