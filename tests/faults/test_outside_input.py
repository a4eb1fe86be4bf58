"""Fault matrix, input from outside (issue #42 items 10-12): names read from folders that are not
UTF-8, numbers and files that used to end in a traceback, a segfault or a dead end. Each case ends in
one line naming the file or field and the fix (exit 2 on the command line), with nothing half-written."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import cv2
import numpy as np
import pytest

from tests.conftest import REPO_ROOT
from tests.faults.conftest import assert_one_line_error

#: a Latin-1 name as another computer's camera software or archive may leave it (bytes e9 ff)
NOT_UTF8_FILE = os.fsdecode(b"shot_\xe9\xff.png")


def _views(folder, cols: int = 2, rows: int = 2, size=(48, 32)):
    """``cols`` x ``rows`` small 8-bit PNG views named v1.png … (a texture shifted per view)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(1)
    base = rng.integers(0, 255, (size[1], size[0] + 8, 3), dtype=np.uint8)
    for i in range(cols * rows):
        assert cv2.imwrite(str(folder / f"v{i + 1}.png"), np.ascontiguousarray(base[:, i % cols: i % cols + size[0]]))
    return folder


# -- item 10: names that are not UTF-8 ------------------------------------------------------------------
def test_import_images_refuses_a_file_name_that_is_not_utf8_by_its_escaped_bytes(tmp_path, run_cli):
    """It crashed (SIGSEGV, exit -11) in OpenCV's haveImageReader on the name."""
    folder = _views(tmp_path / "in", 2, 1)
    os.rename(folder / "v2.png", folder / NOT_UTF8_FILE)
    proc = run_cli("import-images", folder, "--grid", "2x1", "--spacing-mm", "5x5", "--focal-length-px", "100",
                   "--out", tmp_path / "ds")
    assert proc.returncode != -11, "segmentation fault"
    assert_one_line_error(proc, 2, "shot_\\xe9\\xff.png", "not valid UTF-8", "rename")
    assert not (tmp_path / "ds").exists()


def test_a_text_file_named_in_latin1_beside_the_views_is_ignored_as_text(tmp_path, run_cli):
    folder = _views(tmp_path / "in", 2, 1)
    (folder / os.fsdecode(b"notes_\xe9.txt")).write_text("notes of the day\n")
    proc = run_cli("import-images", folder, "--grid", "2x1", "--spacing-mm", "5x5", "--focal-length-px", "100",
                   "--out", tmp_path / "ds")
    assert proc.returncode == 0, proc.stderr


def test_the_image_module_never_hands_a_name_that_is_not_utf8_to_opencv(tmp_path):
    """Run in a child process: on the old code OpenCV's crash ends the process (exit -11)."""
    code = textwrap.dedent(f"""
        import os, sys
        from lfstudio.dataset import images
        path = os.path.join({str(tmp_path)!r}, os.fsdecode(b"v_\\xe9.png"))
        open(path, "wb").write(open({str(_views(tmp_path / 'v', 1, 1) / 'v1.png')!r}, "rb").read())
        for call in (images.kind, images.read_image, lambda p: images.read_grey(p, 64),
                     lambda p: images.preview_rgb8(p, 64)):
            try:
                call(path)
            except images.NotACapture as exc:
                assert "v_\\\\xe9.png" in str(exc) and "not valid UTF-8" in str(exc), str(exc)
            else:
                sys.exit("no error for " + repr(call))
        assert images.thumbnail_array(path, 32) is None
        print("ok")
    """)
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", (proc.returncode, proc.stderr)


def test_a_hot_folder_scan_stops_naming_a_new_file_that_is_not_utf8_instead_of_crashing(tmp_path):
    """A running hot-folder scan crashed (exit 139) when the camera software left such a name. Here
    the scan session the CLI and the window share runs in a child process; the file arrives when the
    scan moves to its first view; the scan pauses naming it and ends normally."""
    code = textwrap.dedent(f"""
        import os, threading
        from pathlib import Path
        from lfstudio.scan.events import EventKind, ScanState
        from lfstudio.scan.scan_plan import ScanPlan
        from lfstudio.studio.session import ScanRequest, ScanSession

        tmp = Path({str(tmp_path)!r})
        hot = tmp / "hot"
        hot.mkdir()
        session = ScanSession(ScanRequest(tmp / "ds", rig="instant", camera=f"folder:{{hot}}", time_scale=0.0),
                              doing="test")
        engine = session.open(lambda existing, rig: (ScanPlan.centered(2, 1, (4.0, 6.0), rig, settle_s=0.0), None))
        engine.camera.call("set_setting", "timeout_s", 20)
        paused = threading.Event()
        engine.subscribe(lambda ev: paused.set() if ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED else None)

        def arrive(ev):     # the camera software saves the shot once the scan has started
            if ev.kind is EventKind.VIEW_STARTED and not os.listdir(hot):
                with open(os.path.join(hot, os.fsdecode(b"shot_\\xe9\\xff.jpg")), "wb") as fh:
                    fh.write(b"\\xff\\xd8" + bytes(4000))

        engine.subscribe(arrive)
        engine.start()
        assert paused.wait(60), engine.message
        print(engine.message)
        engine.abort()
        assert engine.wait(60) is ScanState.FINISHED
        session.close()
    """)
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, (proc.returncode, proc.stderr)
    message = proc.stdout.strip()
    assert "shot_\\xe9\\xff.jpg" in message and "not valid UTF-8" in message, message
    assert message.startswith("Camera refused (view r00 c000)") and "cable" not in message, message


# -- item 11: one line instead of a traceback -----------------------------------------------------------
def _import(run_cli, folder, out, *extra):
    return run_cli("import-images", folder, "--focal-length-px", "100", "--out", out, *extra)


def _csv(path, rows):
    path.write_text("file,x_mm,y_mm\n" + "".join(f"{f},{x},{y}\n" for f, x, y in rows))
    return path


def test_recorded_positions_of_1e308_are_refused_by_line(tmp_path, run_cli):
    """They overflowed the grid fit (numpy LinAlgError: SVD did not converge)."""
    folder = _views(tmp_path / "in", 2, 2)
    csv = _csv(tmp_path / "pos.csv", [("v1.png", 0, 0), ("v2.png", 1e308, 0), ("v3.png", 0, 5), ("v4.png", 5, 5)])
    proc = _import(run_cli, folder, tmp_path / "ds", "--grid", "2x2", "--positions", csv)
    assert_one_line_error(proc, 2, "--positions", "pos.csv line 3", "1e+308 mm is out of range")
    assert not (tmp_path / "ds").exists()


def test_recorded_positions_that_are_all_equal_are_refused(tmp_path, run_cli):
    """They imported as a spacing of 0 mm (and depth divided by it)."""
    folder = _views(tmp_path / "in", 2, 2)
    csv = _csv(tmp_path / "pos.csv", [(f"v{i}.png", 12.5, 3.0) for i in range(1, 5)])
    for extra in ((), ("--spacing-mm", "5x5")):
        proc = _import(run_cli, folder, tmp_path / "ds", "--grid", "2x2", "--positions", csv, *extra)
        assert_one_line_error(proc, 2, "--positions", "do not change along the columns and rows")
        assert not (tmp_path / "ds").exists()


def _hci(folder, extra: str = "", cams=(2, 2), size=(48, 32)):
    """A small HCI benchmark folder (parameters.cfg and its views); ``extra``: added to [meta]."""
    _views(folder, *cams, size=size)
    for i in range(cams[0] * cams[1]):
        os.rename(folder / f"v{i + 1}.png", folder / f"input_Cam{i:03d}.png")
    (folder / "parameters.cfg").write_text(
        "[intrinsics]\n"
        f"image_resolution_x_px = {size[0]}\nimage_resolution_y_px = {size[1]}\n"
        "focal_length_mm = 100\nsensor_size_mm = 35\n\n"
        "[extrinsics]\n"
        f"num_cams_x = {cams[0]}\nnum_cams_y = {cams[1]}\nbaseline_mm = 50\nfocus_distance_m = 1000000000\n\n"
        f"[meta]\n{extra}")
    return folder


@pytest.mark.parametrize("value", ["%(x)s", "-1.5 %", "100%"])
def test_an_hci_parameters_file_with_percent_signs_gets_one_line(value, tmp_path, run_cli):
    """configparser's interpolation read '%' as a reference (InterpolationSyntaxError or
    InterpolationMissingOptionError traceback); a '%' in a value nobody reads is no obstacle."""
    folder = _hci(tmp_path / "hci", f"scene = 100% real, %(x)s\ndisp_min = {value}\ndisp_max = 2\n")
    proc = run_cli("import-images", folder, "--out", tmp_path / "ds")
    assert_one_line_error(proc, 2, "parameters.cfg", "[meta] disp_min", "is not a number")
    folder = _hci(tmp_path / "hci2", "scene = 100% real, %(x)s\n")
    proc = run_cli("import-images", folder, "--out", tmp_path / "ds2")
    assert proc.returncode == 0, proc.stderr


def test_an_hci_grid_of_100000_squared_is_refused_before_any_name_is_built(tmp_path, run_cli):
    """10^10 file names were built before any check (MemoryError)."""
    folder = _hci(tmp_path / "hci")
    cfg = folder / "parameters.cfg"
    cfg.write_text(cfg.read_text().replace("num_cams_x = 2", "num_cams_x = 100000")
                   .replace("num_cams_y = 2", "num_cams_y = 100000"))
    proc = run_cli("import-images", folder, "--out", tmp_path / "ds", timeout=60)
    assert_one_line_error(proc, 2, "parameters.cfg", "num_cams_x", "out of range")


def test_views_of_one_pixel_are_refused_at_import(tmp_path, run_cli):
    """They imported, and 'check' then asked for 18 EB of memory."""
    folder = _views(tmp_path / "in", 2, 2, size=(1, 1))
    proc = _import(run_cli, folder, tmp_path / "ds", "--grid", "2x2", "--spacing-mm", "5x5")
    assert_one_line_error(proc, 2, "v1.png is 1x1 px", "too small", "16x16 px")
    assert not (tmp_path / "ds").exists()


def test_check_of_views_narrower_than_its_disparity_search_ends_with_its_report(tmp_path, run_cli):
    """16 px views (the smallest an import or a scan takes): OpenCV's matcher asked for 18 EB."""
    folder = _views(tmp_path / "in", 2, 2, size=(16, 16))
    proc = _import(run_cli, folder, tmp_path / "ds", "--grid", "2x2", "--spacing-mm", "5x5")
    assert proc.returncode == 0, proc.stderr
    proc = run_cli("check", tmp_path / "ds")
    assert "Traceback" not in proc.stderr and proc.returncode == 0, proc.stderr
    assert (tmp_path / "ds" / "quality.json").is_file()


# -- item 12 ------------------------------------------------------------------------------------------
def test_duplicate_csv_rows_with_conflicting_positions_are_refused_naming_both(tmp_path, run_cli):
    folder = _views(tmp_path / "in", 2, 2)
    rows = [("v1.png", 0, 0), ("v2.png", 5, 0), ("v3.png", 0, 5), ("v4.png", 5, 5), ("v2.png", 7, 0)]
    proc = _import(run_cli, folder, tmp_path / "ds", "--grid", "2x2", "--positions", _csv(tmp_path / "pos.csv", rows))
    assert_one_line_error(proc, 2, "--positions", "lines 3 and 6", "v2.png", "(5, 0)", "(7, 0)")
    # the same position twice is harmless
    rows[-1] = ("v2.png", 5, 0)
    proc = _import(run_cli, folder, tmp_path / "ds", "--grid", "2x2", "--positions", _csv(tmp_path / "pos.csv", rows))
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize("url", ["http://a b/", "https://hooks.example.com/my hook", "ntfy+https://ntfy.sh/a\tb",
                                 "http://ex<ample>.com/x"])
def test_a_notify_url_with_a_space_or_a_bad_host_is_refused_at_parse(url, tmp_path, run_cli):
    """'http://a b/' was accepted, and the scan then waited 10 s at its end for a notice that could not go."""
    proc = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "2x1", "--notify", url,
                   "--out", tmp_path / "ds")
    assert_one_line_error(proc, 2, "--notify")
    assert not (tmp_path / "ds").exists()


def test_a_dataset_name_with_cr_lf_and_accents_reaches_ntfy_as_one_title_line():
    """A CR/LF in the dataset's name made http.client refuse the Title header: every ntfy notice was
    lost; a name that is not Latin-1 was refused the same way."""
    from email.header import decode_header, make_header

    from lfstudio.scan.notify import Notifier
    from tests.scan.receivers import Receiver

    receiver = Receiver()
    try:
        notifier = Notifier([receiver.url("/lab", "ntfy+http")], dataset="day 1\r\nX-Evil: yes Stühle ✓")
        notifier.notify("finished", "done", done=2, total=2)
        assert notifier.close(30)
        assert len(receiver.posts) == 1, "the notice was lost"
        headers = receiver.posts[0]["headers"]
        assert "X-Evil" not in headers
        assert str(make_header(decode_header(headers["Title"]))) == \
            "lfstudio: scan of day 1 X-Evil: yes Stühle ✓ finished"
    finally:
        receiver.close()


def test_a_symlinked_source_image_is_linked_as_the_file_it_leads_to(tmp_path, run_cli):
    """The hard link was made to the symlink itself, and the import failed naming its own hidden
    '.ds.partial-…' folder."""
    folder = _views(tmp_path / "in", 2, 2)
    elsewhere = _views(tmp_path / "elsewhere", 1, 1)
    (folder / "v4.png").unlink()
    (folder / "v4.png").symlink_to(elsewhere / "v1.png")
    proc = _import(run_cli, folder, tmp_path / "ds", "--grid", "2x2", "--spacing-mm", "5x5")
    assert proc.returncode == 0, proc.stderr
    raw = sorted((tmp_path / "ds" / "raw").iterdir())
    assert len(raw) == 4 and not any(p.is_symlink() for p in raw)
    assert raw[-1].read_bytes() == (elsewhere / "v1.png").read_bytes()


def test_an_error_while_a_dataset_is_built_names_the_destination_not_the_hidden_folder(tmp_path):
    from lfstudio.errors import DatasetError
    from lfstudio.export.common import partial_folder

    with pytest.raises(DatasetError) as err:
        with partial_folder(tmp_path / "ds", False) as tmp:
            raise DatasetError(f"{tmp}: cannot create dataset")
    assert str(err.value) == f"{tmp_path / 'ds'}: cannot create dataset"
    assert [p.name for p in tmp_path.iterdir()] == []


@pytest.mark.parametrize("cut", ["png", "jpeg"])
def test_a_truncated_image_is_one_line_and_exit_2_like_garbage_with_no_libpng_line(cut, tmp_path, run_cli):
    """A PNG cut short passed the header checks, then failed later with exit 1 and libpng's own
    'libpng error: …' line on stderr."""
    folder = _views(tmp_path / "in", 2, 1)
    if cut == "jpeg":
        for p in sorted(folder.glob("*.png")):
            img = cv2.imread(str(p))
            assert img is not None and cv2.imwrite(str(p.with_suffix(".jpg")), img)
            p.unlink()
    victim = sorted(folder.iterdir())[1]
    victim.write_bytes(victim.read_bytes()[: victim.stat().st_size * 2 // 3])
    proc = _import(run_cli, folder, tmp_path / "ds", "--grid", "2x1", "--spacing-mm", "5x5")
    line = assert_one_line_error(proc, 2, victim.name, "damaged or truncated")
    assert "libpng" not in proc.stderr and "error" not in proc.stderr.replace(line, ""), proc.stderr
    assert not (tmp_path / "ds").exists()


def test_a_process_refused_for_a_missing_calibration_leaves_no_processed_folder(scanned, run_cli):
    root = scanned(3, 2)
    assert not (root / "calibration.json").exists()
    proc = run_cli("process", root)
    assert proc.returncode == 2 and "calibration.json" in proc.stderr, proc.stderr
    assert not (root / "processed").exists()
