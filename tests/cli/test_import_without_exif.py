"""Images without EXIF (plain PNG files): the focal length is unknown. The import's "next:" line is a
calibrate command that works once F is filled in; calibrate without it says so at once, naming
--focal-length-px (before, it detected features first and then failed naming JSON keys); the
calibration wizard warns and names its own Focal length field, and will not start without it."""

from __future__ import annotations

import shlex
import shutil

from lfstudio.dataset import Dataset


def _imported(run_cli, tiny_dataset, tmp_path):
    images = tmp_path / "plain"
    images.mkdir()
    for i, view in enumerate(sorted(tiny_dataset.done_views(), key=lambda v: (v["row"], v["column"]))):
        shutil.copy(tiny_dataset.path_of(view), images / f"img_{i:02d}.png")
    out = run_cli("import-images", images, "--grid", "5x3", "--spacing-mm", "4x6", "--out", tmp_path / "imported")
    assert out.returncode == 0, out.stderr
    return out, tmp_path / "imported"


def test_the_next_hint_works_and_calibrate_says_what_it_needs_first(run_cli, tiny_dataset, tmp_path):
    out, root = _imported(run_cli, tiny_dataset, tmp_path)
    hint = next(line for line in out.stdout.splitlines() if line.startswith("next: "))
    command = shlex.split(hint[len("next: "):].split("   (")[0])
    assert command[:2] == ["lfstudio", "calibrate"] and command[-2:] == ["--focal-length-px", "F"]
    failed = run_cli(*command[1:-2])
    assert failed.returncode == 2 and "--focal-length-px" in failed.stderr
    assert "features" not in failed.stderr and "lens.focal_length" not in failed.stderr   # at once, in options
    focal = f"{tiny_dataset.focal_length_px():.1f}"
    done = run_cli(*command[1:-1], focal, "--views", "array:3x2")
    assert done.returncode == 0, done.stderr
    assert Dataset.open(root).manifest is not None and (root / "calibration.json").is_file()


def test_the_wizard_names_its_focal_length_field(qtbot, run_cli, tiny_dataset, tmp_path):
    from lfstudio.gui.dialogs.calibration_wizard import CalibrationWizard
    from lfstudio.gui.state import AppState

    _out, root = _imported(run_cli, tiny_dataset, tmp_path)
    state = AppState()
    state.set_dataset(Dataset.open(root))
    wizard = CalibrationWizard(state)
    qtbot.addWidget(wizard)
    wizard.show()
    assert wizard.focal_note.isVisible() and "Focal length field" in wizard.focal_note.text()
    assert wizard.focal_px.specialValueText() == "unknown: enter it"
    wizard.apply_preset((3, 2))
    wizard.start_calibration()
    assert not wizard.runner.running and wizard.stack.currentIndex() == 0     # not started, still on the views
    assert "Focal length field" in wizard.focal_note.text() and "b00020" in wizard.focal_note.styleSheet()
    wizard.close()
