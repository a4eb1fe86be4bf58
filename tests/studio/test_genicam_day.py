"""A whole day on aravis's fake GigE Vision camera: scan, calibrate, process, export.

The camera is aravis's own fake GigE Vision camera over the real protocol, served from this process
(:func:`tests.fakegv.scene_gv_camera`) with frames that photograph the virtual studio from where the
carriage of ``lfstudio sim-rig`` (another process, real pty) truly is; ``lfstudio scan`` (a third
process) drives the rig and takes each frame by software trigger through aravis. Its own ramp pattern
has nothing calibration could use; these frames do: the calibration finds the virtual studio's camera
orientation error (DEMO_ROTATION_DEG) within its stated uncertainty."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from lfstudio.scan.scan_plan import ScanPlan
from tests.conftest import REPO_ROOT
from tests.fakegv import scene_gv_camera

GRID = (5, 3)
SPACING_MM = (30.0, 30.0)
WIDTH_PX = 512


@pytest.fixture
def sim_rig_port(tmp_path):
    """``lfstudio sim-rig`` in its own process: its pty and the true position of its carriage."""
    from lfstudio.studio.simulated import truth_source

    proc = subprocess.Popen([sys.executable, "-m", "lfstudio", "sim-rig", "--time-scale", "0.02"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=REPO_ROOT,
                            env=dict(os.environ, PYTHONPATH=str(REPO_ROOT)))
    try:
        line = proc.stdout.readline() if proc.stdout is not None else ""    # its port, once it is served
        port = line.strip().split()[-1] if line.strip() else ""
        truth = truth_source(port)
        assert port.startswith("/dev/") and truth is not None, line
        yield port, truth
    finally:
        proc.terminate()
        proc.wait(20)


def test_a_whole_day_on_the_fake_genicam_camera(tmp_path, run_cli, sim_rig_port):
    from lfstudio.rig.profile import load_rig
    from lfstudio.sim.studio import DEMO_ROTATION_DEG, demo_studio
    from lfstudio.studio.simulated import studio_kwargs_for

    port, truth = sim_rig_port
    plan = ScanPlan.centered(GRID[0], GRID[1], SPACING_MM, load_rig())
    studio = demo_studio(**studio_kwargs_for(plan.extent_mm(), WIDTH_PX))
    height = studio.height_px

    def render(width: int, rows: int) -> np.ndarray:
        x, y = truth()
        grey = studio.render(x, y).mean(axis=2)                  # linear radiance, 0 … 1 (and beyond)
        picture = np.zeros((rows, width), np.uint8)
        picture[:min(rows, height)] = np.clip(grey[:rows] * 255.0, 0, 255).astype(np.uint8)
        return picture

    out = tmp_path / "ds"
    with scene_gv_camera(render) as camera:
        r = run_cli("scan", "--port", port, "--home", "--camera", f"genicam:{camera.device_id}",
                    "--camera-option", "packet_size=8000", "--set", f"width={WIDTH_PX}", "--set", f"height={height}",
                    "--grid", f"{GRID[0]}x{GRID[1]}", "--spacing-mm", f"{SPACING_MM[0]:g}x{SPACING_MM[1]:g}",
                    "--settle-s", "0", "--out", out, timeout=600)
        assert r.returncode == 0, r.stderr
        assert camera.frames >= GRID[0] * GRID[1]
    manifest = json.loads((out / "dataset.json").read_text())
    views = manifest["views"]
    assert [v["status"] for v in views] == ["done"] * (GRID[0] * GRID[1])
    assert {tuple(v["camera_frame"]["size_px"]) for v in views} == {(WIDTH_PX, height)}
    assert manifest["devices"]["camera"]["kind"] == "genicam"
    focal_px = float(studio.K0[0][0])
    r = run_cli("calibrate", out, "--focal-length-px", f"{focal_px:.3f}", timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    calibration = json.loads((out / "calibration.json").read_text())
    found, sigma = np.array(calibration["rotation_deg"]), np.array(calibration["rotation_std_deg"])
    assert np.all(np.abs(found - DEMO_ROTATION_DEG) <= np.maximum(3 * sigma, 0.05)), (found, sigma)  # the studio's own
    r = run_cli("process", out, "--workers", "1", timeout=600)
    assert r.returncode == 0 and f"{GRID[0] * GRID[1]} processed" in r.stdout + r.stderr, r.stderr
    r = run_cli("export", out, "--format", "png", "--out", tmp_path / "png", timeout=300)
    assert r.returncode == 0, r.stderr
    assert len(list((tmp_path / "png").glob("r*_c*.png"))) == GRID[0] * GRID[1]
