import json
import os

import pytest

from lfstudio.dataset import Dataset, resolve_inside, validate_manifest, view_stem
from lfstudio.dataset.atomic import atomic_write_bytes, atomic_write_with, is_temporary
from lfstudio.errors import DatasetError

CAMERA = {"name": "test", "sensor_px": [800, 600], "sensor_mm": [8.0, 6.0], "pixel_pitch_um": 10.0}
LENS = {"name": "50mm", "focal_length_mm": 50.0}
GRID = {"columns": 3, "rows": 2, "spacing_mm": [4.0, 6.0], "order": "row-meander"}


def test_view_stem():
    assert view_stem(7, 42) == "r07_c042"
    assert view_stem(0, 0) == "r00_c000"
    assert view_stem(120, 1234) == "r120_c1234"
    with pytest.raises(ValueError):
        view_stem(-1, 0)


@pytest.mark.parametrize("bad", ["/etc/passwd", "../x.dng", "raw/../../x", "C:/x", ""])
def test_resolve_inside_refuses_escape(tmp_path, bad):
    with pytest.raises(DatasetError):
        resolve_inside(tmp_path, bad)


def test_resolve_inside_refuses_symlink_escape(tmp_path):
    (tmp_path / "ds").mkdir()
    os.symlink(tmp_path, tmp_path / "ds" / "link")
    with pytest.raises(DatasetError, match="outside"):
        resolve_inside(tmp_path / "ds", "link/secret")
    assert resolve_inside(tmp_path / "ds", "raw/r00_c000.dng") == (tmp_path / "ds" / "raw" / "r00_c000.dng").resolve()


def test_create_open_roundtrip(tmp_path):
    ds = Dataset.create(tmp_path / "ds", camera=CAMERA, lens=LENS, grid=GRID)
    assert len(ds.views) == 6 and all(v["status"] == "pending" for v in ds.views)
    assert (tmp_path / "ds" / "raw").is_dir()
    v = ds.view(1, 2)
    v.update(status="done", file=ds.raw_name(1, 2, ".dng"))
    ds.save()
    again = Dataset.open(tmp_path / "ds")
    assert again.view(1, 2)["file"] == "raw/r01_c002.dng"
    assert [x for x in again.views if x["status"] == "done"] == [again.view(1, 2)]
    assert again.focal_length_px() == pytest.approx(5000.0)
    assert again.focal_length_px(400) == pytest.approx(2500.0)


def test_create_refuses_existing(tmp_path):
    Dataset.create(tmp_path, camera=CAMERA, lens=LENS, grid=GRID)
    with pytest.raises(DatasetError, match="already holds a dataset"):
        Dataset.create(tmp_path, camera=CAMERA, lens=LENS, grid=GRID)


def test_open_reports_every_problem_by_field(tmp_path):
    ds = Dataset.create(tmp_path, camera=CAMERA, lens=LENS, grid=GRID)
    m = ds.manifest
    m["views"][0]["file"] = "../outside.dng"
    m["views"][1]["status"] = "exploded"
    m["views"][2]["row"] = 5
    m["views"].append(dict(m["views"][3]))
    (tmp_path / "dataset.json").write_text(json.dumps(m))
    with pytest.raises(DatasetError) as info:
        Dataset.open(tmp_path)
    text = str(info.value)
    assert "views[0]" in text and "outside" in text
    assert "views[1]" in text and "status" in text
    assert "outside the 3 x 2 grid" in text
    assert "appears more than once" in text
    assert len(info.value.problems) == 4


def test_open_bad_json_and_missing(tmp_path):
    with pytest.raises(DatasetError, match="not found"):
        Dataset.open(tmp_path)
    (tmp_path / "dataset.json").write_text("{not json")
    with pytest.raises(DatasetError, match="cannot be read as JSON"):
        Dataset.open(tmp_path)


def test_validate_newer_version():
    problems = validate_manifest({"format": "lfstudio-dataset", "version": 99, "rig": {}, "camera": {},
                                  "lens": {}, "grid": {"columns": 1, "rows": 1}, "views": []})
    assert any("newer" in p for p in problems)


def test_atomic_write_leaves_no_partial_file(tmp_path):
    target = tmp_path / "a.bin"
    atomic_write_bytes(target, b"old")

    def failing(path):
        path.write_bytes(b"half")
        raise OSError("disk full")

    with pytest.raises(OSError):
        atomic_write_with(target, failing)
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.bin"]


def test_is_temporary():
    assert is_temporary(".r00_c000.0abc1234.tmp.dng") and is_temporary(".notes.0abc1234.tmp")
    assert not is_temporary("r00_c000.dng")
    assert not is_temporary(".r00_c000.abc.tmp.dng") and not is_temporary(".my.tmpnotes")   # not our pattern


def test_a_processed_view_is_told_in_one_place():
    from lfstudio.dataset.manifest import processed_file_name, processed_status

    assert processed_status({"status": "done"}) is None and processed_file_name({"status": "done"}) is None
    done = {"processed": {"status": "done", "file": "processed/r00_c000.png"}}
    assert processed_status(done) == "done" and processed_file_name(done) == "processed/r00_c000.png"
    failed = {"processed": {"status": "failed", "error": "x"}}
    assert processed_status(failed) == "failed" and processed_file_name(failed) is None
    assert processed_file_name({"processed": {"status": "done", "file": ""}}) is None
    assert processed_status({"processed": "done"}) is None          # a damaged record is not processed
