"""lfstudio camera / lfstudio virtual-dataset, run as subprocesses."""

from __future__ import annotations

import json

import rawpy

from lfstudio.dataset import Dataset
from lfstudio.sim.virtual_dataset import load_ground_truth


def test_camera_test_shot_with_the_simulated_camera(run_cli, tmp_path):
    proc = run_cli("camera", tmp_path / "shot", "--position-mm", "12,3", "--width", "200", "--set", "iso=200")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["files"][0].endswith("shot.dng") and out["true_position_mm"] == [12.0, 3.0]
    assert out["settings"]["iso"] == 200
    with rawpy.imread(out["files"][0]) as raw:
        assert raw.raw_image.shape[1] == 200


def test_camera_bad_setting_is_one_line_exit_2(run_cli, tmp_path):
    proc = run_cli("camera", tmp_path / "x", "--width", "200", "--set", "iso=123")
    assert proc.returncode == 2
    assert "iso" in proc.stderr and "Traceback" not in proc.stderr


def test_virtual_dataset_command(run_cli, tmp_path):
    root = tmp_path / "vd"
    proc = run_cli("virtual-dataset", root, "--grid", "3x2", "--width", "160", "--format", "png",
                   "--rotation-deg", "0.5,0,-0.5", "--position-noise-um", "80,50")
    assert proc.returncode == 0, proc.stderr
    ds = Dataset.open(root)
    assert len(ds.done_views()) == 6
    assert load_ground_truth(root)["rotation_deg"] == [0.5, 0.0, -0.5]
    again = run_cli("virtual-dataset", root, "--grid", "3x2")
    assert again.returncode == 2 and "already holds a dataset" in again.stderr
