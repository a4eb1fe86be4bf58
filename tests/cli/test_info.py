"""``lfstudio info``: what it says about the views' files (a real dataset, a real HEVC round trip)."""

from __future__ import annotations

import json

from lfstudio.cli.info import _size
from tests.conftest import hevc_round_trip


def test_info_reports_files_by_folder_and_an_empty_raw_folder_as_empty(make_tiny_dataset, run_cli, tmp_path):

    ds = make_tiny_dataset("png", width_px=241)
    raw_total = sum(ds.path_of(v).stat().st_size for v in ds.done_views())
    proc = run_cli("info", ds.root)
    assert proc.returncode == 0, proc.stderr
    assert f"files     raw/ {_size(raw_total)}\n" in proc.stdout

    back = hevc_round_trip(ds.root, tmp_path, "proc")
    assert not (back.root / "raw").exists() or not any((back.root / "raw").iterdir())
    restored_total = sum(back.path_of(v).stat().st_size for v in back.done_views())

    proc = run_cli("info", back.root)
    assert proc.returncode == 0, proc.stderr
    assert f"files     processed/ {_size(restored_total)} (restored from proc.mkv); raw/ empty\n" in proc.stdout
    assert "raw files" not in proc.stdout
    summary = json.loads(run_cli("info", back.root, "--json").stdout)
    assert summary["raw_bytes"] == 0 and summary["view_file_bytes"] == {"processed/": restored_total}
