"""Journal, replay, checksums, crash leftovers and validation by file and field."""

from __future__ import annotations

import json

import pytest

from lfstudio.dataset import Dataset, validate_manifest
from lfstudio.dataset.atomic import atomic_write_bytes
from lfstudio.dataset.store import JOURNAL_NAME, clean_temporary_files, read_journal, sha256_file
from lfstudio.errors import DatasetError

GRID = {"columns": 3, "rows": 2, "spacing_mm": [4.0, 6.0], "order": "row-meander"}


def make(tmp_path):
    return Dataset.create(tmp_path / "ds", camera={"name": "sim"}, lens={"name": "50mm", "focal_length_mm": 50},
                          grid=GRID, rig={"name": "Reference gantry"})


def capture(ds, r, c, data=b"raw-bytes"):
    name = ds.raw_name(r, c, ".dng")
    atomic_write_bytes(ds.root / name, data + bytes([r, c]))
    return ds.record_view(r, c, status="done", file=name, sha256=sha256_file(ds.root / name),
                          captured_at="2026-11-21T23:00:00+00:00", exposure_s=0.5, reported_mm=[1.0, 2.0])


def test_journal_is_replayed_on_open_without_a_manifest_save(tmp_path):
    ds = make(tmp_path)
    capture(ds, 0, 0)
    capture(ds, 0, 1)
    # the process "dies" here: no save(); the manifest on disk still says pending
    on_disk = json.loads((ds.root / "dataset.json").read_text())
    assert all(v["status"] == "pending" for v in on_disk["views"])
    again = Dataset.open(ds.root)
    assert again.replayed == 2
    assert again.view(0, 1)["status"] == "done" and again.view(0, 1)["file"] == "raw/r00_c001.dng"
    assert again.status_counts()["done"] == 2
    assert again.verify_files() == []


def test_save_folds_the_journal_and_later_records_still_replay(tmp_path):
    ds = make(tmp_path)
    capture(ds, 0, 0)
    ds.save()
    assert (ds.root / JOURNAL_NAME).read_bytes() == b""
    capture(ds, 1, 2)
    again = Dataset.open(ds.root)
    assert again.replayed == 1 and again.manifest["journal_seq"] == 1
    assert again.status_counts()["done"] == 2


def test_records_older_than_the_manifest_are_not_applied_twice(tmp_path):
    ds = make(tmp_path)
    capture(ds, 0, 0)
    journal = (ds.root / JOURNAL_NAME).read_bytes()
    ds.save()
    # crash between the manifest rename and the journal truncation: the old line is still there
    (ds.root / JOURNAL_NAME).write_bytes(journal)
    ds2 = Dataset.open(ds.root)
    ds2.view(0, 0)["status"] = "pending"        # e.g. marked for re-capture and saved
    ds2.save()
    (ds2.root / JOURNAL_NAME).write_bytes(journal)
    assert Dataset.open(ds.root).view(0, 0)["status"] == "pending"


def test_torn_last_line_is_ignored_and_repaired_on_next_append(tmp_path):
    ds = make(tmp_path)
    capture(ds, 0, 0)
    ds.close()
    with open(ds.root / JOURNAL_NAME, "ab") as fh:
        fh.write(b'{"seq": 2, "row": 0, "col')
    again = Dataset.open(ds.root)
    assert again.replayed == 1 and again.journal_problems == []
    capture(again, 0, 1)
    records, problems = read_journal(ds.root / JOURNAL_NAME)
    assert [r["seq"] for r in records] == [1, 2] and problems == []


def test_corrupt_middle_line_is_reported(tmp_path):
    ds = make(tmp_path)
    capture(ds, 0, 0)
    ds.close()
    with open(ds.root / JOURNAL_NAME, "ab") as fh:
        fh.write(b"garbage\n")
    capture(Dataset.open(ds.root), 0, 1)
    again = Dataset.open(ds.root)
    assert any("line 2" in p for p in again.journal_problems)
    assert again.status_counts()["done"] == 2


def test_verify_files_names_missing_and_corrupt_files(tmp_path):
    ds = make(tmp_path)
    capture(ds, 0, 0)
    capture(ds, 0, 1)
    (ds.root / "raw/r00_c000.dng").write_bytes(b"changed")
    (ds.root / "raw/r00_c001.dng").unlink()
    problems = ds.verify_files()
    assert any(p.startswith("raw/r00_c000.dng") and "sha256" in p for p in problems)
    assert any(p.startswith("raw/r00_c001.dng") and "missing" in p for p in problems)


def test_clean_temporary_files_removes_only_crash_leftovers(tmp_path):
    ds = make(tmp_path)
    capture(ds, 0, 0)
    leftovers = [ds.root / "raw/.r00_c001.abcd0123.tmp.dng", ds.root / "thumbs/.r00_c001.00ff00ff.tmp.jpg",
                 ds.root / ".dataset.1234abcd.tmp.json", ds.root / ".notes.deadbeef.tmp"]
    theirs = [ds.root / ".my.tmpnotes", ds.root / ".tmp", ds.root / "raw/.r00_c001.abcd.tmp.dng",
              ds.root / ".backup.tmp.json"]       # the operator's: only the exact pattern is ours
    for p in leftovers + theirs:
        p.write_bytes(b"half")
    removed = clean_temporary_files(ds.root)
    assert sorted(removed) == sorted(leftovers)
    assert all(p.is_file() for p in theirs)
    assert (ds.root / "raw/r00_c000.dng").is_file()


def test_a_killed_writers_manifest_temporary_is_removed_by_the_next_save(tmp_path):
    ds = make(tmp_path)
    left = ds.root / ".dataset.0badf00d.tmp.json"        # a kill -9 of 'lfstudio process' mid-save
    left.write_bytes(b'{"format"')
    again = Dataset.open(ds.root)
    again.save()
    assert not left.exists()


def test_validation_reports_problems_by_field(tmp_path):
    ds = make(tmp_path)
    m = json.loads(json.dumps(ds.manifest))
    m["views"][0].update(status="done", file="../outside.dng", sha256="xyz")
    m["views"][1].update(exposure_s=-1, thumb="/etc/passwd")
    m["journal_seq"] = -3
    problems = validate_manifest(m, ds.root)
    text = "\n".join(problems)
    assert "views[0] (row 0, column 0): file:" in text and "outside" in text
    assert "views[0] (row 0, column 0): sha256" in text
    assert "views[1] (row 0, column 1): exposure_s" in text
    assert "views[1] (row 0, column 1): thumb" in text
    assert "journal_seq" in text
    (ds.root / "dataset.json").write_text(json.dumps(m))
    with pytest.raises(DatasetError) as exc:
        Dataset.open(ds.root)
    assert len(exc.value.problems) == len(problems)


def test_summary_counts(tmp_path):
    ds = make(tmp_path)
    capture(ds, 0, 0)
    ds.record_view(0, 1, status="failed", error="camera timeout")
    s = ds.summary()
    assert (s["views"], s["done"], s["failed"], s["missing"], s["complete"]) == (6, 1, 1, 4, False)
    assert s["raw_bytes"] > 0


def test_a_dataset_is_finished_when_every_view_is_done_or_skipped(tmp_path):
    from lfstudio.dataset.manifest import is_finished

    ds = make(tmp_path)
    cells = [(v["row"], v["column"]) for v in ds.views]
    for r, c in cells[:-2]:
        capture(ds, r, c)
    ds.record_view(*cells[-2], status="skipped")
    ds.record_view(*cells[-1], status="failed", error="camera timeout")
    assert [is_finished(v) for v in ds.views] == [True] * (len(cells) - 1) + [False]
    assert not ds.finished() and not ds.summary()["complete"]
    capture(ds, *cells[-1])
    assert ds.finished() and ds.summary()["complete"]


def test_symlink_leading_outside_is_refused(tmp_path):
    ds = make(tmp_path)
    outside = tmp_path / "outside.dng"
    outside.write_bytes(b"x")
    (ds.root / "raw" / "r00_c000.dng").symlink_to(outside)
    ds.view(0, 0).update(status="done", file="raw/r00_c000.dng")
    problems = validate_manifest(ds.manifest, ds.root)
    assert any("points outside the dataset folder" in p for p in problems)
