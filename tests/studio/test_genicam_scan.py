"""A scan with a GenICam camera (aravis's fake GigE Vision camera over the real protocol): the frames the
camera hands back as arrays are written, checksummed and journaled by the scan's store stage; bad device
words are one line each and write nothing."""

from __future__ import annotations

import hashlib
import json

import cv2
import numpy as np
import pytest

from tests.fakegv import expected_mono8, fake_gv_camera


def test_a_scan_stores_the_frames_as_16_bit_files_with_their_timestamps_and_they_process(tmp_path, run_cli):
    out = tmp_path / "ds"
    with fake_gv_camera() as fake:
        r = run_cli("scan", "--port", "instant", "--camera", f"genicam:{fake.device_id}", "--camera-option",
                    "packet_size=8000", "--grid", "3x2", "--spacing-mm", "4x4", "--out", out, timeout=180)
    assert r.returncode == 0, r.stderr
    manifest = json.loads((out / "dataset.json").read_text())
    views = manifest["views"]
    assert [v["status"] for v in views] == ["done"] * 6
    stamps = []
    for v in views:
        path = out / v["file"]
        assert path.suffix == ".png"
        assert hashlib.sha256(path.read_bytes()).hexdigest() == v["sha256"]
        frame = v["camera_frame"]
        assert frame["pixel_format"] == "Mono8" and frame["size_px"] == [512, 512]
        data = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(data, expected_mono8(frame["frame_id"]).astype(np.uint16) * 257)
        assert v["camera"]["serial"] == "GV01" and v["camera_settings"]["trigger_source"] == "Software"
        assert (out / v["thumb"]).is_file()
        stamps.append((frame["frame_id"], frame["timestamp_ns"]))
    by_id = [t for _, t in sorted(stamps)]
    assert by_id == sorted(by_id) and len(set(by_id)) == 6       # the camera's clock, one frame each
    camera = manifest["devices"]["camera"]
    assert camera["kind"] == "genicam" and camera["spec"] == f"genicam:{fake.device_id}"
    assert camera["model"] == "Fake" and camera["serial"] == "GV01"
    # the rest of the day on its frames (the fake camera's ramp has nothing to calibrate on)
    r = run_cli("process", out, "--no-rectify", "--workers", "1", timeout=300)
    assert r.returncode == 0 and "6 processed" in r.stdout + r.stderr, r.stderr
    r = run_cli("export", out, "--format", "png", "--out", tmp_path / "png", timeout=300)
    assert r.returncode == 0, r.stderr
    assert len(list((tmp_path / "png").glob("r*_c*.png"))) == 6


def test_a_genicam_id_that_does_not_answer_is_one_line_and_writes_nothing(tmp_path, run_cli):
    from tests.fakegv import need_aravis

    need_aravis()
    out = tmp_path / "ds"
    r = run_cli("scan", "--port", "instant", "--camera", "genicam:No-Such-Camera", "--grid", "2x1", "--out", out)
    assert r.returncode != 0
    lines = r.stderr.strip().splitlines()
    assert len(lines) <= 2 and "Traceback" not in r.stderr, r.stderr
    assert "genicam:No-Such-Camera: no camera answers" in r.stderr
    assert not (out / "dataset.json").exists()


@pytest.mark.parametrize("word, said", [
    ("nikon-wifi:1", "unknown camera kind 'nikon-wifi' (valid: one of sim, gphoto2, folder:PATH, genicam:ID, instant"),
    ("genicam:", "genicam: names no camera"),
    ("gphoto2:usb:001", "the gphoto2 camera takes nothing after 'gphoto2'"),
])
def test_bad_camera_words_are_one_line_naming_the_kinds(tmp_path, run_cli, word, said):
    out = tmp_path / "ds"
    r = run_cli("scan", "--port", "instant", "--camera", word, "--grid", "2x1", "--out", out)
    assert r.returncode != 0 and said in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not out.exists()


def test_a_camera_option_the_kind_has_not_is_named_with_those_it_has(tmp_path, run_cli):
    r = run_cli("camera", tmp_path / "shot", "--camera", "genicam:X", "--camera-option", "exposure=3")
    assert r.returncode != 0
    assert "genicam has no option 'exposure'" in r.stderr and "timeout_s, retries, packet_size, buffers" in r.stderr
    r = run_cli("camera", tmp_path / "shot", "--camera", "genicam:X", "--camera-option", "timeout_s=-1")
    assert r.returncode != 0 and "--camera-option timeout_s" in r.stderr
    assert not list(tmp_path.iterdir())


def test_a_pixel_format_lfstudio_cannot_store_is_one_line_and_no_shot(tmp_path, run_cli):
    with fake_gv_camera() as fake:
        r = run_cli("camera", tmp_path / "shot", "--camera", f"genicam:{fake.device_id}",
                    "--set", "pixel_format=Mono12Packed", timeout=120)
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "pixel format 'Mono12Packed' cannot be stored by lfstudio" in r.stderr and "Mono8" in r.stderr
    assert not list(tmp_path.iterdir())


def test_a_camera_opened_by_its_word_is_linked_by_it_again():
    from lfstudio.studio.devices import link_for_camera
    from lfstudio.studio.kinds import CameraKind, register_camera, unregister
    from lfstudio.studio.devices import open_camera
    from lfstudio.studio.simulated import InstantCamera

    register_camera(CameraKind("wordcam", lambda a, c: InstantCamera(), argument="X", origin="plugin t 1 (m:f)"))
    try:
        link = open_camera("wordcam:left", connect=False)
        assert link_for_camera(link.camera).spec.text == "wordcam:left"     # not taken for an instant camera
        link.close()
    finally:
        unregister("wordcam")
