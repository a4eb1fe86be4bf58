"""Paths the operator types: ``~`` and environment variables (lfstudio.dataset.paths.expand_path),
and the folder a new dataset may be created in."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from lfstudio.dataset.paths import check_new_dataset_folder, expand_path, new_dataset_folder_problem, new_sub_folder
from lfstudio.errors import InputError


def test_tilde_and_variables_expand_to_the_home_folder_and_their_values(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("LFS_DAY", "studio_day")
    assert expand_path("~/datasets/studio_day") == tmp_path / "home" / "datasets" / "studio_day"
    assert expand_path("  $HOME/datasets/${LFS_DAY}  ") == tmp_path / "home" / "datasets" / "studio_day"
    assert expand_path("relative/x") == Path("relative/x")
    assert expand_path("relative/x", absolute=True) == Path.cwd() / "relative" / "x"


def test_what_would_become_a_literal_folder_is_refused_naming_the_field(monkeypatch):
    monkeypatch.delenv("LFS_NOT_SET", raising=False)
    with pytest.raises(InputError, match=r"--out: .*\$LFS_NOT_SET, which is not set"):
        expand_path("$LFS_NOT_SET/scan", "--out")
    with pytest.raises(InputError, match=r"Folder: .*no user 'nosuchuser_lfs'"):
        expand_path("~nosuchuser_lfs/scan", "Folder")
    with pytest.raises(InputError, match="DATASET: no path given"):
        expand_path("  ", "DATASET")


def test_a_new_dataset_needs_a_missing_or_empty_folder(tmp_path):
    assert new_dataset_folder_problem(tmp_path / "new") is None
    (tmp_path / "empty").mkdir()
    assert new_dataset_folder_problem(tmp_path / "empty") is None
    (tmp_path / "empty" / "dataset.lock").write_text("")       # a scan that never started
    assert new_dataset_folder_problem(tmp_path / "empty") is None
    mine = tmp_path / "mine"
    mine.mkdir()
    for name in ("thesis.pdf", "photos", "notes.txt", "z.txt"):
        (mine / name).write_text("x") if "." in name else (mine / name).mkdir()
    problem = new_dataset_folder_problem(mine)
    assert problem is not None and str(mine) in problem and "not empty" in problem
    assert "notes.txt" in problem and "1 more" in problem
    (tmp_path / "file").write_text("x")
    assert "is a file" in new_dataset_folder_problem(tmp_path / "file")
    os.remove(tmp_path / "file")


def test_one_rule_for_the_folder_of_every_new_dataset(tmp_path):
    """check_new_dataset_folder: missing/empty fine; a dataset only with the command's own option; other
    files never (not even with that option), naming the folder and a free sub-folder."""
    assert check_new_dataset_folder(tmp_path / "new", "--out") == "missing"
    (tmp_path / "empty").mkdir()
    assert check_new_dataset_folder(tmp_path / "empty", "--out") == "empty"
    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "dataset.json").write_text("{}")
    with pytest.raises(InputError) as exc:
        check_new_dataset_folder(ds, "--out", dataset_fix="add --resume to continue it")
    assert str(exc.value) == f"--out: {ds} already holds a dataset (valid: add --resume to continue it)"
    assert check_new_dataset_folder(ds, "--out", add_to_dataset=True) == "dataset"
    mine = tmp_path / "mine"
    (mine / "lfstudio-scan").mkdir(parents=True)
    (mine / "lfstudio-scan" / "old.txt").write_text("x")       # taken: the next free name is offered
    assert new_sub_folder(mine, "lfstudio-scan") == mine / "lfstudio-scan-2"
    for add in (False, True):
        with pytest.raises(InputError) as exc:
            check_new_dataset_folder(mine, "Folder", add_to_dataset=add, stem="lfstudio-scan")
        assert exc.value.field == "Folder" and f"{mine} is not empty (lfstudio-scan)" in str(exc.value)
        assert exc.value.valid.startswith(f"a new sub-folder, e.g. {mine / 'lfstudio-scan-2'}")
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="is a file"):
        check_new_dataset_folder(tmp_path / "file", "--out", add_to_dataset=True)
