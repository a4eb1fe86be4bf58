"""Dataset → Depth map of a view… and the export dialog's points/depth options, on a real dataset
with a real Qt event loop (offscreen)."""

from __future__ import annotations

import pytest

from lfstudio.calibration.model import rectifying_homography
from lfstudio.dataset.atomic import atomic_write_json
from lfstudio.depth.run import has_disparity
from lfstudio.gui.app import create_window
from lfstudio.gui.dialogs.export_dialog import FORMAT_KEYS, ExportDialog
from lfstudio.gui.views.depth import DepthDialog
from lfstudio.sim.virtual_dataset import load_ground_truth


def _calibrate_exactly(ds):
    t = load_ground_truth(ds.root)
    w, h = t["image_size_px"]
    pp = [(w - 1) / 2, (h - 1) / 2]
    atomic_write_json(ds.root / "calibration.json", {
        "format": "lfstudio-calibration", "version": 1, "rotation_deg": list(t["rotation_deg"]),
        "image_size_px": [w, h], "focal_length_px": t["focal_length_px"], "principal_point_px": pp,
        "principal_point_estimated": False,
        "homography": rectifying_homography(t["rotation_deg"], t["focal_length_px"], (w, h), pp).tolist()})


def _action(window, name):
    return next(a for a in window.menu("Dataset").actions() if a.objectName() == name)


def test_depth_view_computes_and_shows_a_view_with_its_colour_bar(qtbot, tiny_dataset):
    _calibrate_exactly(tiny_dataset)
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    action = _action(window, "actionDepthMap")
    assert not action.isEnabled()
    window.state.set_dataset(tiny_dataset)
    assert action.isEnabled()
    action.trigger()
    dialog = window.findChild(DepthDialog, "depthDialog")
    assert dialog is not None and dialog.isVisible()
    assert dialog.view_edit.text() == "r01_c002" and "no depth map yet" in dialog.caption.text()
    dialog.view_edit.setText("r09_c000")
    dialog.show_button.click()
    assert "not a captured view" in dialog.caption.text()
    dialog.view_edit.setText("r01_c002")
    dialog.range_edit.setText("3, 1")
    dialog.compute_button.click()
    assert "Disparity range" in dialog.caption.text() and "not below" in dialog.caption.text()
    assert not dialog.runner.running
    dialog.range_edit.setText("")
    with qtbot.waitSignal(dialog.runner.finished, timeout=120000):
        dialog.compute_button.click()
    assert has_disparity(tiny_dataset, (1, 2))
    qtbot.waitUntil(lambda: dialog.pictures_shown == 1, timeout=30000)
    pixmap = dialog.image.pixmap()
    assert not pixmap.isNull() and pixmap.width() == 640 and pixmap.height() >= 426    # the view
    labels = dialog.colour_bar.labels()                        # its colour bar, drawn at screen resolution
    assert len(labels) == 5 and all(" px" in t for t in labels) and any(" m" in t for t in labels), labels
    text = dialog.caption.text()
    assert " px" in text and " m" in text and "depth 1." in text, text
    dialog.resize(900, 700)
    dialog.grab().save("/tmp/depth-dialog.png")
    assert "disparity range" in text and "from the scene plan" in text, text
    dialog.hide_check.setChecked(True)
    qtbot.waitUntil(lambda: dialog.pictures_shown == 2, timeout=30000)
    # a range typed into the dialog is searched and said
    dialog.range_edit.setText("0.5, 7")
    with qtbot.waitSignal(dialog.runner.finished, timeout=120000):
        dialog.compute_button.click()
    qtbot.waitUntil(lambda: dialog.pictures_shown == 3, timeout=30000)
    assert "+0.50 … +7.00 px from the Disparity range field" in dialog.caption.text(), dialog.caption.text()
    dialog.close()


def test_export_dialog_offers_points_and_depth_with_the_size_estimate(qtbot, tiny_dataset, tmp_path):
    _calibrate_exactly(tiny_dataset)
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.state.set_dataset(tiny_dataset)
    next(a for a in window.menu("File").actions() if a.text().replace("&", "") == "Export dataset…").trigger()
    dialog = window.findChild(ExportDialog, "exportDialog")
    dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index("nerfstudio"))
    qtbot.waitUntil(lambda: dialog.estimate is not None, timeout=20000)
    plain = dialog.estimate.bytes_estimate
    assert dialog.points_checks["nerfstudio"].isChecked() and not dialog.ns_depth_check.isChecked()
    dialog.ns_depth_check.setChecked(True)
    assert dialog.options().depth is True
    qtbot.waitUntil(lambda: dialog.estimate is not None and dialog.estimate.bytes_estimate > plain, timeout=20000)
    assert "no depth map yet" in dialog.warnings_label.text()
    dialog.resize(900, 780)
    dialog.grab().save("/tmp/export-depth-dialog.png")
    dialog.points_checks["nerfstudio"].setChecked(False)
    assert dialog.options().points is False
    dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index("hci"))
    assert dialog.options().depth is False and dialog.hci_depth_check.isVisibleTo(dialog)
    dialog.hci_depth_check.setChecked(True)
    assert dialog.options().depth is True
    dialog.format_combo.setCurrentIndex(FORMAT_KEYS.index("colmap"))
    assert dialog.options().depth is False and dialog.options().points is True


def test_a_map_whose_processed_image_is_gone_says_so_by_name(tiny_dataset):
    from lfstudio.dataset import Dataset
    from lfstudio.dataset.profile import Profile
    from lfstudio.depth.run import estimate_depth, read_disparity
    from lfstudio.errors import LfError
    from lfstudio.gui.views.depth import depth_picture
    from lfstudio.processing.pipeline import process_dataset

    _calibrate_exactly(tiny_dataset)
    profile = Profile()
    profile.resample.enabled = False
    assert process_dataset(tiny_dataset.root, profile).ok
    ds = Dataset.open(tiny_dataset.root)
    estimate_depth(ds, [(1, 2)])
    assert read_disparity(ds, (1, 2))[2]["source"] == "processed"
    depth_picture(ds, (1, 2))                          # shown while its processed image is there
    ds.processed_path(ds.view(1, 2)).unlink()
    with pytest.raises(LfError, match="r01_c002: .*compute the depth map again"):
        depth_picture(Dataset.open(ds.root), (1, 2))


def test_an_unknown_disparity_range_names_the_dialogs_field_not_the_cli_option(qtbot, tiny_dataset):
    """No scene plan and featureless views: the range cannot be measured. The Depth dialog's message
    names its own Disparity range field; it said 'state it (lfstudio depth --disparity-range MIN,MAX)'."""
    import cv2
    import numpy as np

    tiny_dataset.manifest["plan"] = {k: v for k, v in (tiny_dataset.manifest.get("plan") or {}).items()
                                     if k not in ("near_m", "far_m")}
    tiny_dataset.save()
    for v in tiny_dataset.views:                      # featureless: too few matches to measure the range
        cv2.imwrite(str(tiny_dataset.path_of(v)), np.full((20, 30), 100, np.uint8))
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.state.set_dataset(tiny_dataset)
    _action(window, "actionDepthMap").trigger()
    dialog = window.findChild(DepthDialog, "depthDialog")
    with qtbot.waitSignal(dialog.runner.failed, timeout=120000):
        dialog.compute_button.click()
    text = dialog.caption.text()
    assert "Disparity range" in text and "scene plan" in text, text
    assert "--" not in text and "lfstudio depth" not in text, text
