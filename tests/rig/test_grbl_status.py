"""GRBL 1.1 status-report parsing: every field, any order, garbage around it."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lfstudio.rig.grbl_protocol import parse_status

coord = st.floats(min_value=-9999, max_value=9999, allow_nan=False).map(lambda v: round(v, 3))
triple = st.tuples(coord, coord, coord)
noise = st.text(alphabet=st.characters(blacklist_characters="<>\r\n", min_codepoint=0, max_codepoint=255),
                max_size=12)


def fmt(values):
    return ",".join(f"{v:.3f}" for v in values)


@st.composite
def reports(draw):
    state = draw(st.sampled_from(["Idle", "Run", "Hold:0", "Hold:1", "Jog", "Alarm", "Door:2", "Check",
                                  "Home", "Sleep"]))
    fields = {}
    if draw(st.booleans()):
        fields["MPos"] = draw(triple)
    else:
        fields["WPos"] = draw(triple)
    if draw(st.booleans()):
        fields["WCO"] = draw(triple)
    if draw(st.booleans()):
        fields["Bf"] = (draw(st.integers(0, 15)), draw(st.integers(0, 128)))
    if draw(st.booleans()):
        fields["Ln"] = draw(st.integers(0, 99999))
    if draw(st.booleans()):
        fields["FS"] = (draw(st.integers(0, 20000)), draw(st.integers(0, 1000)))
    elif draw(st.booleans()):
        fields["F"] = draw(st.integers(0, 20000))
    if draw(st.booleans()):
        fields["Pn"] = "".join(draw(st.lists(st.sampled_from("XYZPDHRS"), min_size=1, max_size=4, unique=True)))
    if draw(st.booleans()):
        fields["Ov"] = (draw(st.integers(10, 200)), draw(st.integers(25, 100)), draw(st.integers(10, 200)))
    if draw(st.booleans()):
        fields["A"] = draw(st.sampled_from(["S", "SFM", "C"]))
    order = draw(st.permutations(list(fields)))
    return state, fields, order


def render(key, value):
    if key in ("MPos", "WPos", "WCO"):
        return f"{key}:{fmt(value)}"
    if isinstance(value, tuple):
        return f"{key}:{','.join(str(v) for v in value)}"
    return f"{key}:{value}"


@settings(max_examples=100, deadline=None)
@given(reports(), noise, noise)
def test_every_field_any_order_with_garbage(report, before, after):
    state, fields, order = report
    text = before + "<" + "|".join([state] + [render(k, fields[k]) for k in order]) + ">" + after
    st_ = parse_status(text)
    assert st_ is not None
    name, _, sub = state.partition(":")
    assert st_.state == name and st_.substate == (int(sub) if sub else None)
    for key, attr in (("MPos", "mpos"), ("WPos", "wpos"), ("WCO", "wco")):
        assert getattr(st_, attr) == (tuple(fields[key]) if key in fields else None)
    if "Bf" in fields:
        assert (st_.planner_free, st_.rx_free) == fields["Bf"]
    if "FS" in fields:
        assert (st_.feed_mm_min, st_.spindle_rpm) == fields["FS"]
    if "F" in fields:
        assert st_.feed_mm_min == fields["F"]
    assert st_.line_number == fields.get("Ln")
    assert st_.pins == fields.get("Pn", "")
    assert st_.overrides == fields.get("Ov")
    assert st_.accessories == fields.get("A", "")
    assert st_.unknown == ()


def test_work_position_from_mpos_and_last_wco():
    st_ = parse_status("<Idle|MPos:10.000,20.000,0.000|FS:0,0>")
    assert st_.work_position((1.0, 2.0, 0.0)) == (9.0, 18.0, 0.0)
    with_wco = parse_status("<Idle|MPos:10.000,20.000,0.000|WCO:5.000,5.000,0.000>")
    assert with_wco.work_position((1.0, 2.0, 0.0)) == (5.0, 15.0, 0.0)


@pytest.mark.parametrize("text", ["", "ok", "<>", "<Flying|MPos:1,2,3>", "garbage <Idle", "Idle|MPos:1,2,3>",
                                  "<Hold:x|MPos:0,0,0>"])
def test_not_a_report(text):
    assert parse_status(text) is None


def test_malformed_fields_are_skipped_not_fatal():
    st_ = parse_status("\x00\xff<Run|MPos:1.000,abc,3|FS:100,0|Zz:9|Bf:15>")
    assert st_.state == "Run" and st_.mpos is None and st_.feed_mm_min == 100
    assert set(st_.unknown) == {"MPos:1.000,abc,3", "Zz:9", "Bf:15"}


# -- every line from the controller: parse_line never raises ------------------------------------
from lfstudio.rig.grbl_protocol import GrblLine, parse_line  # noqa: E402


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=300))
def test_parse_line_never_raises_on_any_text(text):
    parsed = parse_line(text)
    assert isinstance(parsed, GrblLine) and parsed.kind in (
        "ok", "error", "alarm", "status", "banner", "msg", "setting", "param", "info", "garbage")


lines_like_grbl = st.one_of(
    st.builds(lambda k, v: f"${k}={v}", st.integers(-5, 99999), st.text("0123456789.-+e", max_size=12)),
    st.builds(lambda n, v: f"[{n}:{v}]", st.sampled_from(["G54", "G92", "G28", "PRB", "TLO", "VER", "MSG"]),
              st.text("0123456789.,-:", max_size=30)),
    st.builds(lambda p, d: f"{p}:{d}", st.sampled_from(["error", "ALARM"]), st.text("0123456789", max_size=5000)),
    st.builds(lambda body: f"<{body}>", st.text("IdleRunHold:0123456789|MPosWCO,.-FSBfPnXYZ", max_size=80)),
)


@settings(max_examples=300, deadline=None)
@given(lines_like_grbl)
def test_parse_line_on_near_misses_of_every_kind(text):
    parsed = parse_line(text)                       # never raises; malformed numbers are garbage
    if parsed.kind == "setting":
        assert parsed.key is not None and parsed.value is not None and math.isfinite(parsed.value)
    if parsed.kind in ("error", "alarm"):
        assert parsed.code is not None and 0 <= parsed.code <= 9999
    if parsed.kind == "param":
        assert parsed.values and all(math.isfinite(v) for v in parsed.values)


@pytest.mark.parametrize("text, kind", [
    ("$1=.", "garbage"), ("$1=1.2.3", "garbage"), ("$110=1e999", "garbage"), ("$110=nan", "garbage"),
    ("[G54:1..2,0,0]", "garbage"), ("[G54:,,]", "garbage"), ("ALARM:" + "9" * 5000, "garbage"),
    ("error:" + "1" * 5000, "garbage"), ("ALARM:", "garbage"), ("<Idle|MPos:1,2,3", "garbage"),
    ("Grbl 1.1h ['$' for help]", "banner"), ("[MSG:'$H'|'$X' to unlock]", "msg"), ("ok", "ok"),
    ("error:7", "error"), ("ALARM:3", "alarm"), ("$110=500.000", "setting"), ("$22=1", "setting"),
    ("[G54:-200.000,-200.000,0.000]", "param"), ("[PRB:0.000,0.000,0.000:0]", "param"),
    ("[VER:1.1h.20190830:]", "info"), ("[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]", "info"),
    ("<Hold:0|MPos:-29.920,0.000,0.000|FS:0,0>", "status"),
])
def test_parse_line_examples(text, kind):
    parsed = parse_line(text)
    assert parsed.kind == kind
    if text == "$110=500.000":
        assert (parsed.key, parsed.value) == (110, 500.0)
    if text.startswith("[G54:-200"):
        assert (parsed.name, parsed.values) == ("G54", (-200.0, -200.0, 0.0))
    if text.startswith("<Hold:0"):
        assert (parsed.status.state, parsed.status.substate) == ("Hold", 0)
    if text.startswith("Grbl"):
        assert parsed.name == "1.1h"


def test_a_line_of_noise_is_garbage_at_once_and_numbers_parse_in_linear_time():
    """The number pattern used to backtrack quadratically (21 s for 64 KiB of digits, holding the GIL, so
    STOP from another thread waited that long); a line longer than GRBL ever sends is garbage unparsed."""
    import threading

    from lfstudio.rig.grbl_protocol import MAX_LINE_CHARS, _number, parse_line

    assert parse_line("$110=" + "0" * MAX_LINE_CHARS + "1").kind == "garbage"       # too long for GRBL
    assert parse_line("$110=500.000").value == 500.0
    done = threading.Event()
    results = []

    def parse():
        results.append(parse_line("$110=" + "1" * 65536 + "x").kind)
        try:
            _number("1" * 65536 + "x")
        except ValueError:
            results.append("refused")
        done.set()

    threading.Thread(target=parse, daemon=True).start()
    assert done.wait(10), "parsing a 64 KiB line took more than 10 s"      # microseconds now; 21 s before
    assert results == ["garbage", "refused"]
    assert _number("12.") == 12.0 and _number(".5") == 0.5 and _number("-3.25") == -3.25
