"""The view records the stages write are the typed ones (dataset/manifest.py ViewRecord, FrameRecord,
ProcessedRecord, HdrMerged, RestoredFrom): a scan on the simulated studio, one picture a view and
bracketed, then processing and the HDR merge, and the importers (import-images, import-hevc of an
export) write only declared keys, every required one, each of its declared kind."""

from __future__ import annotations

import types
import typing

from lfstudio.dataset import Dataset
from lfstudio.dataset.bracket import parse_bracket
from lfstudio.dataset.manifest import FrameRecord, HdrMerged, ProcessedRecord, ViewRecord
from lfstudio.scan.events import ScanState
from lfstudio.scan.scan_plan import ScanPlan
from tests.conftest import hevc_round_trip
from tests.scan.conftest import engine_with_events, open_sim_studio


def _kinds(hint) -> tuple:
    """The runtime types a value of ``hint`` may have (a TypedDict is a dict, a Literal its values' types)."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return tuple(k for a in typing.get_args(hint) for k in _kinds(a))
    if typing.get_origin(hint) is typing.Literal:
        return tuple(type(a) for a in typing.get_args(hint))
    if typing.is_typeddict(hint):
        return (dict,)
    kind = typing.get_origin(hint) or hint
    return (kind, int) if kind is float else (kind,)


def _check(record: dict, typed: type) -> None:
    hints = typing.get_type_hints(typed)
    assert set(record) <= set(hints), (typed.__name__, set(record) - set(hints))
    assert typed.__required_keys__ <= set(record), (typed.__name__, typed.__required_keys__ - set(record))
    for key, value in record.items():
        assert isinstance(value, _kinds(hints[key])), (typed.__name__, key, value)
        if typing.get_origin(hints[key]) is typing.Literal:
            assert value in typing.get_args(hints[key]), (typed.__name__, key, value)
    for key, sub in (("processed", ProcessedRecord), ("restored_from", typing.get_type_hints(ViewRecord)["restored_from"])):
        if typed is ViewRecord and isinstance(record.get(key), dict):
            _check(record[key], sub)


def test_a_scan_and_processing_write_the_typed_view_records(tmp_path):
    from lfstudio.dataset.profile import Profile
    from lfstudio.processing.hdr import MergeOptions, merge_dataset
    from lfstudio.processing.pipeline import process_dataset

    profile = Profile()
    profile.rectify.enabled = False          # no calibration here: the other steps write the record

    for name, bracket in (("single", None), ("bracketed", parse_bracket("-1,0,+1"))):
        session, plan, ds = open_sim_studio(tmp_path / name, 3, 2, 64)
        try:
            engine, _ = engine_with_events(session, ScanPlan(**{**plan.__dict__, "bracket": bracket}), ds)
            engine.start()
            assert engine.wait(60) is ScanState.FINISHED, engine.message
        finally:
            session.close()
        assert process_dataset(ds.root, profile, workers=0).ok
        if bracket:
            assert merge_dataset(ds.root, MergeOptions(), profile, workers=0).merged == 6
        done = Dataset.open(ds.root)
        assert len(done.done_views()) == 6
        for view in done.views:
            _check(view, ViewRecord)
            for frame in view.get("frames") or ():
                _check(frame, FrameRecord)
            _check(view["processed"], ProcessedRecord)
            if bracket:
                _check(view["hdr"], HdrMerged)
        assert all(len(v.get("frames") or ()) == (3 if bracket else 0) for v in done.views)


def test_the_importers_write_the_typed_view_records(tmp_path):
    """import-images of a scan's RAW files, and import-hevc of an export of part of its processed views
    (the others come back skipped, with a note)."""
    from lfstudio.export.import_images import ImportOptions, import_images

    session, plan, ds = open_sim_studio(tmp_path / "scan", 3, 2, 64)
    try:
        engine, _ = engine_with_events(session, plan, ds)
        engine.start()
        assert engine.wait(60) is ScanState.FINISHED, engine.message
    finally:
        session.close()
    grid = (ds.grid.columns, ds.grid.rows)
    imported = Dataset.open(import_images(ImportOptions(ds.root / "raw", tmp_path / "imported", grid, (1.0, 1.0),
                                                        pattern="*.dng")))
    assert len(imported.done_views()) == 6
    for view in imported.views:
        _check(view, ViewRecord)
        assert view.get("source_file", "").endswith(".dng")

    restored = hevc_round_trip(ds.root, tmp_path)
    statuses = sorted(v["status"] for v in restored.views)
    assert statuses == ["done", "done", "skipped", "skipped", "skipped", "skipped"], statuses
    for view in restored.views:
        _check(view, ViewRecord)
        assert ("restored_from" in view) == (view["status"] == "done")
        assert view.get("processed", {}).get("restored_from_hevc", view["status"] != "done") is True
