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
