"""Fault injection in the virtual studio: each defect does what it says, with ground truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from lfstudio.errors import InputError
from lfstudio.sim.studio import ViewFault, VirtualStudio, motion_blur, parse_fault
from lfstudio.sim.virtual_dataset import load_ground_truth, make_virtual_dataset


def _png_rgb(path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB).astype(np.float32) / 65535.0


def test_motion_blur_smears_along_its_direction_only():
    img = np.zeros((41, 41, 3), np.float32)
    img[20, 20] = 1.0                              # a point light
    out = motion_blur(img, 6.0)
    row = out[20, :, 0]
    assert out.sum() == pytest.approx(img.sum(), rel=1e-5)          # brightness kept
    assert np.count_nonzero(out[:, :, 0].sum(axis=1) > 1e-6) == 1    # stays on its row
    assert np.count_nonzero(row > 1e-6) == 7 and row.max() == pytest.approx(1 / 6, rel=1e-3)
    vertical = motion_blur(img, 6.0, 90.0)
    assert np.count_nonzero(vertical[:, 20, 0] > 0.05) >= 5 and np.count_nonzero(vertical[20, :, 0] > 0.05) <= 2
    assert motion_blur(img, 0.0) is img


def test_parse_fault_reads_every_kind_and_names_the_fix():
    assert parse_fault("blur:r01_c002:6") == ViewFault("blur", 1, 2, blur_px=6.0)
    assert parse_fault("blur:r1c2:6,90").blur_angle_deg == 90.0
    assert parse_fault("luminance:r00_c003:1.3").gain == pytest.approx(1.3)
    assert parse_fault("displaced:r02_c002:1.0,-0.5").offset_mm == (1.0, -0.5)
    assert parse_fault("skipped:r01_c001") == ViewFault("skipped", 1, 1)
    for bad in ("blur:r01_c002", "wobble:r01_c001", "skipped", "luminance:r00_c000:1", "displaced:r01_c001:1:1",
                "blur:-1,0:3", "blur:r01:3"):
        with pytest.raises(ValueError) as exc:
            parse_fault(bad)
        assert "KIND:VIEW" in str(exc.value) or "must" in str(exc.value) or "needs" in str(exc.value)


def test_a_fault_at_row_comma_column_is_refused_with_the_view_name():
    """Issue 20: '--fault blur:1,2:6' was row 1, column 2; positions are COLUMN,ROW now, so the old
    form is refused (never read as column 1, row 2) with the view's name in its place."""
    with pytest.raises(ValueError, match=r"write blur:r01_c002:6$"):
        parse_fault("blur:1,2:6")
    with pytest.raises(ValueError, match=r"write skipped:r04_c002$"):
        parse_fault("skipped:4,2")


def test_faults_spoil_exactly_their_views_with_ground_truth(tmp_path):
    faults = [ViewFault("blur", 0, 1, blur_px=5.0), ViewFault("luminance", 1, 3, gain=0.8),
              ViewFault("displaced", 1, 1, offset_mm=(0.7, -0.3)), ViewFault("skipped", 1, 2)]
    ds = make_virtual_dataset(tmp_path / "ds", 4, 2, width_px=160, fmt="png", seed=3, faults=faults)
    clean = make_virtual_dataset(tmp_path / "clean", 4, 2, width_px=160, fmt="png", seed=3)
    truth = load_ground_truth(ds.root)
    assert [f["kind"] for f in truth["faults"]] == ["blur", "luminance", "displaced", "skipped"]
    assert truth["faults"][2]["offset_mm"] == [0.7, -0.3] and truth["faults"][0]["blur_px"] == 5.0
    by_cell = {(v["row"], v["column"]): v for v in truth["views"]}
    # the manifest still says where the rig was told to go
    assert ds.view(1, 1)["reported_mm"] == [4.0, 6.0] and ds.view(1, 2)["reported_mm"] == [8.0, 6.0]
    assert by_cell[(1, 1)]["true_mm"] == pytest.approx([4.7, 5.7])
    # row 1 runs right to left: the view before (1, 2) in capture order is (1, 3)
    assert by_cell[(1, 2)]["true_mm"] == pytest.approx(by_cell[(1, 3)]["true_mm"])
    images = {cell: _png_rgb(ds.path_of(ds.view(*cell))) for cell in by_cell}
    reference = {cell: _png_rgb(clean.path_of(clean.view(*cell))) for cell in by_cell}
    changed = {cell for cell in by_cell if np.abs(images[cell] - reference[cell]).max() > 1e-4}
    assert changed == {(0, 1), (1, 3), (1, 1), (1, 2)}
    np.testing.assert_allclose(images[(1, 2)], reference[(1, 3)], atol=1e-4)    # the skipped view shows (1, 3)
    np.testing.assert_allclose(images[(1, 3)], np.clip(reference[(1, 3)] * 0.8, 0, 1), atol=2e-5)
    np.testing.assert_allclose(images[(0, 1)], np.clip(motion_blur(reference[(0, 1)], 5.0), 0, 1), atol=2e-3)


def test_fault_arguments_are_checked(tmp_path):
    with pytest.raises(InputError, match="outside the 3 x 2 grid"):
        make_virtual_dataset(tmp_path / "a", 3, 2, width_px=64, fmt="png", faults=[ViewFault("skipped", 2, 0)])
    with pytest.raises(InputError, match="first shot"):
        make_virtual_dataset(tmp_path / "b", 3, 2, width_px=64, fmt="png", faults=[ViewFault("skipped", 0, 0)])
    with pytest.raises(InputError, match="two faults"):
        make_virtual_dataset(tmp_path / "c", 3, 2, width_px=64, fmt="png",
                             faults=[ViewFault("blur", 0, 1, blur_px=2), ViewFault("skipped", 0, 1)])


def test_a_displaced_view_is_rendered_from_where_the_camera_really_stood(tmp_path):
    ds = make_virtual_dataset(tmp_path / "ds", 2, 1, width_px=128, fmt="png", seed=5,
                              faults=[ViewFault("displaced", 0, 1, offset_mm=(2.0, 0.0))])
    truth = load_ground_truth(ds.root)
    studio = VirtualStudio(width_px=128, view_region_mm=truth["view_region_mm"], seed=5)
    got = _png_rgb(ds.path_of(ds.view(0, 1)))
    np.testing.assert_allclose(got, np.clip(studio.render(6.0, 0.0), 0, 1), atol=1e-4)
