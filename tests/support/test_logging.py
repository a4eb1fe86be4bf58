"""The log file: where it goes, what device traffic it records, the CLI's --debug and doctor."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import pytest

from lfstudio.support import logs


@pytest.fixture
def configured_logging():
    """setup_logging() for one test; our handlers are removed afterwards."""
    root = logging.getLogger()
    before = list(root.handlers), root.level
    yield logs.setup_logging
    for h in list(root.handlers):
        if h not in before[0]:
            root.removeHandler(h)
            h.close()
    root.setLevel(before[1])


def test_log_dir_follows_env_override(tmp_path, monkeypatch):
    monkeypatch.setenv("LFSTUDIO_LOG_DIR", str(tmp_path / "logs"))
    assert logs.log_file() == tmp_path / "logs" / "lfstudio.log"
    monkeypatch.delenv("LFSTUDIO_LOG_DIR")
    assert logs.log_file().name == "lfstudio.log" and "lfstudio" in str(logs.log_dir())


def test_grbl_exchange_is_logged_at_debug(configured_logging, tmp_path, monkeypatch):
    from lfstudio.rig.profile import load_rig
    from lfstudio.studio.devices import open_rig

    monkeypatch.setenv("LFSTUDIO_LOG_DIR", str(tmp_path / "logs"))
    path = configured_logging(debug=False)
    assert path == tmp_path / "logs" / "lfstudio.log"
    link = open_rig("sim", load_rig(), time_scale=0.02, seed=1, timeout_s=1.0)
    controller = link.controller
    try:
        controller.home()
        controller.move_to(2.0, 1.0)
    finally:
        link.close()
    logging.getLogger("lfstudio.scan.engine").info("scan running")
    logs.flush_logs()
    text = path.read_text(encoding="utf-8")
    assert "DEBUG" in text and "lfstudio.rig.grbl: " in text
    assert "> b'$H\\n'" in text                      # the homing command as sent
    assert "G1" in text or "G0" in text             # the move line
    assert " < ok" in text                          # the controller's answers
    assert "<Idle|" not in text                     # status polls stay out without --debug
    assert "INFO    MainThread lfstudio.scan.engine: scan running" in text


def test_setup_is_idempotent(configured_logging, tmp_path, monkeypatch):
    monkeypatch.setenv("LFSTUDIO_LOG_DIR", str(tmp_path))
    configured_logging()
    configured_logging(debug=True)
    ours = [h for h in logging.getLogger().handlers if getattr(h, "_lfstudio_handler", False)]
    assert len(ours) == 2                           # one console, one file: not four
    assert logs.is_configured()


def test_cli_version(run_cli):
    from lfstudio import __version__

    r = run_cli("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"lfstudio {__version__}"


def test_doctor_with_debug_checks_everything_and_logs(run_cli):
    """`lfstudio --debug doctor`: every required component loads and works; device traffic reaches
    the console (--debug) and the log file in $LFSTUDIO_LOG_DIR."""
    r = run_cli("--debug", "doctor")
    assert r.returncode == 0, r.stdout + r.stderr
    for name in ("Qt", "OpenCV", "LibRaw", "FFmpeg", "RAW decoding", "HEVC encoding", "lens database",
                 "resources", "simulated rig", "dask cluster"):
        assert any(line.startswith("ok   " + name) for line in r.stdout.splitlines()), name
    assert "doctor: all required parts work" in r.stdout
    assert "lfstudio.rig.grbl DEBUG" in r.stderr          # --debug: traffic on the console too
    log_file = Path(os.environ["LFSTUDIO_LOG_DIR"]) / "lfstudio.log"
    assert str(log_file) in r.stdout
    text = log_file.read_text(encoding="utf-8")
    assert "lfstudio.cli: lfstudio" in text and "> b'$H\\n'" in text


LIBRARIES = ("pymodbus.logging", "canopen.sdo", "can.interfaces.udp_multicast", "PIL.PngImagePlugin",
             "matplotlib.font_manager", "urllib3.connectionpool", "asyncio", "some_new_library")


def test_libraries_debug_traffic_stays_out_of_the_log(configured_logging, tmp_path, monkeypatch):
    """After connecting to sim-dryve 19 367 of 19 371 log lines were pymodbus DEBUG traffic: the log
    rotated 5 MB about every 70 s and the day's scans were gone (issue 41, item 5)."""
    monkeypatch.setenv("LFSTUDIO_LOG_DIR", str(tmp_path / "logs"))
    path = configured_logging(debug=True)      # not even with --debug
    for name in LIBRARIES:
        logging.getLogger(name).debug("%s debug traffic", name)
        logging.getLogger(name).info("%s info chatter", name)
        logging.getLogger(name).warning("%s warns", name)
    logging.getLogger("lfstudio.rig.worker").debug("rig: home()")
    logs.flush_logs()
    text = path.read_text(encoding="utf-8")
    for name in LIBRARIES:
        assert f"{name} warns" in text                                  # warnings and errors do reach it
        assert f"{name} debug traffic" not in text and f"{name} info chatter" not in text, name
    assert "lfstudio.rig.worker: rig: home()" in text                  # our own device traffic stays


def test_a_drive_scan_logs_views_not_telegrams_and_tells_the_homing(run_cli, tmp_path):
    """The CLI homed the emulated drives for 44 s without a word; the log filled with Modbus telegrams."""
    r = run_cli("scan", "--port", "sim-dryve", "--camera", "sim", "--grid", "2x1", "--sim-width-px", "96",
                "--time-scale", "0", "--out", tmp_path / "ds")
    assert r.returncode == 0, r.stderr
    assert "homing (both drives)" in r.stderr
    assert "drive x (horizontal)" in r.stderr and "drive y (vertical)" in r.stderr and "rig homed" in r.stderr
    text = (Path(os.environ["LFSTUDIO_LOG_DIR"]) / "lfstudio.log").read_text(encoding="utf-8")
    assert "pymodbus" not in text and "scan finished" in text
    assert len(text.splitlines()) < 100, len(text.splitlines())


def test_rig_home_on_drives_prints_each_drive(run_cli):
    r = run_cli("rig", "--port", "sim-dryve", "--time-scale", "0", "home")
    assert r.returncode == 0, r.stderr
    assert "homing (both drives)" in r.stdout and "drive x (horizontal)" in r.stdout, r.stdout
