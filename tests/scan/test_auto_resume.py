"""Recovery by itself (ScanEngine(auto_resume=N)): causes that clear without a person resume the scan
when they clear, at most N times, each wait and resume told; STOP, alarms (limit switches, homing),
position errors never resume by themselves."""

from __future__ import annotations

import threading

import pytest

from lfstudio.errors import DeviceError
from lfstudio.rig.grbl import ConnectionLost, GrblAlarm, PositionError
from lfstudio.rig.motion import RigState, RigStatus
from lfstudio.rig.profile import load_rig
from lfstudio.scan.engine import ScanEngine
from lfstudio.scan.faults import CLEARS_CAMERA, CLEARS_DISK, CLEARS_RIG
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.notify import Notifier
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.sim.instant import InstantCamera, InstantRig
from lfstudio.studio.session import create_scan_dataset
from tests.scan.receivers import Receiver

RIG = load_rig()
T = 60


class FlakyCamera(InstantCamera):
    """Unplugged after ``unplug_after`` captures until ``plug_in()``: captures and connects fail."""

    def __init__(self, *a, unplug_after: int = 3, **kw):
        super().__init__(*a, **kw)
        self.unplug_after = unplug_after
        self.plugged = threading.Event()
        self.plugged.set()
        self.connects = 0

    def connect(self):
        if not self.plugged.is_set():
            raise DeviceError("instant camera: no camera on the USB bus")
        self.connects += 1
        super().connect()

    def capture(self, stem_path, on_exposed=None):
        if self.captures == self.unplug_after and self.plugged.is_set() and self.unplug_after >= 0:
            self.plugged.clear()
            self.unplug_after = -1
        if not self.plugged.is_set():
            raise DeviceError("instant camera: the camera was disconnected")
        return super().capture(stem_path, on_exposed)


class FaultyRig(InstantRig):
    """Raises ``fault`` from the ``at``-th move; a lost connection stays lost until ``reconnectable``."""

    def __init__(self, config, fault: Exception, at: int = 3):
        super().__init__(config)
        self.fault, self.at = fault, at
        self.reconnectable = threading.Event()
        self.lost = False

    def connect(self):
        if self.lost and not self.reconnectable.is_set():
            raise ConnectionLost("no GRBL controller answers on /dev/ttyUSB0")
        self.lost = False
        super().connect()

    def status(self):
        if self.lost:
            return RigStatus(RigState.DISCONNECTED, message="connection lost")
        if isinstance(self.fault, GrblAlarm) and self.at < 0:
            return RigStatus(RigState.ALARM, self._pos, homed=False, message="ALARM:1")
        return super().status()

    def move_to(self, x_mm, y_mm, timeout_s=None):
        if self.moves == self.at:
            self.at = -1
            if isinstance(self.fault, ConnectionLost):
                self.lost = True
                self._connected = False
            raise self.fault
        return super().move_to(x_mm, y_mm, timeout_s)


def make(tmp_path, rig=None, camera=None, cols=4, rows=3, **kw):
    plan = ScanPlan.centered(cols, rows, (4.0, 6.0), RIG, settle_s=0.0)
    ds = create_scan_dataset(tmp_path / "day1", plan, rig={"name": RIG.name}, camera={"name": "instant"},
                             lens={"name": "test"})
    rig = rig or InstantRig(RIG)
    rig.connect()
    camera = camera or InstantCamera(rig.true_position_mm)
    camera.connect()
    engine = ScanEngine(ds, plan, rig, camera, time_scale=0.0, retries=0, auto_resume_poll_s=0.02, **kw)
    events = []
    engine.subscribe(events.append)
    return engine, ds, events


def paused_events(events):
    return [e for e in events if e.kind is EventKind.STATE and e.state is ScanState.PAUSED]


def test_disk_freed_after_full_resumes_by_itself_and_each_step_is_notified(tmp_path):
    receiver = Receiver()
    free = {"bytes": 10 * 2**30}
    engine, ds, events = make(tmp_path, auto_resume=2)
    engine.free_bytes_fn = lambda root: free["bytes"]
    notifier = Notifier([receiver.url()], dataset="day1")
    engine.subscribe(notifier.on_scan_event)
    waiting = threading.Event()

    def on(ev):
        if ev.kind is EventKind.VIEW_DONE and ev.done == 4:
            free["bytes"] = 5 * 2**20                 # the disk fills up
        if ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED:
            waiting.set()
    engine.subscribe(on)
    engine.start()
    assert waiting.wait(T)
    assert engine.resumes_by_itself and engine.state is ScanState.PAUSED
    assert "Disk almost full" in engine.message and f"resumes by itself when {CLEARS_DISK}" in engine.message
    assert paused_events(events)[0].extra["auto_resume"] == {"waiting_for": CLEARS_DISK, "next": 1, "of": 2}
    free["bytes"] = 10 * 2**30                        # someone freed space: no one presses Resume
    assert engine.wait(T) is ScanState.FINISHED, engine.message
    assert ds.status_counts()["done"] == 12 and engine.auto_resumed == 1
    resumed = [e for e in events if e.kind is EventKind.STATE and e.extra.get("auto_resumed")]
    assert len(resumed) == 1 and resumed[0].message.startswith("resumed by itself: there is free disk space again")
    notifier.close(30)
    receiver.close()
    import json
    bodies = [json.loads(p["body"]) for p in receiver.posts]
    assert [b["event"] for b in bodies] == ["started", "paused", "resumed", "finished"]
    assert bodies[1]["resumes_by_itself"] is True and "Disk almost full" in bodies[1]["message"]
    assert "resumed by itself" in bodies[2]["message"]


def test_at_most_n_times_then_it_waits_for_a_person(tmp_path):
    free = {"bytes": 10 * 2**30}
    engine, ds, events = make(tmp_path, auto_resume=1, cols=6, rows=2)
    engine.free_bytes_fn = lambda root: free["bytes"]
    pauses = threading.Semaphore(0)

    def on(ev):
        if ev.kind is EventKind.VIEW_DONE and ev.done in (3, 7):
            free["bytes"] = 5 * 2**20
        if ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED:
            pauses.release()
    engine.subscribe(on)
    engine.start()
    assert pauses.acquire(timeout=T)
    free["bytes"] = 10 * 2**30                        # clears: the one auto-resume is used
    assert pauses.acquire(timeout=T)                  # full again after view 7
    free["bytes"] = 10 * 2**30
    assert engine.state is ScanState.PAUSED and not engine.resumes_by_itself
    second = paused_events(events)[-1]
    assert "auto_resume" not in second.extra and "resumes by itself" not in second.message
    # freed, but no more auto-resumes: it stays paused until a person resumes (the engine thread would
    # have resumed within a poll; it waits for a request instead: a resume request is what ends it)
    assert not engine.wait_for_state(ScanState.RUNNING, timeout_s=0.5)
    engine.resume()
    assert engine.wait(T) is ScanState.FINISHED and engine.auto_resumed == 1


def test_camera_back_after_a_disconnect_resumes_by_itself(tmp_path):
    rig = InstantRig(RIG)
    camera = FlakyCamera(rig.true_position_mm, unplug_after=3)
    engine, ds, events = make(tmp_path, rig=rig, camera=camera, auto_resume=3)
    engine.start()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=T)
    assert engine.fault.device == "camera" and engine.fault.clears == CLEARS_CAMERA and engine.resumes_by_itself
    connects = camera.connects
    assert not engine.wait_for_state(ScanState.RUNNING, timeout_s=0.3)    # still unplugged: probes fail
    camera.plugged.set()                                                   # plugged back in
    assert engine.wait(T) is ScanState.FINISHED, engine.message
    assert camera.connects == connects + 1 and ds.status_counts()["done"] == 12 and engine.auto_resumed == 1


def test_controller_connection_lost_resumes_when_it_answers_again(tmp_path):
    rig = FaultyRig(RIG, ConnectionLost("connection to the rig on /dev/ttyUSB0 lost (Input/output error)"))
    engine, ds, events = make(tmp_path, rig=rig, auto_resume=1)
    engine.start()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=T)
    assert engine.fault.device == "rig" and engine.fault.clears == CLEARS_RIG and engine.resumes_by_itself
    rig.reconnectable.set()
    assert engine.wait(T) is ScanState.FINISHED, engine.message
    assert ds.status_counts()["done"] == 12


@pytest.mark.parametrize("fault", [GrblAlarm(1, "move to (10, 0) mm"), PositionError("not where it was sent"),
                                   DeviceError("move refused: the rig is alarm, not idle")],
                         ids=["limit-switch-alarm", "position-error", "refused"])
def test_alarms_limit_switches_and_position_errors_never_resume_by_themselves(tmp_path, fault):
    rig = FaultyRig(RIG, fault)
    engine, ds, events = make(tmp_path, rig=rig, auto_resume=5)
    engine.start()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=T)
    assert engine.fault.clears == "" and not engine.resumes_by_itself
    assert "auto_resume" not in paused_events(events)[-1].extra
    assert not engine.wait_for_state(ScanState.RUNNING, timeout_s=0.3)
    engine.abort()
    assert engine.wait(T) is ScanState.FINISHED and engine.auto_resumed == 0


def test_stop_never_resumes_by_itself(tmp_path):
    engine, ds, events = make(tmp_path, auto_resume=5)

    def on(ev):
        if ev.kind is EventKind.VIEW_DONE and ev.done == 2:
            engine.rig.stop_now()                     # STOP pressed
    engine.subscribe(on)
    engine.start()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=T)
    assert engine.message.startswith("STOP pressed") and not engine.resumes_by_itself
    assert not engine.wait_for_state(ScanState.RUNNING, timeout_s=0.3)
    engine.abort()
    assert engine.wait(T) is ScanState.FINISHED and engine.auto_resumed == 0


def test_a_controller_back_in_alarm_needs_a_person_and_says_so(tmp_path):
    """The connection comes back, but the controller restarted into ALARM (homing needed): the wait
    for the connection ends, and the pause now names the alarm and waits for a person."""
    rig = FaultyRig(RIG, ConnectionLost("connection to the rig on /dev/ttyUSB0 lost"))
    engine, ds, events = make(tmp_path, rig=rig, auto_resume=3)
    engine.start()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=T) and engine.resumes_by_itself
    alarm = threading.Event()
    engine.subscribe(lambda ev: ev.kind is EventKind.STATE and ev.extra.get("fault_changed") and alarm.set())
    rig.fault = GrblAlarm(1)                          # status reports ALARM from now on
    rig.reconnectable.set()
    assert alarm.wait(T)
    assert engine.state is ScanState.PAUSED and not engine.resumes_by_itself
    assert engine.message.startswith("Rig in alarm") and engine.auto_resumed == 0
    engine.abort()
    assert engine.wait(T) is ScanState.FINISHED
