"""A scan's device options: the rig kind's described connection options (``--rig-option``) reach its
driver and are checked by its description; camera settings (``--set``) are made before the first view,
and a refused one stops the scan before any folder is made, named by the option."""

from __future__ import annotations

import pytest

from lfstudio.errors import InputError
from lfstudio.rig.profile import load_rig
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.studio.devices import RigSpec, open_rig
from lfstudio.studio.kinds import parse_options, parse_settings, rig_kinds
from lfstudio.studio.session import ScanRequest, ScanSession


def test_every_built_in_rig_kind_is_registered_and_reads_its_own_words():
    kinds = rig_kinds()
    for name in ("grbl", "sim", "instant", "dryve", "canopen", "sim-dryve", "sim-canopen"):
        assert kinds[name].origin == "built-in", name
    assert RigSpec.parse("/dev/ttyUSB0").kind == "grbl" and RigSpec.parse("grbl:/dev/ttyS1").text == "/dev/ttyS1"
    assert RigSpec.parse("dryve:10.0.0.1,10.0.0.2").text == "dryve:10.0.0.1:502,10.0.0.2:502"
    with pytest.raises(InputError, match="the sim rig takes nothing after 'sim:'"):
        RigSpec.parse("sim:x")


def test_rig_options_are_checked_by_the_kinds_description_and_reach_the_driver():
    sim = rig_kinds()["sim"]
    assert parse_options(sim, ["poll_hz=40"], option="--rig-option") == {"poll_hz": 40.0}
    with pytest.raises(InputError, match=r"--rig-option poll_hz: 0 Hz is out of range"):
        parse_options(sim, ["poll_hz=0"], option="--rig-option")
    with pytest.raises(InputError, match=r"sim has no option 'baud'.*baudrate"):
        parse_options(sim, ["baud=9600"], option="--rig-option")
    drives = parse_options(rig_kinds()["sim-dryve"], ["tolerance_mm=drive", "accept_reference=yes"])
    assert drives == {"tolerance_mm": None, "accept_reference": True}
    link = open_rig("sim", load_rig(), lock=False, connect=False, time_scale=0, poll_hz=40.0, stall_s=7.0)
    try:
        assert link.controller.poll_period_s == pytest.approx(1 / 40) and link.controller.stall_s == 7.0
    finally:
        link.close()


def test_scan_settings_are_made_before_the_first_view(tmp_path):
    plan = ScanPlan(2, 1, (4.0, 6.0))
    session = ScanSession(ScanRequest(tmp_path / "ds", rig="instant", camera="instant",
                                      camera_settings=parse_settings(["shutter_s=0.002"])))
    try:
        session.open(lambda existing, cfg: (plan, None))
        assert session.studio is not None and session.studio.camera.settings()["shutter_s"] == 0.002
        from lfstudio.dataset import Dataset

        recorded = Dataset.open(tmp_path / "ds").manifest["devices"]["camera"]
        assert recorded["set"] == {"shutter_s": 0.002}                       # what was set, with the camera
    finally:
        session.close()


def test_a_refused_scan_setting_is_named_and_makes_no_folder(tmp_path):
    plan = ScanPlan(2, 1, (4.0, 6.0))
    session = ScanSession(ScanRequest(tmp_path / "ds", rig="instant", camera="instant",
                                      camera_settings=parse_settings(["pixel_format=Mono16"])))
    with pytest.raises(InputError, match=r"^--set pixel_format: unknown setting of the instant camera"):
        session.open(lambda existing, cfg: (plan, None))
    assert not (tmp_path / "ds").exists() and session.lock is None
    with pytest.raises(InputError, match=r"--set: cannot read 'Mono16'"):
        parse_settings(["Mono16"])


@pytest.mark.parametrize("first, second", [
    ("canopen:can0:1,2", "canopen:socketcan:can0:2,3"),                      # node 2 of can0, spelled two ways
    ("canopen:udp_multicast:1,2", "canopen:udp_multicast:239.74.163.2:2,5"),  # python-can's default group
    ("dryve:Drive-X.studio.lan,drive-y.studio.lan", "dryve:drive-x.studio.lan.:502,drive-z.studio.lan"),
])
def test_one_drive_spelled_two_ways_is_one_drive_to_lock(first, second, tmp_path, monkeypatch):
    """The drives' locks are named by their addresses as the word gives them: a drive named two ways (a
    CAN channel with or without 'socketcan:', a host name's case or final dot) must still be refused to a
    second opener naming the holder (nothing connects here: each drive word locks its drives first)."""
    from lfstudio.rig.profile import DEFAULT_DRIVE_RIG
    from lfstudio.support.locks import LockBusy

    monkeypatch.setenv("LFSTUDIO_RUNTIME_DIR", str(tmp_path))
    config = load_rig(DEFAULT_DRIVE_RIG)
    held = open_rig(first, config, connect=False, doing="the first opener")
    try:
        with pytest.raises(LockBusy, match=r"axis drive .* is in use by .*the first opener"):
            open_rig(second, config, connect=False, doing="the second opener").close()
    finally:
        held.close(disconnect=False)


def test_a_dryve_word_naming_one_drive_twice_is_refused_however_spelled():
    with pytest.raises(InputError, match="both axes name the same drive drive-x:502"):
        RigSpec.parse("dryve:Drive-X,drive-x.:502")


def test_ipv6_drive_addresses_are_read_or_refused_by_name():
    """'dryve:[fd00::10],[fd00::11]' said "port '10]' is not a number", and 'dryve:fd00::10,fd00::11' took
    'fd00:' for the host and 10 for the port (then 'Name or service not known')."""
    assert RigSpec.parse("dryve:[fd00::10],[FD00::11]:5020").text == "dryve:[fd00::10]:502,[fd00::11]:5020"
    assert RigSpec.parse("dryve:fd00::10,fd00::11").addresses == ("[fd00::10]:502", "[fd00::11]:502")
    assert RigSpec.parse(RigSpec.parse("dryve:[fd00::10],h").text).addresses == ("[fd00::10]:502", "h:502")
    with pytest.raises(InputError, match=r"'\[fd00::10\]x': an IPv6 address is written \[ADDRESS\]:PORT"):
        RigSpec.parse("dryve:[fd00::10]x,h")
    with pytest.raises(InputError, match=r"'fd00:::1': 'fd00:::1' is not an IPv6 address"):
        RigSpec.parse("dryve:fd00:::1,h")
    with pytest.raises(InputError, match="both axes name the same drive"):
        RigSpec.parse("dryve:[fd00::10]:502,fd00:0::10")


def test_a_camera_in_use_is_named_by_its_device_word(tmp_path, monkeypatch):
    """A hot folder held by another opener was named by its lock's key: 'camera folder-/path is in use
    by …'; it is the word the operator typed, 'camera folder:/path'."""
    from lfstudio.studio.devices import open_camera
    from lfstudio.support.locks import LockBusy

    monkeypatch.setenv("LFSTUDIO_RUNTIME_DIR", str(tmp_path / "run"))
    hot = tmp_path / "hot"
    hot.mkdir()
    held = open_camera(f"folder:{hot}", connect=False, doing="the first opener")
    try:
        with pytest.raises(LockBusy, match=rf"^camera folder:{hot} is in use by .*the first opener"):
            open_camera(f"folder:{hot}", connect=False, doing="the second")
    finally:
        held.close(disconnect=False)


def test_a_plugin_rig_in_use_is_named_by_its_device_word(tmp_path, monkeypatch):
    """A plugin rig held by another opener was named by its lock's key ('rig port myrig-left is in use')."""
    from lfstudio.studio.kinds import RigKind, register_rig, unregister
    from lfstudio.studio.simulated import InstantRig
    from lfstudio.support.locks import LockBusy

    monkeypatch.setenv("LFSTUDIO_RUNTIME_DIR", str(tmp_path))
    register_rig(RigKind("myrig", lambda argument, ctx: InstantRig(ctx.config), argument="X",
                         lock_key=lambda argument: f"myrig-{argument}", origin="plugin t 1 (m:f)"))
    try:
        held = open_rig("myrig:left", load_rig(), connect=False, doing="the first opener")
        try:
            with pytest.raises(LockBusy, match=r"^rig myrig:left is in use by .*the first opener"):
                open_rig("myrig:left", load_rig(), connect=False, doing="the second")
        finally:
            held.close(disconnect=False)
    finally:
        unregister("myrig")


def test_a_drive_pair_spelled_two_ways_keeps_one_record_of_the_last_scan(tmp_path, monkeypatch):
    """Which dataset's scan last used a rig is kept per rig (session.note_scan_on_rig, by the controller's
    port): a resume that finds its rig where it left it continues only if no other dataset was scanned on
    it since. The same CAN drives spelled 'can0' in one scan and 'socketcan:can0' in the next were two
    rigs there, so the other dataset's scan went unnoticed."""
    from lfstudio.rig.profile import DEFAULT_DRIVE_RIG
    from lfstudio.support.locks import rig_record_path

    monkeypatch.setenv("LFSTUDIO_RUNTIME_DIR", str(tmp_path))
    config = load_rig(DEFAULT_DRIVE_RIG)
    ports = []
    for word in ("canopen:can0:1,2", "canopen:socketcan:can0:1,2"):
        link = open_rig(word, config, connect=False, lock=False)
        ports.append(link.port)
        link.close(disconnect=False)
    assert rig_record_path(ports[0]) == rig_record_path(ports[1]), ports
