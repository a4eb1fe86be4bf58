"""The Planner panel: typing into fields changes outputs and warnings; files; QSettings; plots."""

import json

import pytest
from PySide6.QtCore import Qt

from lfstudio.gui.app import create_window
from lfstudio.gui.imageutil import qimage_to_rgb
from lfstudio.gui.panels.planner import style_prop
from lfstudio.planning.presets import reference_plan
from lfstudio.planning.scene_plan import load_plan, save_plan


@pytest.fixture
def window(qtbot):
    w = create_window(simulated=True)
    qtbot.addWidget(w)
    w.resize(1500, 950)
    w.show()
    qtbot.waitExposed(w)
    return w


def planner(window):
    return window.panels["plannerDock"]


def type_into(qtbot, box, text):
    """Select the field's text and type like a user (keyboard tracking fires on every key)."""
    box.setFocus()
    box.selectAll()
    qtbot.keyClicks(box.lineEdit(), text)


def test_reference_plan_shown_and_published(window, qtbot):
    p = planner(window)
    qtbot.waitUntil(lambda: window.state.plan is not None)
    assert window.state.plan == reference_plan()
    assert p.outputs["aperture"].text().startswith("f/15.3")
    assert "2121" in p.outputs["images"].text()
    assert "1.77 m" in p.outputs["min_distance"].text()


def test_typing_changes_outputs_and_warnings(window, qtbot):
    p = planner(window)
    near = p.rows["near_m"].spins[0]
    assert not p.rows["near_m"].message.isVisible()
    type_into(qtbot, near, "1.2")
    qtbot.waitUntil(lambda: p.plan is not None and p.plan.near_m == pytest.approx(1.2))
    # 80 µm at 1.2 m is 0.74 px > 0.5 px: a warning next to the near field, the field marked
    qtbot.waitUntil(lambda: p.rows["near_m"].message.isVisible())
    assert "1.77 m" in p.rows["near_m"].message.text()
    assert style_prop(near, "severity") == "warning"
    assert p.outputs["reposition"].text().startswith("0.74")
    assert window.state.plan.near_m == pytest.approx(1.2)       # still valid: published

    fnum = p.rows["f_number"].spins[0]
    type_into(qtbot, fnum, "8")
    qtbot.waitUntil(lambda: p.plan.f_number == 8)
    qtbot.waitUntil(lambda: "sharp" in p.rows["f_number"].message.text())
    assert style_prop(p.outputs["sharp"], "flag") == "bad"


def test_invalid_input_marks_field_and_keeps_last_valid_plan(window, qtbot):
    p = planner(window)
    qtbot.waitUntil(lambda: window.state.plan is not None)
    published = window.state.plan
    far = p.rows["far_m"].spins[0]
    type_into(qtbot, far, "1.5")              # not beyond the near distance 1.77 m
    qtbot.waitUntil(lambda: p.error is not None)
    assert p.error.field == "far_m"
    assert style_prop(far, "severity") == "error"
    assert "near distance" in p.rows["far_m"].message.text()
    assert p.outputs["aperture"].text() == "—"
    assert "Far" in p.status_label.text()
    assert window.state.plan == published     # an invalid plan is never published
    type_into(qtbot, far, "6")
    qtbot.waitUntil(lambda: p.error is None)
    assert style_prop(far, "severity") == ""
    assert window.state.plan.far_m == 6


def test_grid_beyond_travel_is_marked_not_published(window, qtbot):
    p = planner(window)
    qtbot.waitUntil(lambda: window.state.plan is not None)
    type_into(qtbot, p.rows["grid"].spins[0], "2000")
    qtbot.waitUntil(lambda: p.plan.grid_columns == 2000)
    assert "travel" in p.rows["grid"].message.text()
    assert style_prop(p.rows["grid"].spins[0], "severity") == "error"
    assert "beyond travel" in p.outputs["images"].text()
    assert window.state.plan.grid_columns == 101


def test_presets_fill_fields_and_edits_switch_to_custom(window, qtbot):
    p = planner(window)
    p.combos["camera_name"].setCurrentText("Nikon Z7 II")
    qtbot.waitUntil(lambda: p.plan.camera_name == "Nikon Z7 II")
    assert p.rows["sensor_px"].spins[0].value() == 8256
    p.combos["rig_name"].setCurrentText("Desktop slider 1 m")
    qtbot.waitUntil(lambda: p.plan.rig_name == "Desktop slider 1 m")
    assert p.rows["repeatability_um"].spins[0].value() == 20
    type_into(qtbot, p.rows["sensor_px"].spins[0], "6000")
    qtbot.waitUntil(lambda: p.plan.sensor_px[0] == 6000)
    assert p.combos["camera_name"].currentText() == "Custom"
    assert "Nikon Z7 II" in p.plan.camera_name


def test_proposed_spacing_button(window, qtbot):
    p = planner(window)
    qtbot.mouseClick(p.apply_spacing_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: p.plan.spacing_mm[0] < 1)
    assert p.result.neighbour_disparity_px["horizontal"] == pytest.approx(1.0, abs=0.01)


def test_wanted_parallax_shows_the_proposed_grid(window, qtbot):
    p = planner(window)
    assert p.outputs["proposed_grid"].text() == "— (set a wanted parallax)"
    type_into(qtbot, p.rows["target_parallax_fraction"].spins[0], "20")
    qtbot.waitUntil(lambda: p.result is not None and p.result.proposed_grid is not None)
    grid = p.result.proposed_grid                      # the dataset's typed Grid at the plan's spacing
    assert grid.columns == 103 and grid.spacing_mm == p.plan.grid.spacing_mm
    assert p.outputs["proposed_grid"].text() == f"103 × {grid.rows} for 20 %"


def test_plan_file_round_trip_through_the_panel(window, qtbot, tmp_path):
    p = planner(window)
    plan = reference_plan().replace(near_m=2.5, far_m=8.0, f_number=16.0, grid_columns=51, grid_rows=11)
    path = tmp_path / "scene.toml"
    save_plan(path, plan)
    assert p.open_plan_file(path)
    assert p.current_plan() == plan
    assert p.rows["f_number"].spins[0].value() == 16
    out = tmp_path / "again.json"
    assert p.save_plan_file(out)
    assert load_plan(out) == plan
    assert json.loads(out.read_text())["format"] == "lfstudio-plan"


def test_bad_plan_file_reports_without_raising(window, qtbot, tmp_path):
    p = planner(window)
    bad = tmp_path / "bad.toml"
    bad.write_text("this is = not [toml")
    with qtbot.waitSignal(window.state.errorOccurred) as sig:
        assert not p.open_plan_file(bad)
    assert "bad.toml" in sig.args[1]


def test_last_plan_returns_on_start(qtbot):
    w1 = create_window(simulated=True)
    qtbot.addWidget(w1)
    p1 = w1.panels["plannerDock"]
    p1.set_plan(reference_plan().replace(near_m=3.0, far_m=9.0, grid_columns=31))
    p1.evaluate()
    w1.close()
    w2 = create_window(simulated=True)
    qtbot.addWidget(w2)
    plan = w2.panels["plannerDock"].current_plan()
    assert (plan.near_m, plan.far_m, plan.grid_columns) == (3.0, 9.0, 31)


def test_file_menu_has_plan_actions(window):
    texts = [a.text() for a in window.menu("File").actions()]
    assert "Open plan…" in texts and "Save plan as…" in texts
    assert all(a.toolTip() for a in window.menu("File").actions() if a.text())


def test_plots_follow_the_plan_and_are_not_blank(window, qtbot):
    plots = window.panels["planPlotsDock"]
    qtbot.waitUntil(lambda: window.state.plan is not None)
    assert plots.dof_plot.getPlotItem().listDataItems()
    assert len(plots.disparity_plot.getPlotItem().listDataItems()) == 4
    before = plots.note.text()
    planner(window).set_plan(reference_plan().replace(spacing_mm=(8.0, 6.0)))
    qtbot.waitUntil(lambda: plots.note.text() != before)
    assert "31.38 px horizontal" in plots.note.text()
    pixels = qimage_to_rgb(plots.grab().toImage())
    assert pixels.std() > 10
    # every curve named in a legend that sits outside the plotted area (it covered the curves of a narrow plot)
    for plot, names in ((plots.dof_plot, 4), (plots.disparity_plot, 4)):
        item = plot.getPlotItem()
        assert len(item.legend.items) == names
        assert not item.legend.sceneBoundingRect().intersects(item.getViewBox().sceneBoundingRect())


def test_planner_keeps_full_height_at_1500x950(window):
    """Panels that share the left area are tabs, so the Planner is not squeezed by them."""
    dock = window.docks["plannerDock"]
    others = [d for name, d in window.docks.items()
              if name != "plannerDock" and window.dockWidgetArea(d) == window.dockWidgetArea(dock)]
    tabbed = window.tabifiedDockWidgets(dock)
    assert all(d in tabbed for d in others)
    assert dock.height() > 700
    assert window.height() <= 960


@pytest.mark.parametrize("height", [250, 420])
def test_a_low_planner_dock_has_one_scroll_bar(window, qtbot, height):
    """Lower than the Planner's minimum, its dock scrolled and the inputs' own area scrolled inside it:
    two vertical scroll bars, one in the other. Now the dock's scroll bar alone reaches every input."""
    from PySide6.QtWidgets import QScrollArea

    dock = window.docks["plannerDock"]
    dock.setFloating(True)
    dock.resize(480, height)
    area, panel = dock.widget(), window.panels["plannerDock"]
    inner = panel.findChild(QScrollArea, "plannerScroll")
    qtbot.waitUntil(lambda: area.viewport().height() <= height and panel.height() >= panel.minimumHeight(),
                    timeout=5000)
    qtbot.wait(50)       # not a synchronisation: the layout gets turns of the event loop to settle
    outer_scrolls = area.verticalScrollBar().maximum() > 0
    inner_scrolls = inner.verticalScrollBar().maximum() > 0
    assert not (outer_scrolls and inner_scrolls), (height, area.verticalScrollBar().maximum(),
                                                   inner.verticalScrollBar().maximum())
    if height < panel.minimumSizeHint().height():
        assert outer_scrolls and not inner_scrolls


def test_every_editor_accepts_exactly_what_the_plan_accepts(window):
    """One description per parameter: each editor's range is the scene plan's own (the window once
    took 100 000 columns where the plan stops at 20 000, and a pixel pitch of 0 the plan refuses)."""
    from lfstudio.planning.scene_plan import PARAMS

    p = planner(window)
    checked = 0
    for key, row in p.rows.items():
        if not row.spins:
            continue                                   # presets and the bracket: text
        name = "grid_columns" if key == "grid" else key
        param = PARAMS[name]
        scale = 100.0 if key == "target_parallax_fraction" else 1.0
        for box in row.spins:
            top, bottom = box.maximum() / scale, box.minimum() / scale
            assert param.number.check(name, top) == pytest.approx(top)                 # the top is valid
            assert param.number.problem(top * 1.001 + 1) is not None                     # and nothing above
            if param.optional:
                assert param.number.problem(bottom) is not None    # the minimum means None ("auto")
                assert box.specialValueText() == param.optional
            else:
                assert param.number.problem(bottom) is None
            assert param.label == row.label.text()
            checked += 1
    assert checked >= 25
    grid = p.rows["grid"].spins[0]
    assert grid.maximum() == 20_000 and p.rows["pixel_pitch_um"].spins[0].minimum() == pytest.approx(0.1)


def test_the_disk_row_checks_the_disk_of_the_scan_panels_dataset_folder(window, qtbot, small_disk, tmp_path):
    """The Planner measures the free space (off the GUI thread) of the folder the Scan panel will write to:
    a 1 GB tmpfs is too little for the reference grid's raw files (179 GB) (marked, the tooltip naming the need,
    the free space, the folder and the fix); a 3 x 2 grid (506 MB) on the same disk is not."""
    p = planner(window)
    scan = window.panels["scanPanel"]
    qtbot.waitUntil(lambda: p.result is not None)
    disk = small_disk(2**30)                     # a tmpfs takes memory only for what is written
    scan.folder.setText(str(disk.path / "studio"))
    qtbot.waitUntil(lambda: p.destination is not None and p.destination[0] == str(disk.path / "studio"), timeout=5000)
    out = p.outputs["disk"]
    assert out.text().splitlines()[1:] == ["1.1 GB free: too little", f"on the disk at …{str(disk.path)[-25:]}"]
    assert style_prop(out, "flag") == "bad"
    tip = out.toolTip()
    assert tip.startswith("Disk too small for this scan: 2121 views need about") and str(disk.path / "studio") in tip
    assert "the plan's" in tip and "Fix: free space there" in tip
    p.grab().save(str(tmp_path / "planner-disk.png"))
    p.set_plan(p.current_plan().replace(grid_columns=3, grid_rows=2))
    p.evaluate()
    assert out.text().splitlines()[1] == "1.1 GB free: enough", out.text()
    assert style_prop(out, "flag") == ""
    scan.folder.setText("")
    qtbot.waitUntil(lambda: p.destination is None)
    assert "free at" not in out.text() and "Scan panel" in out.toolTip()


def test_the_fly_fields_and_continuous_motion(window, qtbot):
    """#40: the fly scan's inputs (blur limit, frame rate, bandwidth, report rate, fly speed) are editors of
    the plan, and "Continuous motion" makes the capture time the fly scan's."""
    p = planner(window)
    box = p.fly_box
    assert box.isCheckable() and box.title() == "Continuous motion (fly scan)"
    for key in ("blur_limit_px", "frame_rate_fps", "bandwidth_mb_s", "report_rate_hz", "fly_speed_mm_s"):
        assert key in p.rows and p.rows[key].spins[0].parent() is box
    box.setChecked(False)
    qtbot.waitUntil(lambda: "fly scan" not in p.outputs["time"].text())
    # the reference camera's 0.5 s exposure allows no fly speed at 0.5 px of blur
    assert p.outputs["fly"].text().startswith("not possible")
    assert style_prop(p.outputs["fly"], "flag") == ""        # plain: nobody asked for a fly scan
    box.setChecked(True)
    qtbot.waitUntil(lambda: style_prop(p.outputs["fly"], "flag") == "warn")     # asked for: the warning colour
    assert all(s.isEnabled() for s in p.rows["blur_limit_px"].spins)
    qtbot.waitUntil(lambda: "no fly speed" in p.outputs["time"].text())
    assert style_prop(p.outputs["time"], "flag") == "warn"
    # a machine-vision camera: 1 ms, 20 frames/s
    type_into(qtbot, p.rows["exposure_s"].spins[0], "0.001")
    type_into(qtbot, p.rows["frame_rate_fps"].spins[0], "20")
    qtbot.waitUntil(lambda: p.plan is not None and p.plan.frame_rate_fps == 20 and p.plan.exposure_s == 0.001)
    qtbot.waitUntil(lambda: "fly scan" in p.outputs["time"].text())
    assert "80 mm/s (camera frame rate binds)" in p.outputs["fly"].text()
    type_into(qtbot, p.rows["fly_speed_mm_s"].spins[0], "40")
    qtbot.waitUntil(lambda: p.plan.fly_speed_mm_s == 40)
    qtbot.waitUntil(lambda: "at 40 mm/s" in p.outputs["fly"].text())
    assert window.state.plan.fly_speed_mm_s == 40 and window.state.plan.frame_rate_fps == 20   # published
    type_into(qtbot, p.rows["blur_limit_px"].spins[0], "0.1")
    qtbot.waitUntil(lambda: p.plan.blur_limit_px == pytest.approx(0.1))
    qtbot.waitUntil(lambda: p.outputs["fly"].text().startswith("not possible"))
    assert "blur" in p.outputs["fly"].toolTip()
    box.setChecked(False)
    assert not p.rows["fly_speed_mm_s"].spins[0].isEnabled()       # the box's fields follow it


def test_take_grid_from_the_plan_takes_the_fly_choice(window, qtbot):
    """The Planner's and the Scan panel's "Continuous motion (fly scan)" ticks: Take grid from the plan
    (and a new plan) copies the Planner's to the Scan panel (they were independent)."""
    p, scan = planner(window), window.panels["scanPanel"]
    p.fly_box.setChecked(False)
    qtbot.waitUntil(lambda: "fly scan" not in p.outputs["time"].text())
    scan.fly.setChecked(False)
    p.fly_box.setChecked(True)
    type_into(qtbot, p.rows["fly_speed_mm_s"].spins[0], "40")
    qtbot.waitUntil(lambda: window.state.plan is not None and window.state.plan.fly_speed_mm_s == 40)
    qtbot.mouseClick(scan.from_plan, Qt.MouseButton.LeftButton)
    assert scan.fly.isChecked()
    qtbot.waitUntil(lambda: "continuous motion at 40 mm/s" in scan.log_view.toPlainText())
    assert "continuous motion" in scan.summary.text() and "Planner plans" not in scan.summary.text()
    scan.fly.setChecked(False)       # the operator unticks the Scan panel's: the summary says they differ
    assert "the Planner plans a fly scan: Take grid from the plan" in scan.summary.text()
    p.fly_box.setChecked(False)
    qtbot.waitUntil(lambda: "no fly speed" not in p.outputs["time"].text() and "fly scan" not in p.outputs["time"].text())
    qtbot.mouseClick(scan.from_plan, Qt.MouseButton.LeftButton)
    assert not scan.fly.isChecked()
    p.fly_box.setChecked(True)       # the Planner's tick alone (the plan unchanged): the Scan panel follows
    qtbot.waitUntil(scan.fly.isChecked)
