import pytest
import numpy as np
from hypothesis import given, settings, strategies as st

from lfstudio.calibration.model import (apply_homography, intrinsics, nominal_principal_point, project,
                                        rectifying_homography, rotation_matrix, scale_homography)

angles = st.lists(st.floats(-6, 6), min_size=3, max_size=3)
offsets = st.lists(st.floats(-60, 60), min_size=2, max_size=2)


@settings(max_examples=30, deadline=None)
@given(angles, offsets)
def test_homography_maps_captured_pixels_to_the_ideal_camera(rot, pp_off):
    size, f = (1600, 1068), 2200.0
    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(-0.5, 0.5, 50), rng.uniform(-0.3, 0.3, 50), rng.uniform(1.8, 4.8, 50)])
    C = np.array([0.12, -0.04, 0.0])
    K_true = intrinsics(f, nominal_principal_point(size) + np.array(pp_off))
    K0 = intrinsics(f, nominal_principal_point(size))
    captured, _ = project(X, C, rotation_matrix(rot), K_true)
    ideal, _ = project(X, C, np.eye(3), K0)
    H = rectifying_homography(rot, f, size, nominal_principal_point(size) + np.array(pp_off))
    assert np.allclose(apply_homography(H, captured), ideal, atol=1e-6)


@settings(max_examples=20, deadline=None)
@given(angles)
def test_scaled_homography_commutes_with_resizing(rot):
    full, half = (2000, 1334), (500, 333.5)
    H = rectifying_homography(rot, 2800.0, full)
    Hs = scale_homography(H, full, (500, 334))
    s = 500 / 2000
    pts = np.array([[10.0, 20.0], [1000.0, 600.0], [1900.0, 1300.0]])
    to_small = (pts + 0.5) * s - 0.5
    expected = (apply_homography(H, pts) + 0.5) * s - 0.5
    assert np.allclose(apply_homography(Hs, to_small), expected, atol=1e-9)
    assert half[0] == 500


def test_rotation_convention_is_extrinsic_xyz():
    R = rotation_matrix([0, 0, 90])
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-12)   # x turns into y (down) for +rz


# -- calibration.json: one validating loader and saver ----------------------------------------------
def _doc(H, size=(482, 320)):
    return {"created": "2026-11-22T00:00:00+00:00", "rotation_deg": [0.5, -0.2, 0.1], "image_size_px": list(size),
            "focal_length_px": 671.3, "homography": np.asarray(H, float).tolist(),
            "residual_px": {"after": {"rms": 0.3}}}


def test_one_loader_refuses_a_broken_file_for_every_stage(make_tiny_dataset):
    """calibrate's saver, processing's rectification, export and the quality check read the one
    validating loader: a singular homography is refused naming the file, everywhere."""
    import pytest

    from lfstudio.calibration.model import CALIBRATION_NAME, homography_for, load_calibration, save_calibration
    from lfstudio.dataset.atomic import atomic_write_json
    from lfstudio.dataset.profile import Profile
    from lfstudio.errors import DatasetError
    from lfstudio.export import ExportOptions, export_dataset
    from lfstudio.processing.pipeline import make_plan

    ds = make_tiny_dataset("png", width_px=482)
    H = rectifying_homography([0.5, -0.2, 0.1], 671.3, (482, 320))
    save_calibration(ds, _doc(H))
    for where in (ds, ds.root, str(ds.root)):           # a Dataset, a Path (whose .root is "/"), a str
        doc = load_calibration(where)
        assert doc is not None and np.allclose(homography_for(doc), H)
    # the same homography for half-size images, through the one scaling (pixel centres)
    assert np.allclose(homography_for(doc, (241, 160)), scale_homography(H, (482, 320), (241, 160)))
    with pytest.raises(DatasetError, match="homography"):
        save_calibration(ds, _doc(np.zeros((3, 3))))
    atomic_write_json(ds.root / CALIBRATION_NAME, _doc(np.zeros((3, 3))))
    for read in (lambda: load_calibration(ds),
                 lambda: make_plan(ds, Profile()),
                 lambda: export_dataset(ds, ExportOptions("png", ds.root.parent / "out", views="r00_c000"))):
        with pytest.raises(DatasetError, match=r"calibration\.json: invalid calibration.*homography: must be an invertible 3x3"):
            read()
    assert not (ds.root.parent / "out").exists()


def _absurd_documents(w=400, h=300):
    from lfstudio.calibration.model import rectifying_homography
    good = {"format": "lfstudio-calibration", "version": 1, "rotation_deg": [1.0, -2.0, 0.5],
            "image_size_px": [w, h], "homography": rectifying_homography([1.0, -2.0, 0.5], 500.0, (w, h)).tolist()}
    spun = dict(good, rotation_deg=[-19291050.0, -1.5, 2.0])           # what the undamped fit once saved
    flung = dict(good, homography=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.01, 0.0, 1.0]])   # corners thrown far
    behind = dict(good, homography=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-0.004, 0.0, 1.0]])  # a corner at infinity
    return good, {"angles": spun, "corners": flung, "behind": behind}


@pytest.mark.parametrize("kind", ["angles", "corners", "behind"])
def test_an_absurd_calibration_is_never_written_and_never_used(tmp_path, kind):
    import json

    from lfstudio.calibration.model import load_calibration, save_calibration
    from lfstudio.dataset import Dataset
    from lfstudio.errors import DatasetError

    ds = Dataset.create(tmp_path / "ds", camera={"name": "c", "sensor_px": [400, 300], "pixel_pitch_um": 5.0},
                        lens={"name": "l", "focal_length_mm": 2.5}, grid={"columns": 2, "rows": 1, "spacing_mm": [5, 5]})
    good, bad = _absurd_documents()
    save_calibration(ds, good)                                         # a sane one is saved and loaded
    assert load_calibration(ds.root)["rotation_deg"] == good["rotation_deg"]
    word = {"angles": "outside the fit's bounds", "corners": "% of the image diagonal", "behind": "unbounded"}[kind]
    with pytest.raises(DatasetError) as exc:
        save_calibration(ds, bad[kind])
    assert word in " ".join(exc.value.problems)
    assert load_calibration(ds.root)["rotation_deg"] == good["rotation_deg"]      # not written
    (ds.root / "calibration.json").write_text(json.dumps(bad[kind]))            # crafted by hand
    with pytest.raises(DatasetError) as exc:
        load_calibration(ds.root)
    assert word in " ".join(exc.value.problems) and "calibrate' again" in str(exc.value)
