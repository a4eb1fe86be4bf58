"""The Process… dialog on a real dataset: menu entry, preview, picking, run with progress, refresh."""

from __future__ import annotations

from PySide6.QtCore import QPoint, Qt

from lfstudio.dataset import Dataset
from lfstudio.gui.app import create_window
from lfstudio.gui.dialogs.process_dialog import ProcessDialog
from lfstudio.gui.imageutil import qimage_to_rgb


def _dialog(qtbot, ds):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    window.state.set_dataset(ds)
    actions = {a.text().replace("&", ""): a for a in window.menu("Dataset").actions()}
    assert "Process…" in actions and actions["Process…"].isEnabled()
    actions["Process…"].trigger()
    dialog = window.findChild(ProcessDialog, "processDialog")
    assert dialog is not None
    return window, dialog


def test_preview_pick_and_process(qtbot, make_dataset):
    ds = make_dataset(rows=1, cols=3, gains={(0, 0): 1.1}, w=96, h=64)
    window, dialog = _dialog(qtbot, ds)
    dialog.editors["rectify"].setChecked(False)  # no calibration in this dataset
    dialog.workers_spin.setValue(2)                # a real process pool under the GUI
    with qtbot.waitSignal(dialog.preview_runner.finished, timeout=30000):
        dialog.update_preview()
    assert "gain" in dialog.preview_info.text()
    pixels = qimage_to_rgb(dialog.split_view.grab().toImage())
    assert pixels.std() > 5  # an image, not an empty frame

    # pick the white point by clicking the preview
    dialog.pick_white.click()
    assert dialog.split_view.pick_mode == "white"
    r = dialog.split_view.image_rect()
    qtbot.mouseClick(dialog.split_view, Qt.LeftButton, pos=QPoint(int(r.center().x()), int(r.center().y())))
    values = dialog.editors["color"].values()
    assert values["mode"] == "points" and values["white_point_px"] != [0.0, 0.0]
    assert dialog.split_view.pick_mode is None
    dialog.editors["color"].setChecked(False)

    changed = []
    window.state.datasetChanged.connect(changed.append)
    with qtbot.waitSignal(dialog.runner.finished, timeout=60000):
        dialog.process_button.click()
    assert "3 processed" in dialog.result_label.text()
    assert "process pool (2 workers)" in dialog.result_label.text()
    assert dialog.progress.eta_label.text().startswith("took ")   # not an ETA left over from the run
    assert changed and changed[-1].view(0, 0)["processed"]["status"] == "done"
    assert "3</b> of 3" in window.panels["processingPanel"].summary.text()
    assert Dataset.open(ds.root).manifest["processing"]["profile"]["rectify"]["enabled"] is False


def test_bad_field_is_reported_not_raised(qtbot, make_dataset):
    ds = make_dataset(rows=1, cols=2)
    window, dialog = _dialog(qtbot, ds)
    dialog.editors["lens"].fields["dist_coeffs"].setText("0.1 abc")
    dialog.update_preview()
    assert "dist coeffs" in dialog.preview_info.text() and not dialog.preview_runner.running


def test_processing_without_calibration_says_how_to_fix(qtbot, make_dataset):
    ds = make_dataset(rows=1, cols=2)
    window, dialog = _dialog(qtbot, ds)
    dialog.workers_spin.setValue(0)
    with qtbot.waitSignal(dialog.runner.failed, timeout=30000):
        dialog.process_button.click()
    assert "calibrate" in dialog.result_label.text()


def test_broken_profile_file_is_reported_and_defaults_are_used(qtbot, make_dataset):
    ds = make_dataset(rows=1, cols=2)
    (ds.root / "processing.toml").write_text("[resample]\nscale = 7\n")
    window, dialog = _dialog(qtbot, ds)
    qtbot.waitUntil(lambda: "scale" in window.statusBar().currentMessage())
    assert dialog.profile() == dialog.profile().__class__()


def _shown(label) -> str:
    """The text a rich-text label displays (markup rendered, entities decoded)."""
    from PySide6.QtGui import QTextDocument

    doc = QTextDocument()
    doc.setHtml(label.text())
    return doc.toPlainText()


def _spin(dialog, step, key):
    return dialog.editors[step].fields[key]


def test_wheel_scrolls_the_profile_and_changes_a_value_only_after_a_click(qtbot, make_dataset):
    """A wheel turned over the profile scrolls it; the field under the pointer keeps its value."""
    from PySide6.QtCore import QPointF
    from PySide6.QtTest import QTest
    from PySide6.QtWidgets import QScrollArea

    ds = make_dataset(rows=1, cols=2)
    window, dialog = _dialog(qtbot, ds)
    qtbot.waitExposed(dialog)
    spin = _spin(dialog, "color", "white_output")
    scroll = spin.parentWidget()
    while not isinstance(scroll, QScrollArea):
        scroll = scroll.parentWidget()
    scroll.ensureWidgetVisible(spin)
    bar = scroll.verticalScrollBar()
    assert bar.maximum() > bar.value()          # there is more profile below to scroll to
    start = bar.value()

    def wheel_over_spin(notches: int) -> None:
        centre = spin.mapTo(dialog, spin.rect().center())
        for _ in range(notches):
            QTest.wheelEvent(dialog.windowHandle(), QPointF(centre), QPoint(0, -120))

    wheel_over_spin(3)
    qtbot.waitUntil(lambda: bar.value() > start)
    assert spin.value() == 0.9 and not spin.hasFocus()

    scroll.ensureWidgetVisible(spin)
    qtbot.mouseClick(spin, Qt.LeftButton)       # the operator picks the field on purpose
    assert spin.hasFocus()
    wheel_over_spin(30)                          # far more than the value allows
    qtbot.waitUntil(lambda: spin.value() < 0.9)
    assert 0 < spin.value() <= 1                # the widget holds what the profile accepts
    assert dialog.profile().color.white_output == spin.value()


def test_every_number_field_holds_only_what_the_profile_accepts(qtbot, make_dataset):
    from lfstudio.dataset.profile import LIMITS

    ds = make_dataset(rows=1, cols=2)
    window, dialog = _dialog(qtbot, ds)
    checked = 0
    for (step, key), limits in LIMITS.items():
        spin = _spin(dialog, step, key)
        for extreme in (-1e9, 1e9):
            spin.setValue(extreme)
            assert limits.problem(spin.value()) is None, (step, key, spin.value(), limits.valid())
        checked += 1
        spin.setValue(spin.minimum())
    assert checked == len(LIMITS)


def test_messages_name_the_fields_as_the_dialog_labels_them(qtbot, make_dataset):
    from PySide6.QtWidgets import QLabel

    ds = make_dataset(rows=1, cols=2)
    window, dialog = _dialog(qtbot, ds)
    deflicker = dialog.editors["deflicker"]
    assert deflicker.form.labelForField(deflicker.fields["low"]).text() == "low"
    deflicker.fields["low"].setValue(0.6)
    deflicker.fields["high"].setValue(0.5)
    dialog.process_button.click()               # refused before anything runs, on the dialog itself
    text = _shown(dialog.result_label)
    assert "De-flicker (gain to the reference) › low/high: need low < high" in text, text
    assert "[deflicker]" not in text and not dialog.runner.running
    dialog.update_preview()
    assert "De-flicker (gain to the reference) › low/high: need low < high" in _shown(dialog.preview_info)
    # the group title and row label the message names are the ones on screen
    assert deflicker.title().endswith("De-flicker (gain to the reference)")
    assert isinstance(deflicker.form.labelForField(deflicker.fields["high"]), QLabel)


def test_close_button_closes_the_idle_dialog(qtbot, make_dataset):
    ds = make_dataset(rows=1, cols=2)
    window, dialog = _dialog(qtbot, ds)
    qtbot.waitExposed(dialog)
    assert dialog.close_button.text().replace("&", "") == "Close"
    qtbot.mouseClick(dialog.close_button, Qt.LeftButton)
    qtbot.waitUntil(lambda: not dialog.isVisible())


def test_choices_are_shown_in_operator_words_and_saved_as_the_profile_values(qtbot, make_dataset):
    """The de-flicker statistic showed the profile's internal name 'median_ratio'."""
    ds = make_dataset(rows=1, cols=2)
    window, dialog = _dialog(qtbot, ds)
    statistic = dialog.editors["deflicker"].fields["statistic"]
    shown = [statistic.itemText(i) for i in range(statistic.count())]
    assert not any("_" in text for text in shown), shown
    assert statistic.currentText() == "median of per-pixel ratios (robust)"
    statistic.setCurrentIndex(statistic.findText("ratio of the medians"))
    assert dialog.editors["deflicker"].values()["statistic"] == "median"
    dialog.editors["deflicker"].set_value("statistic", "median_ratio")
    assert statistic.currentText() == "median of per-pixel ratios (robust)"
    for editor in dialog.editors.values():          # no other choice shows an internal name either
        for field in editor.fields.values():
            if hasattr(field, "itemText"):
                assert not any("_" in field.itemText(i) for i in range(field.count())), editor.name


def test_every_editor_is_made_from_the_profiles_description(qtbot, make_dataset):
    """One description per parameter: each row's label, tip, kind and range are the profile's own
    (lfstudio.dataset.profile.PARAMS), so the dialog accepts exactly what the profile does."""
    from PySide6.QtWidgets import QCheckBox, QComboBox, QDoubleSpinBox, QLineEdit, QSpinBox

    from lfstudio.dataset.profile import PARAMS

    ds = make_dataset(rows=1, cols=2)
    window, dialog = _dialog(qtbot, ds)
    for (step, key), param in PARAMS.items():
        editor = dialog.editors[step]
        if key == "enabled":
            assert editor.isCheckable()
            continue
        w = editor.fields[key]
        assert editor.form.labelForField(w).text() == param.label and param.tip in w.toolTip(), (step, key)
        if param.choices:
            assert isinstance(w, QComboBox) and [w.itemData(i) for i in range(w.count())] == list(param.choices)
        elif param.flag:
            assert isinstance(w, QCheckBox)
        elif param.lengths or param.number is None:
            assert isinstance(w, QLineEdit)
        else:
            assert isinstance(w, QSpinBox if param.number.integer else QDoubleSpinBox), (step, key)
            for end in (w.minimum(), w.maximum()):
                assert param.number.problem(end) is None, (step, key, end)      # both ends valid
            n = param.number
            if n.high is not None:
                assert w.maximum() == n.high, (step, key)                         # and the whole top reachable
            if n.low is not None and not n.low_open:
                assert w.minimum() == n.low, (step, key)


def test_a_bracketed_scan_is_processed_then_merged_and_the_dialog_reports_both(qtbot, bracketed):
    ds, _studio = bracketed
    window, dialog = _dialog(qtbot, Dataset.open(ds.root))
    for step in ("color", "deflicker", "shading", "rectify", "resample"):
        dialog.editors[step].setChecked(False)
    with qtbot.waitSignal(dialog.runner.finished, timeout=120000):
        dialog.process_button.click()
    text = dialog.result_label.text()
    assert "2 processed" in text
    assert "HDR: 2 views merged" in text
    assert [v["hdr"]["status"] for v in Dataset.open(ds.root).done_views()] == ["done", "done"]
