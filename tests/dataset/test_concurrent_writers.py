"""Two writers of one dataset (docs/dataset-format.md, "Two commands at once"): the scan, which owns
the journal (it holds dataset.lock), and a stage beside it (processing, calibration), each with its own
Dataset object as two processes would have. Every save merges what the other wrote meanwhile, field by
field; only the owner appends to or empties the journal. (The same with real processes:
tests/faults/test_concurrency.py.)"""

from __future__ import annotations

import json
import os

import pytest

from lfstudio.dataset import Dataset
from lfstudio.support.locks import LockBusy, NotALockFile, dataset_lock

CAMERA = {"name": "cam", "sensor_px": [800, 600], "sensor_mm": [8.0, 6.0], "pixel_pitch_um": 10.0}
LENS = {"name": "lens", "focal_length_mm": 50.0}


def _scan_and_stage(tmp_path):
    Dataset.create(tmp_path / "ds", camera=CAMERA, lens=LENS, grid={"columns": 3, "rows": 2, "spacing_mm": [4.0, 6.0]})
    scan = Dataset.open(tmp_path / "ds")
    scan.journal_lock = dataset_lock(scan.root, "scanning").acquire()
    scan.record_view(0, 0, status="done", file="raw/r00_c000.dng")
    stage = Dataset.open(tmp_path / "ds")          # opened mid-scan: sees view (0, 0) through the journal
    return scan, stage


def _on_disk(root):
    ds = Dataset.open(root)
    try:
        return {(v["row"], v["column"]): v for v in ds.views}, ds.manifest
    finally:
        ds.close()


def test_a_stage_saving_beside_a_scan_keeps_the_scans_views_and_the_scan_keeps_the_stages_records(tmp_path):
    scan, stage = _scan_and_stage(tmp_path)
    assert stage.view(0, 0)["status"] == "done"
    scan.record_view(0, 1, status="done", file="raw/r00_c001.dng")        # journal only, after the stage opened
    stage.view(0, 0)["processed"] = {"status": "done", "file": "processed/r00_c000.png"}
    stage.manifest["processing"] = {"summary": {"processed": 1}}
    stage.save()                                   # stale copy of (0, 1): merged, not written over it
    views, manifest = _on_disk(scan.root)
    assert views[(0, 1)]["status"] == "done" and views[(0, 0)]["processed"]["status"] == "done"
    assert (scan.root / "journal.jsonl").stat().st_size > 0             # only the scan empties its journal

    scan.record_view(1, 2, status="done", file="raw/r01_c002.dng")
    scan.save()                                    # the scan's save keeps the stage's records
    views, manifest = _on_disk(scan.root)
    assert manifest["processing"] == {"summary": {"processed": 1}}
    assert views[(0, 0)]["processed"]["status"] == "done"
    assert [views[c]["status"] for c in ((0, 0), (0, 1), (1, 2))] == ["done"] * 3
    assert (scan.root / "journal.jsonl").stat().st_size == 0
    assert "processed" in scan.view(0, 0)          # and knows them in memory (its next saves keep them)

    stage.manifest["calibration"] = {"file": "calibration.json"}
    stage.checkpoint()                             # a stage's checkpoint is a merged save, never the journal
    assert (scan.root / "journal.jsonl").stat().st_size == 0
    views, manifest = _on_disk(scan.root)
    assert views[(1, 2)]["status"] == "done" and manifest["calibration"] == {"file": "calibration.json"}
    assert manifest["processing"] == {"summary": {"processed": 1}}
    scan.journal_lock.release()


def test_what_both_change_in_one_view_keeps_each_ones_own_field(tmp_path):
    scan, stage = _scan_and_stage(tmp_path)
    scan.record_view(0, 0, thumb="thumbs/r00_c000.jpg")
    stage.view(0, 0)["processed"] = {"status": "done"}
    stage.save()
    scan.save()
    views, _ = _on_disk(scan.root)
    assert views[(0, 0)]["thumb"] == "thumbs/r00_c000.jpg" and views[(0, 0)]["processed"] == {"status": "done"}
    scan.journal_lock.release()


def test_a_stage_cannot_append_to_the_journal_of_a_running_scan(tmp_path):
    scan, stage = _scan_and_stage(tmp_path)
    with pytest.raises(LockBusy, match="in use by"):
        stage.record_view(1, 1, status="done", file="raw/r01_c001.dng")
    scan.journal_lock.release()
    stage.record_view(1, 1, status="done", file="raw/r01_c001.dng")     # nobody owns it now: may append
    scan2 = Dataset.open(scan.root)
    assert scan2.view(1, 1)["status"] == "done" and scan2.view(0, 0)["status"] == "done"


def test_journal_seq_written_by_a_stage_never_hides_the_scans_later_records(tmp_path):
    scan, stage = _scan_and_stage(tmp_path)
    stage.manifest["processing"] = {}
    stage.save()                                   # writes journal_seq = 1 (what it has seen)
    scan.record_view(0, 2, status="done", file="raw/r00_c002.dng")      # seq 2
    views, manifest = _on_disk(scan.root)
    assert manifest["journal_seq"] == 1 and views[(0, 2)]["status"] == "done"
    scan.journal_lock.release()


@pytest.mark.parametrize("name", ["dataset.lock", "manifest.lock"])
def test_a_lock_file_that_is_a_symlink_is_refused_and_its_target_untouched(tmp_path, name):
    Dataset.create(tmp_path / "ds", camera=CAMERA, lens=LENS, grid={"columns": 2, "rows": 1, "spacing_mm": [4.0, 6.0]})
    root = tmp_path / "ds"
    victim = root / "dataset.json" if name == "manifest.lock" else tmp_path / "victim.txt"
    if name == "dataset.lock":
        victim.write_text("precious\n")
    before = victim.read_bytes()
    (root / name).unlink(missing_ok=True)
    os.symlink(victim, root / name)                # inside the folder: the path guard lets it be
    with pytest.raises(NotALockFile, match="not an ordinary file"):
        if name == "dataset.lock":
            dataset_lock(root, "scanning").acquire()
        else:
            Dataset.open(root).save()
    assert victim.read_bytes() == before
    json.loads((root / "dataset.json").read_text())
