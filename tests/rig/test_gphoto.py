"""The gphoto2 driver's pure parts: reading the camera's setting texts, matching a value against the
offered choices, and the operator's message for every libgphoto2 error code. Everything that talks
to a camera runs against libgphoto2's virtual PTP camera in test_gphoto_vusb.py."""

from __future__ import annotations

import pytest

from lfstudio.errors import InputError
from lfstudio.rig.gphoto import (SETTINGS, _GP_MESSAGES, gp_message, match_choice, parse_ev, parse_f_number,
                                 parse_iso, parse_shutter_s)


@pytest.mark.parametrize("text,seconds", [
    ("1/100", 0.01), ("0.0100s", 0.01), ("1.0000s", 1.0), ("1/4000", 0.00025), ("30", 30.0), ('2.5"', 2.5),
    ("1/3 s", 1 / 3), ("0.3", 0.3), ("1/8000s", 0.000125), ("2 sec", 2.0),
    ("Bulb", None), ("bulb", None), ("Auto", None), ("Time", None), ("", None), ("0", None), ("1/0", None)])
def test_shutter_texts_of_real_bodies(text, seconds):
    assert parse_shutter_s(text) == (pytest.approx(seconds) if seconds else None)


@pytest.mark.parametrize("text,value", [("f/8", 8.0), ("8", 8.0), ("F5.6", 5.6), ("f/2.8", 2.8), ("f 11", 11.0),
                                        ("implicit auto", None), ("", None)])
def test_f_number_texts(text, value):
    assert parse_f_number(text) == value


@pytest.mark.parametrize("text,value", [("100", 100), ("ISO 3200", 3200), ("100.0", 100), ("Auto", None),
                                        ("Auto ISO", None), ("Hi 1", None), ("1/3", None)])
def test_iso_texts(text, value):
    assert parse_iso(text) == value


@pytest.mark.parametrize("text,value", [("+1", 1.0), ("-0.3", -0.3), ("0", 0.0), ("+1/3", 1 / 3), ("-2/3 EV", -2 / 3)])
def test_exposure_compensation_texts(text, value):
    assert parse_ev(text) == pytest.approx(value)


SONY_SHUTTER = ("30", "25", "1", "0.8", "1/2", "1/60", "1/100", "1/125", "1/250", "1/4000", "Bulb")
VUSB_SHUTTER = ("1.0000s", "0.1000s", "0.0500s", "0.0200s", "0.0100s", "0.0050s", "0.0025s", "0.0012s", "0.0001s")


@pytest.mark.parametrize("choices,wanted,found", [
    (SONY_SHUTTER, 0.01, "1/100"), (SONY_SHUTTER, "0.01 s", "1/100"), (SONY_SHUTTER, "1/100", "1/100"),
    (SONY_SHUTTER, 0.0167, "1/60"), (SONY_SHUTTER, 0.5, "1/2"), (SONY_SHUTTER, 30, "30"),
    (SONY_SHUTTER, "bulb", "Bulb"), (VUSB_SHUTTER, 0.01, "0.0100s"), (VUSB_SHUTTER, "1/100", "0.0100s"),
    (VUSB_SHUTTER, 0.0012, "0.0012s"), (VUSB_SHUTTER, "1 s", "1.0000s")])
def test_shutter_is_matched_by_value(choices, wanted, found):
    assert match_choice("shutter_s", SETTINGS["shutter_s"], wanted, choices) == found


@pytest.mark.parametrize("choices,wanted,found", [
    (("f/2.8", "f/4", "f/5.6", "f/8", "f/11"), 8, "f/8"), (("2.8", "4", "5.6", "8"), 8, "8"),
    (("f/2.8", "f/4", "f/5.6", "f/8"), "f/5.6", "f/5.6"), (("f/2.8", "f/4", "f/5.6", "f/8"), 5.7, "f/5.6"),
    (("f/7.1", "f/8"), "7.1", "f/7.1")])
def test_aperture_is_matched_by_value(choices, wanted, found):
    assert match_choice("aperture", SETTINGS["aperture"], wanted, choices) == found


def test_iso_is_matched_exactly_and_words_by_text():
    choices = ("Auto", "100", "200", "400", "800")
    spec = SETTINGS["iso"]
    assert match_choice("iso", spec, 400, choices) == "400"
    assert match_choice("iso", spec, "ISO 200", choices) == "200"
    assert match_choice("iso", spec, "auto", choices) == "Auto"
    with pytest.raises(InputError, match=r"iso: 250 is not offered by the camera \(valid: Auto, 100, 200, 400, 800\)"):
        match_choice("iso", spec, 250, choices)


def test_text_settings_match_ignoring_case_and_spacing_or_one_containing_choice():
    spec = SETTINGS["format"]
    choices = ("JPEG Fine", "RAW", "RAW + JPEG Fine", "RAW + JPEG Normal")
    assert match_choice("format", spec, "raw", choices) == "RAW"
    assert match_choice("format", spec, "raw+jpegfine", choices) == "RAW + JPEG Fine"
    assert match_choice("format", spec, "normal", choices) == "RAW + JPEG Normal"     # the one containing it
    with pytest.raises(InputError, match="not offered"):
        match_choice("format", spec, "RAW + JPEG", choices)               # two choices contain it: ask
    with pytest.raises(InputError, match="not offered"):
        match_choice("format", spec, "TIFF", choices)


def test_a_value_between_two_choices_is_refused_with_the_list():
    with pytest.raises(InputError) as err:
        match_choice("shutter_s", SETTINGS["shutter_s"], 0.003, VUSB_SHUTTER, "Nikon DSC D750")
    assert str(err.value) == ("shutter_s: 0.003 s is not offered by Nikon DSC D750 (valid: "
                              + ", ".join(VUSB_SHUTTER) + ")")


class GpError(Exception):
    """libgphoto2's exception as python-gphoto2 raises it (code + libgphoto2's text)."""

    def __init__(self, code):
        try:
            import gphoto2

            self.string = gphoto2.gp_result_as_string(code)
        except ImportError:
            self.string = "Unknown error"
        super().__init__(f"[{code}] {self.string}")
        self.code = code


@pytest.mark.parametrize("code", sorted(_GP_MESSAGES))
def test_every_known_code_has_an_operator_message(code):
    text = gp_message(GpError(code), "capture")
    assert text.startswith("camera: capture failed: ") and text.endswith(f"[gphoto2 {code}]")
    assert "Traceback" not in text and "GPhoto2Error" not in text and "Unknown error" not in text


@pytest.mark.parametrize("code,words", [
    (-3, "the card or the camera's buffer is full"), (-105, "no camera found"), (-53, "busy with another program"),
    (-7, "USB input/output error"), (-110, "the camera is busy"), (-52, "check the cable"),
    (-115, "card is full"), (-6, "'PC Remote'"), (-108, "retry the shot")])
def test_the_messages_say_what_happened(code, words):
    assert words in gp_message(GpError(code), "capture")


def test_out_of_memory_is_not_what_the_operator_reads():
    assert "memory" not in gp_message(GpError(-3), "capture").split("[")[0].lower()


def test_a_camera_that_did_not_answer_says_how_long_it_was_waited_for():
    assert "the camera did not answer within 30 s" in gp_message(GpError(-10), "capture", waited_s=30.2)
    assert "did not answer in time" in gp_message(GpError(-10), "capture")


def test_libgphoto2s_own_words_are_quoted():
    text = gp_message(GpError(-1), "capture", camera_said="PTP Store Full")
    assert text == ("camera: capture failed: the camera reported 'PTP Store Full': check its screen; switch it "
                    "off and on if it repeats [gphoto2 -1]")
    text = gp_message(GpError(-3), "capture", camera_said="Camera memorycard ran full during capture.")
    assert "(libgphoto2: 'Camera memorycard ran full during capture.')" in text


def test_an_unknown_code_still_says_what_to_do():
    text = gp_message(GpError(-999), "capture")
    assert "switch the camera off and on, reconnect it and retry" in text and text.endswith("[gphoto2 -999]")
