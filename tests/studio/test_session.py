"""The scan session's rules in one process: device records and what counts as other devices, the
per-view device record surviving a crash (journal), the homing policy on real GRBL-protocol rigs."""

from __future__ import annotations

import pytest

from lfstudio.dataset import Dataset
from lfstudio.errors import DeviceError, InputError
from lfstudio.rig.motion import RigState
from lfstudio.rig.profile import load_rig
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.studio.devices import open_rig
from lfstudio.studio.session import (create_scan_dataset, device_differences, prepare_rig, recorded_devices,
                                     rig_spec_of)

REAL = {"rig": {"kind": "grbl", "profile": "Reference gantry", "port": "/dev/ttyUSB0", "firmware": "GRBL 1.1h"},
        "camera": {"kind": "gphoto2", "spec": "gphoto2", "model": "Sony ILCE-7RM2", "serial": "123"}}


def with_(record: dict, dev: str, **changes) -> dict:
    return {**record, dev: {**record[dev], **changes}}


def test_what_counts_as_other_devices():
    assert device_differences(REAL, REAL) == []
    assert device_differences(REAL, with_(REAL, "rig", port="/dev/ttyUSB1")) == []   # USB renumbered
    assert device_differences(REAL, with_(REAL, "camera", serial=None)) == []        # not told: not compared
    sim = {"rig": {"kind": "sim", "profile": "Reference gantry"}, "camera": {"kind": "sim", "spec": "sim"}}
    assert [d.split(":")[0] for d in device_differences(REAL, sim)] == ["rig kind", "camera kind"]
    other_body = device_differences(REAL, with_(REAL, "camera", serial="456"))
    assert other_body == ["camera serial: the dataset was captured with '123', this scan has '456'"]
    assert rig_spec_of(REAL["rig"]) == "/dev/ttyUSB0" and rig_spec_of(sim["rig"]) == "sim"


@pytest.mark.parametrize("record", [{"kind": "grbl"}, {"kind": "dryve", "port": None}, {"kind": None}])
def test_a_rig_record_without_its_port_is_refused_naming_port_not_opened_as_a_port(record):
    """A damaged or hand-edited devices record: no serial port named after the kind ("grbl", "None")
    is opened on --resume; the operator is asked for --port."""
    from lfstudio.errors import InputError
    from lfstudio.studio.devices import RigSpec

    assert rig_spec_of(record) == ""
    with pytest.raises(InputError) as err:
        RigSpec.parse(rig_spec_of(record))
    assert str(err.value).startswith("--port: no rig given")


def test_datasets_made_before_the_device_record_are_read_from_their_old_fields(tmp_path):
    plan = ScanPlan(2, 1, (4.0, 6.0))
    old = create_scan_dataset(tmp_path / "old", plan, rig={"name": "Reference gantry", "port": "/dev/ttyACM0"},
                              camera={"name": "x", "driver": "folder:/data/in"}, lens={})
    assert recorded_devices(old) == {"rig": {"kind": "grbl", "profile": "Reference gantry", "port": "/dev/ttyACM0"},
                                     "camera": {"kind": "folder", "spec": "folder:/data/in"}}
    gui = create_scan_dataset(tmp_path / "gui", plan, rig={"name": "Reference gantry"}, camera={"name": "x"}, lens={})
    assert recorded_devices(gui) is None


def test_per_view_devices_are_journalled_and_cleared_when_the_own_devices_return(tmp_path):
    plan = ScanPlan(3, 1, (4.0, 6.0))
    ds = create_scan_dataset(tmp_path / "ds", plan, rig={}, camera={}, lens={}, devices=REAL)
    done = {"status": "done", "file": "raw/r00_c000.dng"}
    other = with_(REAL, "camera", serial="456")
    ds.capture_devices = other
    ds.record_view(0, 0, **done)
    ds.record_view(0, 1, **{**done, "file": "raw/r00_c001.dng"})
    ds.capture_devices = None                       # the dataset's own camera is back: re-capture (0, 1)
    ds.record_view(0, 1, **{**done, "file": "raw/r00_c001.dng"})
    ds.record_view(0, 2, status="failed")
    ds.close()                                      # no save: what a crash leaves, the journal only
    again = Dataset.open(tmp_path / "ds")
    assert again.replayed == 4
    assert again.view(0, 0)["devices"] == other
    assert again.view(0, 1)["devices"] is None and "devices" not in again.view(0, 2)


def test_homing_policy_on_a_rig_with_limit_switches():
    config = load_rig()
    link = open_rig("sim", config, time_scale=0, timeout_s=1.0)
    try:
        rig = link.controller
        assert rig.status().state is RigState.ALARM
        with pytest.raises(DeviceError, match=r"ALARM .*add --home to this command, or first run 'lfstudio rig "
                                              rf"--port {link.port} home'"):
            prepare_rig(rig, config, link.port)
        with pytest.raises(InputError, match="--origin-here: .* homes with its limit switches"):
            prepare_rig(rig, config, link.port, origin_here=True)
        assert prepare_rig(rig, config, link.port, home=True) == ["rig homed"]
        assert prepare_rig(rig, config, link.port) == []            # homed: nothing to say
        rig.disconnect()
        rig.connect()                                               # a new connection: the controller's word
        assert rig.status().homed and prepare_rig(rig, config, link.port) == []
    finally:
        link.close()


def test_homing_policy_on_a_rig_without_limit_switches():
    config = load_rig("Desktop slider 1 m")
    link = open_rig("sim", config, time_scale=0, timeout_s=1.0)
    try:
        rig = link.controller
        with pytest.raises(InputError, match="--home: .* has no limit switches.*--origin-here"):
            prepare_rig(rig, config, link.port, home=True)
        with pytest.raises(DeviceError, match="not homed .*--origin-here"):
            prepare_rig(rig, config, link.port)
        assert prepare_rig(rig, config, link.port, origin_here=True) == [
            "origin (0, 0) set at the carriage's current position"]
        assert rig.status().homed and rig.status().position_mm == (0.0, 0.0)
    finally:
        link.close()


def test_resume_on_a_recorded_port_that_is_gone_says_so(tmp_path):
    from lfstudio.studio.session import ScanRequest, ScanSession

    plan = ScanPlan(2, 1, (4.0, 6.0))
    gone = with_(REAL, "rig", port=str(tmp_path / "ttyUSB9"))
    create_scan_dataset(tmp_path / "ds", plan, rig={"name": "Reference gantry"}, camera={}, lens={}, devices=gone)
    session = ScanSession(ScanRequest(tmp_path / "ds", resume=True))
    with pytest.raises(DeviceError, match=r"captured with the rig on .*ttyUSB9, which is not there now.*--port PORT"):
        session.open(lambda existing, cfg: (plan, None))
    assert session.lock is None                     # released again


def test_a_resume_whose_rig_profile_is_gone_is_refused_not_run_on_another_profile(tmp_path):
    """The dataset's rig profile (its soft limits, speeds, homing) no longer installed: the resume went on
    with the reference gantry's limits (a note said so), i.e. the rig's limits assumed. It is refused,
    naming the profile and --rig-profile, before any device is opened."""
    from dataclasses import replace

    from lfstudio.studio.session import ScanRequest, ScanSession

    workshop = replace(load_rig(), name="workshop rig 1 m")          # a profile of this day, gone tomorrow
    plan = ScanPlan(2, 1, (4.0, 6.0))
    first = ScanSession(ScanRequest(tmp_path / "ds", rig="instant", camera="instant", rig_config=workshop))
    first.open(lambda existing, cfg: (plan, None))
    first.close()
    assert Dataset.open(tmp_path / "ds").manifest["rig"]["name"] == "workshop rig 1 m"
    again = ScanSession(ScanRequest(tmp_path / "ds", resume=True))
    with pytest.raises(InputError, match=r"^--rig-profile: the dataset's rig profile 'workshop rig 1 m' "):
        again.open(lambda existing, cfg: (plan, None))
    assert again.studio is None and again.lock is None


def test_a_resume_of_a_dataset_without_its_devices_needs_them_named(tmp_path):
    """A dataset that does not record its devices (made by an older lfstudio's window) resumed without
    --port/--camera went on with the simulated rig and camera: the rest of a real scan filled with
    rendered pictures, a warning in the log. They must be named; nothing is opened or written."""
    import json

    from lfstudio.studio.session import ScanRequest, ScanSession

    plan = ScanPlan(2, 1, (4.0, 6.0))
    create_scan_dataset(tmp_path / "ds", plan, rig={"name": "Reference gantry"}, camera={"name": "ILCE-7RM2"},
                        lens={}).close()
    before = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    session = ScanSession(ScanRequest(tmp_path / "ds", resume=True))
    with pytest.raises(InputError, match=r"^--port/--camera: .*does not record which devices captured it"):
        session.open(lambda existing, cfg: (plan, None))
    assert session.studio is None and session.lock is None
    assert json.loads((tmp_path / "ds" / "dataset.json").read_text()) == before
