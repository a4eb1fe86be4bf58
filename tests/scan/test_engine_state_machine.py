"""The scan engine under any order of the operator's requests (pause, resume, abort, skip,
re-capture) with camera faults injected, as a hypothesis state machine: every state change the
listeners see is one of the transition table's, every refusal names a state that does not allow the
request, and no view is lost or taken twice (instant simulated rig, a camera the test steps)."""

from __future__ import annotations

import shutil
import tempfile
import threading
from collections import Counter
from pathlib import Path

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from lfstudio.errors import DeviceError
from lfstudio.rig.profile import load_rig
from lfstudio.scan.engine import ScanEngine
from lfstudio.scan.events import TERMINAL, TRANSITIONS, EventKind, ScanRequestRefused, ScanState
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.sim.instant import InstantCamera, InstantRig
from lfstudio.studio.session import create_scan_dataset

RIG = load_rig()
T = 30            # s; every wait ends as soon as its condition holds
COLS, ROWS = 3, 2
CELLS = [(r, c) for r in range(ROWS) for c in range(COLS)]


class SteppedCamera(InstantCamera):
    """The instant camera, but each capture waits for the test's ``step`` and may fail on request."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.gate = threading.Semaphore(0)
        self.fail_next = threading.Event()

    def capture(self, stem_path, on_exposed=None):
        assert self.gate.acquire(timeout=T), "the test never let the capture go"
        if self.fail_next.is_set():
            self.fail_next.clear()
            raise DeviceError("camera: capture failed: injected by the test")
        return super().capture(stem_path, on_exposed)


class EngineRequests(RuleBasedStateMachine):
    def __init__(self):
        super().__init__()
        self.tmp = Path(tempfile.mkdtemp(prefix="lfstudio-sm-"))
        plan = ScanPlan.centered(COLS, ROWS, (4.0, 6.0), RIG, settle_s=0.0)
        self.ds = create_scan_dataset(self.tmp / "ds", plan, rig={"name": RIG.name}, camera={"name": "instant"},
                                      lens={"name": "test", "focal_length_mm": 50.0})
        rig = InstantRig(RIG)
        rig.connect()
        self.camera = SteppedCamera(rig.true_position_mm)
        self.camera.connect()
        self.engine = ScanEngine(self.ds, plan, rig, self.camera, time_scale=0.0, retries=1)
        self.events = []
        self.engine.subscribe(self.events.append)
        self.requests = []                # (kind, future)
        self.recaptured = Counter()       # cell -> re-capture requests that named it
        self.engine.start()

    def _request(self, kind, call, *args) -> bool:
        """Make a request; a refusal at once must name a state the table does not allow it in."""
        try:
            self.requests.append((kind, call(*args)))
            return True
        except ScanRequestRefused as exc:
            assert exc.trigger not in TRANSITIONS[exc.state], (kind, exc.state)
            return False

    @rule()
    def pause(self):
        self._request("pause", self.engine.pause)

    @rule()
    def resume(self):
        self._request("resume", self.engine.resume)

    @rule(cells=st.lists(st.sampled_from(CELLS), min_size=1, max_size=2, unique=True))
    def skip(self, cells):
        self._request("skip", self.engine.skip, cells)

    @rule(cells=st.lists(st.sampled_from(CELLS), min_size=1, max_size=2, unique=True))
    def recapture(self, cells):
        if self._request("recapture", self.engine.recapture, cells):
            for cell in cells:
                self.recaptured[cell] += 1

    @rule(n=st.integers(1, 3))
    def let_captures_go(self, n):
        for _ in range(n):
            self.camera.gate.release()

    @rule()
    def camera_fails_once(self):
        self.camera.fail_next.set()

    @precondition(lambda self: len(self.requests) > 4)
    @rule()
    def abort(self):
        self._request("abort", self.engine.abort)

    @invariant()
    def every_state_change_is_in_the_table(self):
        states = [e.state for e in list(self.events) if e.kind is EventKind.STATE]
        for before, after in zip([ScanState.IDLE] + states, states):
            assert before == after or after in TRANSITIONS[before].values(), (before, after, states)

    def teardown(self):
        try:
            self._request("abort", self.engine.abort)
            self.camera.gate.release(1000)
            for _ in range(3):                    # a fault may pause it before the abort is applied
                if self.engine.wait(T) in TERMINAL:
                    break
                self._request("abort", self.engine.abort)
            assert self.engine.state is ScanState.FINISHED, self.engine.message
            for kind, future in self.requests:
                exc = future.exception(timeout=T)
                if exc is not None:
                    assert isinstance(exc, ScanRequestRefused), (kind, exc)
                    assert exc.trigger not in TRANSITIONS[exc.state], (kind, exc.state)
            done_events = Counter((e.row, e.column) for e in self.events if e.kind is EventKind.VIEW_DONE)
            for cell, times in done_events.items():       # never taken twice unless asked again
                assert times <= 1 + self.recaptured[cell], (cell, times, self.recaptured[cell])
            ds = type(self.ds).open(self.ds.root)
            for cell in done_events:                       # nothing taken is lost
                view = ds.view(*cell)
                if self.recaptured[cell] == 0:
                    assert view["status"] == "done", (cell, view["status"])
                if view["status"] == "done":
                    assert ds.path_of(view).is_file(), cell
            assert sum(1 for c in CELLS if ds.view(*c)["status"] == "done") == ds.status_counts()["done"]
        finally:
            shutil.rmtree(self.tmp, ignore_errors=True)


TestEngineRequests = EngineRequests.TestCase
TestEngineRequests.settings = settings(max_examples=25, stateful_step_count=15, deadline=None,
                                       suppress_health_check=[HealthCheck.too_slow])
