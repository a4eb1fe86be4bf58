"""Every benchmark runs once at tiny sizes (full tier): it must exit 0 and print the lines that say it
measured what it measures. No figure is asserted (figures live in benchmarks/README.md); what this
catches is a benchmark that rotted: a scan that no longer starts, a view never processed, an option or
an API that moved. A benchmark that finds its subject did not happen exits non-zero itself and says why
(benchmarks/grid_gui.py quotes the window's message), and that message is in the failure here.

A new script in benchmarks/ needs its entry in SMOKE (test_every_benchmark_has_a_smoke_run)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest

from tests.conftest import REPO_ROOT

BENCH = REPO_ROOT / "benchmarks"
#: real photographs some benchmarks use where present (as they find them: beside the checkout)
STANFORD = REPO_ROOT.parent / "shared" / "data" / "lightfield" / "stanford_chess_5x5"
HCI = any((REPO_ROOT.parent / "shared" / "data" / "lightfield").glob("hci_*"))

#: script -> (tiny arguments ({tmp}: the test's folder), lines its output must contain)
SMOKE: dict[str, tuple[list[str], list[str]]] = {
    "calibration_accuracy.py": (["--smoke"], ["1 trials per row", "2 × 3 (paper)", "The default at shift 0 over 1 trials",
                                             "(the rig model) |"]),
    "calibration_perfect_views.py": (["--seeds", "1", "--hci-trials", "1", "--keep", "{tmp}/pv"],
                                     ["virtual studio seed 0", "angles within 2σ of zero", "rotation applied in"]),
    "calibration_speed.py": (["--views", "array:2x2", "--width", "400", "--fmt", "png"],
                            ["calibrate cold", "calibrate warm", "rotation error vs truth"]),
    "card_buffer.py": (["--grid", "3x2", "--time-scale", "0.01", "--width", "32", "--timeout-s", "200"],
                       ["6 done and verified", "card buffering: last picture taken after",
                        "per view within a row, simulated s (median): move"]),
    "card_kill_soak.py": (["--trials", "1", "--camera", "sim", "--grid", "2x2"], ["sim trial 0:", "1 trials, 0 failed"]),
    "concurrency_soak.py": (["--trials", "1", "--grid", "2x2"], ["1 trials (2x2 views", "0 views lost"]),
    "depth_points.py": (["--grids", "5x3", "--width", "480", "--dense-views", "2", "--skip-cluster", "--skip-2000",
                         "--skip-small"],
                        ["5 x 3 at 480 px rendered", "self-calibration: rotation", "points: ", "dense (2 views",
                         "per view (columns", "maps' own (self-calibrated) frame"]),
    "export_hevc.py": (["--width", "320", "--columns", "2", "--rows", "1", "--no-psy-compare"],
                       ["16-bit PNG export: 2 views", "encode speed", "PSNR"]),
    "fault_soak.py": (["--trials", "1", "--kinds", "kill"], ["trial   1 kill", "1 trials, 0 lost, 0 duplicated, 0 outside"]),
    "fly_kill_soak.py": (["--trials", "1", "--grid", "3x2", "--kill-min-s", "4", "--kill-max-s", "6"],
                         ["fly trial 0:", "1 trials (", "0 failed"]),
    "fly_scan.py": (["--grid", "4x10", "--time-scale", "0.2", "--width", "64", "--calibrate", "--calibrate-width", "160",
                     "--step-grid", "3x1"],
                    ["trigger: hardware", "grid 4 x 10 = 40 views", "fly scan:", "blur at the nearest depth",
                     "blur estimator on known blur", "blur measured on the pictures (",
                     "recorded position vs truth", "added by the fly recording", "step scan of 3 x 1 on the same rig",
                     "calibration views (array:4ex10"]),
    "fly_scan_drives.py": (["--grid", "3x2", "--time-scale", "0.2", "--transport", "modbus", "--touch-probe",
                            "--stop-trials", "1"],
                           ["grid 3x2 at time scale 0.2", "| modbus | 80.0", "| modbus-probe |",
                            "touch probe: ", "recorded position vs truth, all: RMS",
                            "STOP during a fly move (modbus): the quick stop reached both drives"]),
    "genicam.py": (["--frames", "8", "--grid", "2x1"], ["software trigger, Mono8  512 x  512", "scan 2x1 (2 views)",
                                                          "1 % of packets dropped"]),
    "hci_depth.py": (["--centre-only", "--skip-chess"], ["scene | ours BadPix(0.07)"] if HCI else ["no HCI scene found"]),
    "gui_never_waits.py": (["--trials", "1", "--steps", "2", "--hold-s", "0.1", "--width", "400"],
                           ["window STOP, drive x's link stalled, GUI thread: median",
                            "StatusServer.close(), its loop held up 0.1 s, caller: median",
                            "radiance slider, 400 x 266 px, GUI-thread slices: median"]),
    "grid_gui.py": (["--grid", "3x2", "--scan-views", "12", "--scan-timeout-s", "120"],
                    ["open 6-view dataset to a painted grid", "scan through the GUI                       12 views"]),
    "grid_thumbnails.py": (["--width", "200", "--views", "101", "--root", "{tmp}/thumbs"],
                           ["one thumbnail, CPU per view", "first opening (thumbnails made from the files)",
                            "reopened (thumbnails from the cache)", "all 101 tiles in"]),
    "hdr_bracket.py": (["--width", "160", "--views", "2", "--columns", "2", "--time-scale", "0.01"],
                       ["merged  ", "middle frame", "1 frame:", "3 frames:", "processing CPU per view"]),
    "log_lines_per_view.py": (["2x1"], ["sim        2 views:", "sim-dryve  2 views:", "lines and"]),
    "manifest_save.py": (["--repeat", "1", "--grids", "4x3,8x3"], ["4 x 3 = 12 views", "8 x 3 = 24 views",
                                                                    "open per view, 24 / 12 views"]),
    "planner_update.py": (["--n", "3"], ["ScenePlan.derive()", "Planner update", "Plan plots update + paint",
                                         "One keystroke in the main window"]),
    "processing_quality.py": (["--views", "1", "--width", "320", "--root", "{tmp}/quality"],
                              ["auto (default):", "AHD at full size", "PSNR"]),
    "processing_throughput.py": (["--views", "2", "--width", "320", "--root", "{tmp}/processing"],
                                 ["former path (AHD, zlib default), 1 worker", "default path, 1 worker"]),
    "quality_check.py": (["--width", "320", "--grid", "3x3", "--repeat", "1"],
                         ["calibrate (2 x 3 views, cold)", "check (9 views)", "verdict pass: 9 pass"]),
    "real_gantry_calibration.py": (["--views", "array:3x2"], ["as published", "turned by", "angles outside their stated 2σ"]
                                   if STANFORD.is_dir() else ["Stanford Chess: ../shared/data not present, skipped"]),
    "rig_latency.py": (["--n", "10", "--seconds", "0.2"], ["G-code line", "status query", "move_to, instant simulator",
                                                         "sustained status rate"]),
    "scan_critical_path.py": (["--columns", "2", "--rows", "1", "--time-scale", "0.02", "--width-px", "80"],
                              ["measured scan", "critical path", "ratio measured/critical"]),
    "scan_ctrl_c.py": (["--phases", "move", "--grid", "2x1"], ["Ctrl+C during the first move", "worst time to exit"]),
    "scan_overhead.py": (["--grids", "3x2"], ["instant camera alone", "3 x 2 =     6 views"]),
    "sheared_import.py": (["--width", "320", "--zero-planes", "2.5"], ["2.5"]),
    "stop_latency.py": (["--trials", "1", "--transport", "modbus"], ["modbus   no stall         drive x: median",
                                                                    "modbus   drive x stalled  drive y: median"]),
    "studio_render.py": (["--width", "200", "--views", "2"], ["render per view", "render + sensor + DNG write"]),
    "unattended.py": (["--n", "3", "--grid", "3x2", "--poll-s", "0.1", "--held", "20", "--flood-grid", "3x2",
                       "--on-finish-mb", "1"],
                      ["engine state event -> POST received", "with the page and a client", "20 connections held open",
                       "--on-finish printing 1 MB"]),
}


def test_every_benchmark_has_a_smoke_run():
    scripts = {p.name for p in BENCH.glob("*.py") if not p.name.startswith("_")}
    assert scripts == set(SMOKE), f"without a smoke run: {sorted(scripts - set(SMOKE))}; gone: {sorted(set(SMOKE) - scripts)}"


#: benchmarks that need a program of the system, and which
NEEDS = {"genicam.py": "arv-fake-gv-camera-0.8"}


@pytest.mark.parametrize("script", sorted(SMOKE))
def test_benchmark_smoke_run(script, tmp_path):
    args, lines = SMOKE[script]
    if script in NEEDS and shutil.which(NEEDS[script]) is None:
        pytest.skip(f"{script} needs {NEEDS[script]} (aravis-tools), not installed here")
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               QT_QPA_PLATFORM="offscreen", LFSTUDIO_CONFIG_DIR=str(tmp_path / "config"))
    proc = subprocess.run([sys.executable, str(BENCH / script), *(a.format(tmp=tmp_path) for a in args)],
                          capture_output=True, text=True, timeout=280, env=env, cwd=tmp_path)
    said = proc.stdout + proc.stderr
    assert proc.returncode == 0, f"{script} exited {proc.returncode}:\n{said[-3000:]}"
    assert "Traceback" not in said, said[-3000:]
    missing = [line for line in lines if line not in proc.stdout]
    assert not missing, f"{script} did not print {missing}:\n{proc.stdout[-3000:]}"
