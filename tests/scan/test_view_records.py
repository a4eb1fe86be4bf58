"""The view records the stages write are the typed ones (dataset/manifest.py ViewRecord, FrameRecord,
ProcessedRecord): a scan on the simulated studio, one picture a view and bracketed, then processing,
write only declared keys, every required one, each of its declared kind."""

from __future__ import annotations

import types
import typing

from lfstudio.dataset import Dataset
from lfstudio.dataset.bracket import parse_bracket
from lfstudio.dataset.manifest import FrameRecord, ProcessedRecord, ViewRecord
from lfstudio.scan.events import ScanState
from lfstudio.scan.scan_plan import ScanPlan
from tests.scan.conftest import engine_with_events, open_sim_studio


def _check(record: dict, typed: type) -> None:
    hints = typing.get_type_hints(typed)
    assert set(record) <= set(hints), (typed.__name__, set(record) - set(hints))
    assert typed.__required_keys__ <= set(record), (typed.__name__, typed.__required_keys__ - set(record))
    for key, value in record.items():
        hint = hints[key]
        union = typing.get_origin(hint) in (typing.Union, types.UnionType)
        kinds = tuple(typing.get_origin(a) or a for a in (typing.get_args(hint) if union else (hint,)))
        kinds = tuple(dict if k in (FrameRecord, ProcessedRecord) else k for k in kinds)
        kinds += (int,) if float in kinds else ()
        assert isinstance(value, kinds), (key, value)


def test_a_scan_and_processing_write_the_typed_view_records(tmp_path):
    from lfstudio.dataset.profile import Profile
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
        done = Dataset.open(ds.root)
        assert len(done.done_views()) == 6
        for view in done.views:
            _check(view, ViewRecord)
            for frame in view.get("frames") or ():
                _check(frame, FrameRecord)
            _check(view["processed"], ProcessedRecord)
        assert all(len(v.get("frames") or ()) == (3 if bracket else 0) for v in done.views)
