import json

import cv2
import numpy as np
from PySide6.QtCore import QPoint, Qt

from lfstudio.gui.app import create_window
from lfstudio.gui.dialogs.calibration_wizard import PAGE_RESULTS, PAGE_RUN, PAGE_VIEWS, CalibrationWizard
from lfstudio.gui.state import AppState


def _action(window, name):
    menu = window.menu("Dataset")
    return next(a for a in menu.actions() if a.text().replace("&", "") == name)


def test_menu_entry_opens_the_wizard_for_the_open_dataset(qtbot, tiny_dataset):
    window = create_window(simulated=True)
    qtbot.addWidget(window)
    act = _action(window, "Calibrate…")
    assert not act.isEnabled() and act.toolTip()
    window.state.set_dataset(tiny_dataset)
    assert act.isEnabled()
    act.trigger()
    wizard = window.findChild(CalibrationWizard)
    assert wizard is not None and wizard.isVisible()
    assert wizard.stack.currentIndex() == PAGE_VIEWS
    # the default views over the 5 x 3 grid: every row x the first two and last two columns; the
    # default pair set (spanning) is every pair in each row (3 x 6) and column (4 x 3)
    assert len(wizard.picker.selected) == 12 and "18 horizontal + 12 vertical" in wizard.selection_label.text()
    wizard.close()


def test_wizard_runs_shows_results_and_saves(qtbot, tiny_dataset):
    state = AppState()
    state.set_dataset(tiny_dataset)
    wizard = CalibrationWizard(state)
    qtbot.addWidget(wizard)
    wizard.show()
    # the grid picker toggles a captured view on click
    wizard.apply_preset((2, 3))
    before = set(wizard.picker.selected)
    cell, x0, y0 = wizard.picker._geometry()
    qtbot.mouseClick(wizard.picker, Qt.LeftButton, pos=QPoint(int(x0 + 1.5 * cell), int(y0 + 1.5 * cell)))
    assert wizard.picker.selected == before | {(1, 1)}
    wizard.apply_preset((2, 3))
    with qtbot.waitSignal(wizard.runner.finished, timeout=120_000):
        wizard.next_button.click()
        assert wizard.stack.currentIndex() == PAGE_RUN
    assert wizard.stack.currentIndex() == PAGE_RESULTS
    assert "→" in wizard.headline.text() and "rotation" in wizard.report_text.toPlainText()
    doc = wizard.result["run"].document
    std = doc["uncertainty"]["rotation_std_deg"]
    assert f"± {std[0]:.3f}°" in wizard.headline.text()               # per angle, as the CLI prints it
    corner = doc["uncertainty"]["corner_error_px"]
    assert f"≤ {corner[0]:.3f} px (1σ)" in wizard.uncertainty_label.text()
    assert "principal point" in wizard.uncertainty_label.text()
    assert len(wizard.vector_lines.xData) > 20
    qtbot.waitUntil(lambda: hasattr(wizard, "inspection"), timeout=60_000)
    assert wizard.epi_items["h_after"].image is not None and wizard.epi_items["h_before"].image.shape[0] == 5
    assert wizard.pair_items[0].image is not None
    for i in range(wizard.tabs.count()):       # every tab renders something, not a blank page
        wizard.tabs.setCurrentIndex(i)
        img = wizard.grab().toImage()
        assert not img.isNull()
    wizard.accept_button.click()
    doc = json.loads((tiny_dataset.root / "calibration.json").read_text())
    assert doc["rotation_deg"] == wizard.accepted_document["rotation_deg"]


def test_cancel_and_errors_are_shown_on_the_page(qtbot, tiny_dataset):
    state = AppState()
    state.set_dataset(tiny_dataset)
    wizard = CalibrationWizard(state)
    qtbot.addWidget(wizard)
    with qtbot.waitSignal(wizard.runner.cancelled, timeout=60_000):
        wizard.start_calibration()
        wizard.job_widget.cancel_button.click()
    assert "Cancelled" in wizard.error_label.text() and wizard.back_button.isEnabled()
    wizard.go_back()
    for v in tiny_dataset.views:      # featureless images: too few matches
        cv2.imwrite(str(tiny_dataset.path_of(v)), np.full((20, 30), 100, np.uint8))
    with qtbot.waitSignal(wizard.runner.failed, timeout=60_000):
        wizard.start_calibration()
    assert "too few feature matches" in wizard.error_label.text()
    assert "Traceback" not in wizard.log.toPlainText()


def test_saved_wizard_choices_follow_improved_defaults_but_keep_a_real_choice(qtbot, tiny_dataset):
    """Choices saved by an older wizard (the old defaults 'all' pairs at 2000 px) do not pin a
    wizard to them; a choice that differs from the defaults survives reopening."""
    from lfstudio.calibration.features import DEFAULT_WORK_WIDTH_PX
    from lfstudio.calibration.pairs import DEFAULT_PAIR_SET, PAIR_SETS
    from lfstudio.gui.settings import settings

    s = settings()
    s.setValue("calibration/pair_set", "all")          # what every wizard closed before saved
    s.setValue("calibration/work_width_px", 2000)
    s.sync()
    state = AppState()
    state.set_dataset(tiny_dataset)

    def open_wizard():
        w = CalibrationWizard(state)
        qtbot.addWidget(w)
        return w

    wizard = open_wizard()
    assert wizard.pair_set.currentData() == DEFAULT_PAIR_SET
    assert wizard.work_width.value() == DEFAULT_WORK_WIDTH_PX
    other = next(p for p in PAIR_SETS if p != DEFAULT_PAIR_SET)
    wizard.pair_set.setCurrentIndex(PAIR_SETS.index(other))
    wizard.work_width.setValue(DEFAULT_WORK_WIDTH_PX + 400)
    wizard.reject()
    again = open_wizard()
    assert again.pair_set.currentData() == other and again.work_width.value() == DEFAULT_WORK_WIDTH_PX + 400
    again.pair_set.setCurrentIndex(PAIR_SETS.index(DEFAULT_PAIR_SET))   # back to the default: not pinned
    again.reject()
    assert settings().value("calibration/pair_set") is None


def test_a_one_row_dataset_says_which_angle_is_held(qtbot, tmp_path):
    from tests.calibration.synthetic import make_layered_dataset

    ds = make_layered_dataset(tmp_path / "row", columns=3, rows=1, size_px=(480, 320), rotation_deg=(0.0, -1.5, 2.0))
    state = AppState()
    state.set_dataset(ds)
    wizard = CalibrationWizard(state)
    qtbot.addWidget(wizard)
    wizard.show()
    assert wizard.next_button.isEnabled() and "rows only: pan and roll are determined, tilt is held at 0°" \
        in wizard.selection_label.text()
    wizard.next_button.click()
    qtbot.waitUntil(lambda: wizard.stack.currentIndex() == PAGE_RESULTS or "failed" in wizard.log.toPlainText(),
                    timeout=120_000)
    assert wizard.stack.currentIndex() == PAGE_RESULTS, wizard.log.toPlainText()
    assert "rx +0.000° (held: not determined)" in wizard.headline.text()
    assert "ry " in wizard.headline.text() and "± " in wizard.headline.text()
    text = wizard.uncertainty_label.text()
    assert "tilt (rx): not determined by one row — held at 0°" in text and "rows will line up" in text
    wizard.resize(1100, 800)
    wizard.grab().save(str(tmp_path / "wizard_one_row.png"))
    import shutil
    shutil.copy(tmp_path / "wizard_one_row.png", "/tmp/wizard_one_row.png")
