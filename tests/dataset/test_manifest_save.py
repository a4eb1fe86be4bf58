"""Saving the manifest: compact JSON (one view per line) that any JSON reader loads as the
manifest, with the text of unchanged views reused from save to save and every change written."""

from __future__ import annotations

import json
import math
import os

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lfstudio.dataset import Dataset, validate_manifest
from lfstudio.dataset.manifest import ManifestWriter
from lfstudio.errors import DatasetError

CAMERA = {"name": "test", "sensor_px": [800, 600], "pixel_pitch_um": 10.0}
LENS = {"name": "50mm", "focal_length_mm": 50.0}


def _dataset(tmp_path, columns=4, rows=3) -> Dataset:
    return Dataset.create(tmp_path / "ds", camera=CAMERA, lens=LENS,
                          grid={"columns": columns, "rows": rows, "spacing_mm": [4.0, 6.0]})


def owned(ds: Dataset) -> Dataset:
    """``ds`` as a scan holds it: the dataset's lock taken, so its checkpoints go to the journal."""
    from lfstudio.support.locks import dataset_lock

    ds.journal_lock = dataset_lock(ds.root, "scanning").acquire()
    return ds


def on_disk(ds: Dataset) -> dict:
    return json.loads(ds.manifest_path.read_text(encoding="utf-8"))


def as_json(obj):
    return json.loads(json.dumps(obj))


def test_file_is_compact_json_one_view_per_line_that_any_reader_loads(tmp_path):
    ds = _dataset(tmp_path)
    ds.record_view(0, 1, status="done", file="raw/r00_c001.dng", sha256="a" * 64, timings_s={"move": 0.5})
    ds.save()
    text = ds.manifest_path.read_text(encoding="utf-8")
    lines = text.splitlines()
    assert lines[0].startswith('{"format":"lfstudio-dataset","version":1,')
    assert lines[1] == '"views":['
    assert len(lines) == 2 + 12 + 1 and lines[-1] == "]}"
    assert all(line.startswith('{"row":') for line in lines[2:-1])
    assert ": " not in text and "\n " not in text          # no indentation, no spaces after separators
    assert on_disk(ds) == as_json(ds.manifest)
    assert validate_manifest(on_disk(ds), ds.root) == []
    again = Dataset.open(ds.root)
    assert again.view(0, 1)["timings_s"] == {"move": 0.5} and again.manifest == as_json(ds.manifest)


def test_every_kind_of_change_reaches_the_file(tmp_path):
    ds = _dataset(tmp_path)
    ds.save()
    v = ds.view(1, 2)
    v["status"] = "failed"                                   # in place
    v["timings_s"] = {"move": 1.0}
    ds.save()
    assert on_disk(ds) == as_json(ds.manifest)
    v["timings_s"]["move"] = 2.0                             # nested, in place
    ds.save()
    assert on_disk(ds)["views"][6]["timings_s"] == {"move": 2.0}
    ds.manifest["views"][0] = {**ds.manifest["views"][0], "status": "skipped"}   # replaced by a new dict
    ds.manifest["views"].append({"row": 3, "column": 0, "status": "pending"})    # added
    del ds.manifest["views"][5]                                                   # removed
    ds.manifest["processing"] = {"profile_sha256": "x"}                          # a new top-level key
    ds.save()
    assert on_disk(ds) == as_json(ds.manifest)


def test_unchanged_views_keep_their_text_and_changed_ones_are_encoded_again():
    writer = ManifestWriter()
    manifest = {"format": "f", "views": [{"row": 0, "column": c, "x": [1, 2]} for c in range(3)]}
    first = writer.encode(manifest)
    kept = writer._texts[1]
    manifest["views"][0]["x"].append(3)
    second = writer.encode(manifest)
    assert writer._texts[1] is kept                          # the same string object: not encoded again
    assert json.loads(second)["views"][0]["x"] == [1, 2, 3] and first != second


def test_the_file_read_on_open_is_reused_and_journal_replays_still_land(tmp_path):
    ds = _dataset(tmp_path)
    ds.save()
    ds.record_view(2, 3, status="done", file="raw/r02_c003.dng")   # in the journal only: replayed on open
    ds.close()
    # a view line spelled differently from what the encoder writes (same value): kept while unchanged
    text = ds.manifest_path.read_text()
    spelled = text.replace('{"row":1,"column":1,', '{"row": 1, "column": 1, ')
    assert spelled != text
    ds.manifest_path.write_text(spelled)
    again = Dataset.open(ds.root)
    assert again.replayed == 1
    again.view(0, 0)["status"] = "skipped"
    again.save()
    saved = again.manifest_path.read_text()
    assert '{"row": 1, "column": 1, ' in saved                # reused from the file, not encoded again
    assert on_disk(again) == as_json(again.manifest)
    assert on_disk(again)["views"][11]["status"] == "done" and on_disk(again)["views"][0]["status"] == "skipped"


def test_a_manifest_in_the_former_layout_opens_and_is_rewritten_compact(tmp_path):
    ds = _dataset(tmp_path)
    ds.manifest_path.write_text(json.dumps(ds.manifest, indent=1) + "\n")      # as lfstudio wrote it before
    again = Dataset.open(ds.root)
    again.save()
    assert on_disk(again) == as_json(again.manifest)
    assert again.manifest_path.read_text().splitlines()[1] == '"views":['



def test_a_value_json_cannot_hold_fails_the_save_and_keeps_the_previous_file(tmp_path):
    ds = _dataset(tmp_path)
    ds.save()
    before = ds.manifest_path.read_bytes()
    ds.view(0, 0)["exposure_s"] = math.nan
    with pytest.raises(ValueError):
        ds.save()
    assert ds.manifest_path.read_bytes() == before
    assert not [p for p in ds.root.iterdir() if p.name.startswith(".dataset")]   # no temporary left


_values = st.recursive(st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.text(max_size=6)
                       | st.floats(allow_nan=False, allow_infinity=False),
                       lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=4), inner,
                                                                                    max_size=3), max_leaves=6)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 5), st.sampled_from(["set", "nested", "replace", "del"]),
                          st.text(min_size=1, max_size=4), _values), min_size=1, max_size=12))
def test_random_edits_between_saves_always_land_in_the_file(edits):
    writer = ManifestWriter()
    manifest = {"format": "f", "views": [{"row": 0, "column": c, "d": {"k": c}} for c in range(6)]}
    for i, op, key, value in edits:
        views = manifest["views"]
        v = views[i % len(views)] if views else None
        if v is None:
            views.append({"row": 0, "column": 0})
        elif op == "set":
            v[key] = value
        elif op == "nested":
            v.setdefault("d", {})[key] = value
        elif op == "replace":
            views[i % len(views)] = {**v, key: value}
        elif len(views) > 1:
            views.pop(i % len(views))
        assert json.loads(writer.encode(manifest)) == as_json(manifest)


def test_open_checks_symlinks_once_per_folder_and_still_refuses_an_escape(tmp_path):
    ds = _dataset(tmp_path, columns=3, rows=1)
    outside = tmp_path / "outside.dng"
    outside.write_bytes(b"x")
    (ds.root / "raw" / "r00_c000.dng").write_bytes(b"x")
    os.symlink(ds.root / "raw" / "r00_c000.dng", ds.root / "raw" / "r00_c001.dng")   # inside: fine
    os.symlink(outside, ds.root / "raw" / "r00_c002.dng")                              # leads outside
    for c in range(2):
        ds.view(0, c).update(status="done", file=f"raw/r00_c00{c}.dng")
    ds.save()
    Dataset.open(ds.root)
    ds.view(0, 2).update(status="done", file="raw/r00_c002.dng")
    ds.save()
    with pytest.raises(DatasetError, match="outside"):
        Dataset.open(ds.root)


# -- journal-first checkpoints -------------------------------------------------------------------------
def reopened(ds: Dataset) -> dict:
    """The manifest as a crash right now would leave it: a fresh open of the folder (file + journal)."""
    return as_json(Dataset.open(ds.root).manifest)


def test_checkpoint_journals_changed_views_and_leaves_the_manifest_file_alone(tmp_path):
    ds = owned(_dataset(tmp_path))
    ds.save()
    before = ds.manifest_path.read_bytes()
    ds.record_view(0, 1, status="done", file="raw/r00_c001.dng", timings_s={"move": 0.5})
    journal = ds.root / "journal.jsonl"
    size = journal.stat().st_size
    ds.checkpoint()                              # the record_view line already holds that view
    assert journal.stat().st_size == size and ds.manifest_path.read_bytes() == before
    v = ds.view(1, 2)                            # changed behind record_view's back: a key set, a key gone
    v["status"] = "failed"
    del v["exposure_s"]
    ds.checkpoint()
    assert ds.manifest_path.read_bytes() == before
    last = json.loads(journal.read_text().splitlines()[-1])
    assert last["view"] == as_json(v) and (last["row"], last["column"]) == (1, 2)
    assert reopened(ds) == {**as_json(ds.manifest), "modified": on_disk(ds)["modified"]}
    assert "exposure_s" not in Dataset.open(ds.root).view(1, 2)
    ds.save()                                    # folds the journal into the file
    assert journal.stat().st_size == 0 and on_disk(ds) == as_json(ds.manifest)


def test_checkpoint_rewrites_the_manifest_for_new_top_level_keys_and_a_long_journal(tmp_path, monkeypatch):
    ds = owned(_dataset(tmp_path, columns=20, rows=10))
    ds.save()
    ds.manifest["processing"] = {"profile": "default"}
    ds.checkpoint()
    assert on_disk(ds)["processing"] == {"profile": "default"}
    from lfstudio.dataset import manifest as manifest_module

    monkeypatch.setattr(manifest_module, "JOURNAL_MIN_BYTES", 20_000)      # a journal of ~80 lines, not ~4000
    limit = max(manifest_module.JOURNAL_MIN_BYTES, ds.manifest_path.stat().st_size // 2)
    journal = ds.root / "journal.jsonl"
    i = 0
    while (journal.stat().st_size if journal.exists() else 0) <= limit:   # views changed over and over
        ds.views[i % 200]["attempts"] = i
        ds.checkpoint()
        i += 1
    before = ds.manifest_path.read_bytes()
    ds.views[0]["attempts"] = -1
    ds.checkpoint()                              # past the limit: written out, journal emptied
    assert ds.manifest_path.read_bytes() != before and journal.stat().st_size == 0
    assert on_disk(ds) == as_json(ds.manifest)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 11), st.sampled_from(["record", "set", "delete", "checkpoint", "save"]),
                          st.integers(0, 5)), max_size=30))
def test_whatever_mix_of_changes_and_checkpoints_a_reopen_sees_exactly_the_durable_ones(tmp_path_factory, steps):
    """record_view is durable when it returns, a checkpoint or save makes everything durable, a
    change made directly to a view only with the next checkpoint or save."""
    ds = _dataset(tmp_path_factory.mktemp("mix"))
    durable = as_json(ds.manifest["views"])
    for index, action, value in steps:
        v = ds.views[index]
        if action == "record":
            ds.record_view(v["row"], v["column"], attempts=value)
            durable[index]["attempts"] = value
        elif action == "set":
            v["exposure_s"] = float(value)
        elif action == "delete":
            v.pop("exposure_s", None)
        else:
            getattr(ds, action)()
            durable = as_json(ds.manifest["views"])
        assert reopened(ds)["views"] == durable
