"""Review findings on dataset/bracket.py, fixed: the text the Scan
panel fills in from an opened dataset must read back as the same bracket (else the window's resume
is refused naming two identical brackets), and ±1 EV around the commonest shutter times must find
the camera's own nominal 1/60 s and 1/120-ish choices (cameras list 1/60 for 1/62.5 s)."""

from __future__ import annotations

import pytest

from lfstudio.dataset.bracket import Bracket, frame_times_on_camera, parse_bracket

FULL_STOPS = [1 / 1000, 1 / 500, 1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15, 1 / 8, 1 / 4, 1 / 2, 1.0]
FULL_STOP_TEXTS = ["1/1000", "1/500", "1/250", "1/125", "1/60", "1/30", "1/15", "1/8", "1/4", "1/2", "1"]


def test_ev_steps_read_back_from_their_text():
    b = parse_bracket("-2,0,+2")
    assert parse_bracket(Bracket.from_manifest(b.to_manifest()).text()) == b


def test_explicit_shutter_times_read_back_from_their_text():
    b = parse_bracket("1/500,1/125,1/30s")
    recorded = Bracket.from_manifest(b.to_manifest())      # what the Scan panel fills in from the dataset
    assert parse_bracket(recorded.text(), "Bracket") == recorded


@pytest.mark.parametrize("base_s, expected", [(1 / 125, (1 / 250, 1 / 125, 1 / 60)),
                                              (1 / 60, (1 / 125, 1 / 60, 1 / 30))])
def test_one_ev_around_the_commonest_shutter_times_finds_the_cameras_nominal_times(base_s, expected):
    times = frame_times_on_camera(parse_bracket("-1,0,+1"), base_s, FULL_STOPS, FULL_STOP_TEXTS)
    assert times == pytest.approx(expected)
