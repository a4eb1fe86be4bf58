"""``lfstudio scan`` and ``lfstudio info`` as a user runs them (subprocesses)."""

from __future__ import annotations

import json


def test_scan_instant_then_info_and_resume_is_a_no_op(run_cli, tmp_path):
    out = tmp_path / "ds"
    r = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "3x2", "--spacing-mm", "4x6",
                "--out", out, "--time-scale", "0")
    assert r.returncode == 0, r.stderr
    assert "6 of 6 views captured" in r.stderr
    info = run_cli("info", out, "--json", "--verify")
    assert info.returncode == 0, info.stderr
    summary = json.loads(info.stdout)
    assert (summary["done"], summary["missing"], summary["file_problems"]) == (6, 0, [])
    text = run_cli("info", out)
    assert "6 done, 0 missing, 0 failed" in text.stdout
    again = run_cli("scan", "--port", "instant", "--camera", "instant", "--out", out, "--resume")
    assert again.returncode == 0 and "nothing to do" in again.stderr
    assert "no device connected" in again.stderr and "homed" not in again.stderr     # no homing for nothing


def test_scan_errors_name_the_option(run_cli, tmp_path):
    r = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "2000x3", "--out", tmp_path / "a")
    assert r.returncode == 2 and "--grid/--spacing-mm" in r.stderr and "4000 mm" in r.stderr
    r = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "abc", "--out", tmp_path / "b")
    assert r.returncode == 2 and "--grid" in r.stderr
    r = run_cli("scan", "--port", "instant", "--camera", "instant", "--out", tmp_path / "c", "--resume")
    assert r.returncode == 2 and "no dataset to resume" in r.stderr
    r = run_cli("scan", "--port", "instant", "--camera", "nikon", "--grid", "2x2", "--out", tmp_path / "d")
    assert r.returncode == 2 and "--camera" in r.stderr


def test_info_reports_manifest_problems_by_field(run_cli, tmp_path):
    ds = tmp_path / "bad"
    ds.mkdir()
    (ds / "dataset.json").write_text(json.dumps({"format": "lfstudio-dataset", "version": 1, "rig": {},
                                                 "camera": {}, "lens": {}, "grid": {"columns": 2, "rows": 1},
                                                 "views": [{"row": 0, "column": 5, "status": "done"}]}))
    r = run_cli("info", ds)
    assert r.returncode == 1
    assert "views[0] (row 0, column 5): outside the 2 x 1 grid" in r.stderr
    assert "a view with status 'done' needs a file" in r.stderr


def test_scan_expands_a_quoted_tilde_and_variables_in_paths(run_cli, tmp_path):
    """A quoted '~/x' or '$HOME/x' reaches lfstudio unexpanded by the shell: it must still mean the
    home folder, not a folder literally named '~' in the working folder."""
    home, cwd = tmp_path / "home", tmp_path / "cwd"
    home.mkdir()
    cwd.mkdir()
    r = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "2x1", "--out", "~/datasets/day1",
                "--time-scale", "0", env={"HOME": str(home)}, cwd=cwd)
    assert r.returncode == 0, r.stderr
    assert (home / "datasets" / "day1" / "dataset.json").is_file()
    info = run_cli("info", "$HOME/datasets/day1", env={"HOME": str(home)}, cwd=cwd)
    assert info.returncode == 0 and "2 done" in info.stdout, info.stderr
    assert list(cwd.iterdir()) == []                # no '~' or '$HOME' folder made here
    r = run_cli("info", "$LFS_UNSET_VARIABLE/day1", env={"LFS_UNSET_VARIABLE": None}, cwd=cwd)
    assert r.returncode == 2 and "$LFS_UNSET_VARIABLE, which is not set" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_scan_into_a_folder_holding_other_files_is_refused(run_cli, tmp_path):
    mine = tmp_path / "Documents"
    mine.mkdir()
    (mine / "thesis.pdf").write_bytes(b"%PDF")
    r = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "2x1", "--out", mine,
                "--time-scale", "0")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "--out" in lines[0] and "not empty (thesis.pdf)" in lines[0]
    assert f"a new sub-folder, e.g. {mine / 'lfstudio-scan'}" in lines[0]
    assert sorted(p.name for p in mine.iterdir()) == ["thesis.pdf"]          # nothing written there
