"""The scan engine's state machine: the one transition table, requests refused from the wrong state
(never half-applied), requests from any thread applied by the engine thread, FAILED on any
unexpected exception (never a scan that hangs), and the rig interlock while a scan runs."""

from __future__ import annotations

import json
import threading

import pytest

from lfstudio.dataset import Dataset
from lfstudio.errors import DatasetError
from lfstudio.rig.profile import load_rig
from lfstudio.rig.worker import DeviceBusy, DeviceWorker
from lfstudio.scan.engine import ScanEngine
from lfstudio.studio.session import create_scan_dataset
from lfstudio.scan.events import (OWNS_RIG, REQUESTS, TERMINAL, TRANSITIONS, EventKind, ScanRequestRefused,
                                  ScanState, Trigger, allowed_requests, next_state)
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.sim.instant import InstantCamera, InstantRig

RIG = load_rig()
T = 30  # s; the waits end as soon as the condition holds


class HeldCamera(InstantCamera):
    """The instant camera, but each capture waits until the test lets it go (``release``)."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.entered = threading.Semaphore(0)
        self.gate = threading.Semaphore(0)

    def capture(self, stem_path, on_exposed=None):
        self.entered.release()
        assert self.gate.acquire(timeout=T), "the test never released the capture"
        return super().capture(stem_path, on_exposed)

    def release(self, n=1):
        for _ in range(n):
            self.gate.release()


@pytest.fixture
def make(tmp_path):
    made = []

    def make_engine(cols=3, rows=2, camera_cls=InstantCamera, name="ds", shared_rig=False, shared_camera=False, **kw):
        plan = ScanPlan.centered(cols, rows, (4.0, 6.0), RIG, settle_s=0.0)
        ds = create_scan_dataset(tmp_path / name, plan, rig={"name": RIG.name}, camera={"name": "instant"},
                                 lens={"name": "test", "focal_length_mm": 50.0})
        rig = InstantRig(RIG)
        rig.connect()
        cam = camera_cls(rig.true_position_mm)
        cam.connect()
        rig_device = DeviceWorker(rig, name="rig", publish_hz=20) if shared_rig else rig
        cam_device = DeviceWorker(cam, name="camera", publish_hz=20) if shared_camera else cam
        engine = ScanEngine(ds, plan, rig_device, cam_device, time_scale=0.0, **kw)
        events = []
        engine.subscribe(events.append)
        made.append((engine, cam, rig_device))
        if shared_camera:
            made.append((engine, cam, cam_device))
        return engine, ds, rig, cam, events, rig_device

    yield make_engine
    for engine, cam, rig_device in made:
        if isinstance(cam, HeldCamera):
            cam.release(100)
        engine.wait(T)
        if isinstance(rig_device, DeviceWorker):
            rig_device.close(disconnect=False)


def requests_of(engine):
    return {Trigger.START: engine.start, Trigger.PAUSE: engine.pause, Trigger.RESUME: engine.resume,
            Trigger.ABORT: engine.abort, Trigger.SKIP: lambda: engine.skip([(0, 0)]),
            Trigger.RECAPTURE: lambda: engine.recapture([(0, 0)])}


def assert_refuses_the_rest(engine, state):
    """Every request the table does not allow in ``state`` is refused, naming both, and changes nothing."""
    assert engine.state is state
    before = (engine.remaining, len(engine._inbox), engine.message, engine.aborted)
    refused = []
    for trigger, request in requests_of(engine).items():
        if trigger in TRANSITIONS[state]:
            continue
        with pytest.raises(ScanRequestRefused) as info:
            request()
        assert info.value.trigger is trigger and info.value.state is state
        assert info.value.kind == "request-refused"
        refused.append(trigger)
    assert engine.state is state
    assert (engine.remaining, len(engine._inbox), engine.message, engine.aborted) == before
    return refused


# -- the table ---------------------------------------------------------------------------------------
def test_the_transition_table_is_the_whole_state_machine():
    assert set(TRANSITIONS) == set(ScanState)
    for state in ScanState:
        for trigger in Trigger:
            if trigger in TRANSITIONS[state]:
                assert next_state(state, trigger) is TRANSITIONS[state][trigger]
            else:
                with pytest.raises(ScanRequestRefused) as info:
                    next_state(state, trigger)
                assert (info.value.state, info.value.trigger) == (state, trigger)
    # terminal states end everything; every other state can fail, and can reach the end
    for state in ScanState:
        assert (not TRANSITIONS[state]) == (state in TERMINAL)
        if state not in TERMINAL:
            assert TRANSITIONS[state][Trigger.CRASH] is ScanState.FAILED
    reachable, todo = {ScanState.IDLE}, [ScanState.IDLE]
    while todo:
        for nxt in TRANSITIONS[todo.pop()].values():
            if nxt not in reachable:
                reachable.add(nxt)
                todo.append(nxt)
    assert reachable == set(ScanState)
    for state in set(ScanState) - TERMINAL:
        seen, todo = {state}, [state]
        while todo:
            for nxt in TRANSITIONS[todo.pop()].values():
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        assert ScanState.FINISHED in seen, state
    # the operator's words for what is possible
    assert allowed_requests(ScanState.PAUSED) == [Trigger.RESUME, Trigger.ABORT, Trigger.SKIP, Trigger.RECAPTURE]
    assert "possible now: resume, abort, skip, recapture" in str(ScanRequestRefused(Trigger.PAUSE, ScanState.PAUSED))
    assert OWNS_RIG == {ScanState.RUNNING, ScanState.PAUSING, ScanState.STOPPING}


def test_a_live_engine_refuses_every_request_its_state_does_not_allow(make):
    engine, ds, rig, cam, events, _ = make(camera_cls=HeldCamera)
    refused = {ScanState.IDLE: assert_refuses_the_rest(engine, ScanState.IDLE)}
    assert refused[ScanState.IDLE] == [Trigger.RESUME]

    engine.start().result(T)
    assert cam.entered.acquire(timeout=T)                      # the first view is being exposed
    refused[ScanState.RUNNING] = assert_refuses_the_rest(engine, ScanState.RUNNING)
    assert engine.pause().result(T) is ScanState.PAUSING       # applied while the capture still runs
    refused[ScanState.PAUSING] = assert_refuses_the_rest(engine, ScanState.PAUSING)
    assert engine.abort().result(T) is ScanState.STOPPING
    refused[ScanState.STOPPING] = assert_refuses_the_rest(engine, ScanState.STOPPING)
    cam.release()
    assert engine.wait(T) is ScanState.FINISHED and engine.message.startswith("Aborted: 1 of 6")
    refused[ScanState.FINISHED] = assert_refuses_the_rest(engine, ScanState.FINISHED)
    assert engine.aborted and cam.captures == 1

    engine2, ds2, rig2, cam2, events2, _ = make(camera_cls=HeldCamera, name="ds2")
    engine2.start()
    assert cam2.entered.acquire(timeout=T)
    engine2.pause()
    cam2.release()
    assert engine2.wait_for_state(ScanState.PAUSED, timeout_s=T)
    refused[ScanState.PAUSED] = assert_refuses_the_rest(engine2, ScanState.PAUSED)
    assert engine2.resume().result(T) is ScanState.RUNNING
    cam2.release(5)
    assert engine2.wait(T) is ScanState.FINISHED and ds2.status_counts()["done"] == 6

    assert set(refused) == set(ScanState) - {ScanState.FAILED}      # FAILED: see the NaN test
    assert set(refused[ScanState.FINISHED]) == set(REQUESTS)


def test_requests_from_other_threads_are_applied_by_the_engine_thread(make):
    engine, ds, rig, cam, events, _ = make(camera_cls=HeldCamera)
    changed_on = []
    engine.subscribe(lambda ev: changed_on.append((ev.state, threading.current_thread().name))
                     if ev.kind is EventKind.STATE else None)
    engine.start()
    assert cam.entered.acquire(timeout=T)
    results = {}

    def from_another_thread():
        results["pause"] = engine.pause()
    helper = threading.Thread(target=from_another_thread, name="operator")
    helper.start()
    helper.join(T)
    assert results["pause"].result(T) is ScanState.PAUSING
    cam.release()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=T)
    assert cam.captures == 1                                  # paused after the view that was running

    # two requests queued together: the second no longer fits once the first is applied
    with engine._cond:                                        # hold the engine thread back for a moment
        aborting = engine.abort()
        resuming = engine.resume()                            # allowed now (paused) ...
    assert aborting.result(T) is ScanState.STOPPING
    with pytest.raises(ScanRequestRefused) as info:           # ... but not once stopping: refused, not applied
        resuming.result(T)
    assert info.value.state is ScanState.STOPPING and info.value.trigger is Trigger.RESUME
    assert info.value.kind == "request-refused"
    assert engine.wait(T) is ScanState.FINISHED and engine.message.startswith("Aborted")
    assert any(e.kind is EventKind.LOG and "resume refused" in e.message for e in events)
    states = [s for s, _ in changed_on]
    assert states == [ScanState.RUNNING, ScanState.PAUSING, ScanState.PAUSED, ScanState.STOPPING,
                      ScanState.FINISHED]
    assert {name for _, name in changed_on} == {"scan-engine"}
    assert cam.captures == 1 and ds.status_counts()["done"] == 1


def test_a_pause_before_the_start_lands_before_the_first_view(make):
    engine, ds, rig, cam, events, _ = make()
    paused = engine.pause()                                   # accepted while idle, applied once it runs
    assert engine.state is ScanState.IDLE and not paused.done()
    engine.start()
    assert paused.result(T) is ScanState.PAUSING
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=T) and cam.captures == 0
    engine.resume()
    assert engine.wait(T) is ScanState.FINISHED and cam.captures == 6


def test_a_listener_may_pause_and_resume_from_inside_its_callback(make):
    engine, ds, rig, cam, events, _ = make()
    seen = []

    def on(ev):
        if ev.kind is EventKind.VIEW_DONE and ev.done == 2 and not seen:
            seen.append(engine.pause())
        if ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED:
            seen.append(engine.resume())
    engine.subscribe(on)
    engine.start()
    assert engine.wait(T) is ScanState.FINISHED
    assert [f.result(T) for f in seen] == [ScanState.PAUSING, ScanState.RUNNING]
    assert ds.status_counts()["done"] == 6


# -- failures end in FAILED ----------------------------------------------------------------------------
def test_a_nan_in_a_resumed_dataset_fails_the_scan_before_the_rig_moves(make):
    engine, ds, rig, cam, events, _ = make()
    engine.skip([(1, 0), (1, 1), (1, 2)])          # a first run leaves three views to do
    engine.start()
    assert engine.wait(T) is ScanState.FINISHED
    manifest = json.loads(ds.manifest_path.read_text())
    manifest["lens"]["focal_length_mm"] = float("nan")
    for v in manifest["views"]:
        if v["status"] == "skipped":
            v["status"] = "pending"
    ds.manifest_path.write_text(json.dumps(manifest))          # json writes NaN; our writer refuses it
    with pytest.raises(DatasetError, match=r"lens\.focal_length_mm: not a finite number"):
        Dataset.open(ds.root)                                 # the loader refuses it, naming the field...
    manifest["lens"]["focal_length_mm"] = 50.0
    ds.manifest_path.write_text(json.dumps(manifest))
    resumed = Dataset.open(ds.root)
    resumed.lens["focal_length_mm"] = float("nan")            # ...and a NaN put there in memory fails the scan
    assert resumed.status_counts()["pending"] == 3
    again = ScanEngine(resumed, engine.plan, rig, cam, time_scale=0.0)
    moves_before = rig.true_position_mm()
    again.start()
    assert again.wait(T) is ScanState.FAILED                  # not a scan that never ends
    assert "lens.focal_length_mm" in again.message and "not a number" in again.message
    assert str(resumed.manifest_path) in again.message
    assert cam.captures == 3 and rig.true_position_mm() == moves_before
    assert Dataset.open(ds.root).verify_files() == []
    assert assert_refuses_the_rest(again, ScanState.FAILED) == list(requests_of(again))


def test_an_exception_in_the_engines_own_handlers_fails_the_scan(make, monkeypatch):
    engine, ds, rig, cam, events, rig_worker = make(shared_rig=True)
    record = ds.record_view

    def broken(row, column, **fields):
        if fields.get("status") == "skipped":
            raise RuntimeError("journal exploded")
        return record(row, column, **fields)
    monkeypatch.setattr(ds, "record_view", broken)

    def on(ev):
        if ev.kind is EventKind.VIEW_DONE and ev.done == 2:
            engine.skip()                                  # the next view: recording it raises
        raise ValueError("a broken listener is logged, it does not end the scan")
    engine.subscribe(on)
    engine.start()
    assert engine.wait(T) is ScanState.FAILED
    assert engine.message.startswith("Unexpected error: RuntimeError: journal exploded")
    assert "resume the scan" in engine.message
    assert rig_worker.holder is None                       # the rig is given back
    assert rig_worker.call("status").homed
    again = Dataset.open(ds.root)
    assert again.status_counts()["done"] >= 2 and again.verify_files() == []


# -- the rig interlock ---------------------------------------------------------------------------------
def test_while_a_scan_runs_other_motion_is_refused_naming_it_and_stop_pauses_it(make):
    engine, ds, rig, cam, events, rig_worker = make(camera_cls=HeldCamera, shared_rig=True)
    assert rig_worker.holder is None
    engine.start()
    assert cam.entered.acquire(timeout=T)
    assert engine.label.startswith(f"the scan of {ds.root.name} (started ")
    assert rig_worker.holder == engine.label
    where = rig.true_position_mm()
    for command, args in (("jog", (5.0, 0.0)), ("move_to", (10.0, 10.0)), ("home", ()), ("set_origin", ())):
        with pytest.raises(DeviceBusy) as info:
            rig_worker.call(command, *args)
        assert f"in use by {engine.label}" in str(info.value) and "STOP is always available" in str(info.value)
    assert rig.true_position_mm() == where

    rig_worker.stop_now()                                   # STOP is always accepted ...
    cam.release()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=T)   # ... and the scan does not move on
    assert engine.message.startswith("STOP pressed") and engine.fault.device == "rig"
    assert cam.captures == 1
    assert rig_worker.holder is None                        # paused: the operator has the rig back
    rig_worker.call("jog", 1.0, 0.0)
    rig_worker.call("home")

    engine.resume()
    cam.release(5)
    assert engine.wait(T) is ScanState.FINISHED, engine.message
    assert rig_worker.holder is None and ds.status_counts()["done"] == 6
    assert rig_worker.call("jog", 1.0, 0.0) is None


def second_dataset(first):
    """A 2 x 1 scan's plan and its new dataset beside ``first``."""
    plan = ScanPlan.centered(2, 1, (4.0, 6.0), RIG, settle_s=0.0)
    return plan, create_scan_dataset(first.root.parent / "second", plan, rig={"name": RIG.name},
                                     camera={"name": "i"}, lens={"name": "t"})


def test_while_a_scan_runs_the_camera_refuses_every_other_caller_naming_it(make, tmp_path):
    """The camera is leased like the rig: a test shot, a setting, a live-view frame from anybody else
    is refused naming the scan, never reaches the camera; it is free again when paused and at the end."""
    engine, ds, rig, cam, events, _ = make(camera_cls=HeldCamera, shared_camera=True)
    camera = engine.camera                                   # the worker the window shares with the scan
    assert camera.holder is None
    engine.start()
    assert cam.entered.acquire(timeout=T)                    # the scan's first capture is under way
    assert camera.holder == engine.label
    applied = []
    cam.set_setting = lambda name, value: applied.append((name, value))     # what reaches the camera
    for command, args in (("capture", (tmp_path / "test_shot",)), ("set_setting", ("iso", 3200)),
                          ("preview", ()), ("connect", ())):
        with pytest.raises(DeviceBusy) as info:
            camera.call(command, *args)
        assert f"camera: {command}(" in str(info.value) and f"in use by {engine.label}" in str(info.value)
    assert applied == [] and not list(tmp_path.glob("test_shot*"))

    engine.pause()
    cam.release()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=T)
    assert camera.holder is None and cam.captures == 1       # paused: the operator has the camera back
    camera.call("set_setting", "iso", 200)
    assert applied == [("iso", 200)]
    cam.release()
    assert camera.call("capture", tmp_path / "test_shot").path.is_file()
    assert cam.entered.acquire(timeout=T)                    # (that was the test shot's)

    engine.resume()
    assert cam.entered.acquire(timeout=T) and camera.holder == engine.label
    cam.release(10)
    assert engine.wait(T) is ScanState.FINISHED, engine.message
    assert camera.holder is None and ds.status_counts()["done"] == 6
    camera.call("set_setting", "iso", 400)                   # finished: free again
    assert applied == [("iso", 200), ("iso", 400)]


def test_a_second_scan_on_a_held_camera_pauses_naming_the_first_and_holds_neither_device(make):
    first, ds1, rig, cam, events, _ = make(camera_cls=HeldCamera, shared_camera=True)
    first.start()
    assert cam.entered.acquire(timeout=T)
    plan, ds2 = second_dataset(ds1)
    rig2 = InstantRig(RIG)
    rig2.connect()
    rig2_worker = DeviceWorker(rig2, name="rig", publish_hz=20)
    try:
        second = ScanEngine(ds2, plan, rig2_worker, first.camera, time_scale=0.0)
        second.start()
        assert second.wait_for_state(ScanState.PAUSED, timeout_s=T)
        assert second.message.startswith("Camera: cannot be taken by") and f"in use by {first.label}" in second.message
        assert second.fault.device == "camera" and rig2_worker.holder is None   # the rig it took is given back
        first.abort()
        cam.release(10)
        assert first.wait(T) is ScanState.FINISHED
        second.abort()
        assert second.wait(T) is ScanState.FINISHED and ds2.status_counts()["done"] == 0
    finally:
        rig2_worker.close(disconnect=False)


def test_a_second_scan_on_a_held_rig_pauses_naming_the_first(make):
    first, ds1, rig, cam, events, rig_worker = make(camera_cls=HeldCamera, shared_rig=True)
    first.start()
    assert cam.entered.acquire(timeout=T)
    plan, ds2 = second_dataset(ds1)
    cam2 = InstantCamera(rig.true_position_mm)
    cam2.connect()
    second = ScanEngine(ds2, plan, rig_worker, cam2, time_scale=0.0)
    second.start()
    assert second.wait_for_state(ScanState.PAUSED, timeout_s=T)
    assert f"in use by {first.label}" in second.message and cam2.captures == 0
    first.abort()
    cam.release(10)
    assert first.wait(T) is ScanState.FINISHED
    second.resume()
    assert second.wait(T) is ScanState.FINISHED and ds2.status_counts()["done"] == 2


class TransferHeldCamera(InstantCamera):
    """The instant camera whose exposure ends at once but whose transfer (the rest of the capture call)
    waits until the test lets it go: the next view's exposure waits for it."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.exposed = threading.Semaphore(0)
        self.gate = threading.Semaphore(0)

    def capture(self, stem_path, on_exposed=None):
        result = super().capture(stem_path, on_exposed)
        self.exposed.release()
        assert self.gate.acquire(timeout=T), "the test never released the transfer"
        return result

    def release(self, n=1):
        for _ in range(n):
            self.gate.release()


def test_stop_while_the_next_view_waits_for_the_camera_exposes_nothing_more(make):
    """STOP pressed after the rig reached the next view, while the engine waits for the previous
    view's transfer: before, that view was still exposed once the camera was free (one more exposure
    after STOP); now the scan pauses without it and the view is taken again after Resume."""
    engine, ds, rig, cam, events, rig_worker = make(camera_cls=TransferHeldCamera, shared_rig=True)
    second_started = threading.Event()
    engine.subscribe(lambda ev: second_started.set()
                     if ev.kind is EventKind.VIEW_STARTED and ev.index == 1 else None)
    engine.start()
    assert cam.exposed.acquire(timeout=T)             # view 1 exposed, its transfer held
    assert second_started.wait(T)                     # the engine is on to view 2
    rig_worker.stop_now()
    cam.release()                                     # view 1's transfer ends: the camera is free
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=T)
    assert cam.captures == 1, "an exposure after STOP"
    assert [ev.index for ev in events if ev.kind is EventKind.VIEW_EXPOSED] == [0]
    engine.resume()
    cam.release(10)
    assert engine.wait(T) is ScanState.FINISHED, engine.message
    assert ds.status_counts()["done"] == 6 and cam.captures == 6


def test_waiting_for_a_state_returns_after_the_listeners_had_its_event(make):
    """A caller of wait_for_state then reads what the listeners were told: the state is not seen before
    its STATE event has reached them (under load a waiter woke first and found no 'paused' event)."""
    engine, ds, rig, cam, events, _ = make(camera_cls=HeldCamera)
    in_listener, release = threading.Event(), threading.Event()

    def slow_listener(event):
        if event.kind is EventKind.STATE and event.state is ScanState.PAUSED:
            in_listener.set()
            release.wait(T)

    engine.subscribe(slow_listener)
    engine.start()
    assert cam.entered.acquire(timeout=T)
    engine.pause()
    cam.release()
    assert in_listener.wait(T)                         # the engine is PAUSED; its event is being delivered
    assert engine.state is ScanState.PAUSED
    assert not engine.wait_for_state(ScanState.PAUSED, timeout_s=0.2)   # not announced to everyone yet
    release.set()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=T)
    assert any(e.kind is EventKind.STATE and e.state is ScanState.PAUSED for e in events)
    engine.abort()
    cam.release(10)
    engine.wait(T)


def test_stop_while_resuming_pauses_as_the_operators_stop_not_as_a_lost_connection(make):
    """STOP pressed just after Resume, while the engine checks the rig after the pause: STOP cancels that
    check's status call, and the reconnect that followed was refused by the holding controller (GRBL's
    error 8): the scan paused on "Rig: reconnecting failed ... Check the cable and power" with an alarm.
    It pauses on the operator's STOP."""
    from lfstudio.errors import DeviceError

    engine, ds, rig, cam, events, rig_worker = make(camera_cls=HeldCamera, shared_rig=True)
    engine.start()
    assert cam.entered.acquire(timeout=T)
    rig_worker.stop_now()
    cam.release()
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=T) and engine.fault.stop_pressed
    real_status = rig.status

    def status_while_stop_is_pressed():           # the recovery's status call, and STOP meanwhile
        rig.status = real_status
        rig_worker.stop_soon()
        raise DeviceError("cancelled by STOP")

    def refused_connect():
        raise DeviceError("controller refused '$I': error 8, '$' command only valid when the controller is Idle")
    rig.status, rig.connect = status_while_stop_is_pressed, refused_connect
    assert engine.resume().result(timeout=T) is ScanState.RUNNING
    assert engine.wait_for_state(ScanState.PAUSED, timeout_s=T)
    assert engine.fault is not None and engine.fault.stop_pressed, engine.fault
    assert "reconnecting failed" not in engine.message
    assert cam.captures == 1                       # nothing more was taken
    engine.abort()
