"""DeviceWorker: order, timeouts, STOP bypass, rate-bounded snapshots, any driver."""

from __future__ import annotations

import threading
import time

import pytest

from lfstudio.errors import DeviceError
from lfstudio.rig.worker import DeviceBusy, DeviceFault, DeviceWorker


class Recorder:
    """A plain synchronous driver that records what ran on which thread."""

    def __init__(self):
        self.log: list[tuple[str, object]] = []
        self.threads: set[str] = set()
        self.release = threading.Event()
        self.entered = threading.Event()
        self.stopped = threading.Event()
        self.stop_thread: str | None = None
        self.polls = 0
        self.fail_status = False

    def do(self, value):
        self.threads.add(threading.current_thread().name)
        self.log.append(("do", value))
        return value * 2

    def block(self):
        self.entered.set()
        self.release.wait(10)
        self.log.append(("block", None))
        return "released"

    def boom(self):
        raise DeviceError("axis X: cable unplugged")

    def stop(self):
        self.stop_thread = threading.current_thread().name
        self.stopped.set()
        self.release.set()

    def status(self):
        self.polls += 1
        if self.fail_status:
            raise DeviceError("no answer")
        return {"polls": self.polls}


@pytest.fixture
def worker():
    driver = Recorder()
    w = DeviceWorker(driver, name="rec", publish_hz=20)
    yield w
    driver.release.set()
    w.close()


def test_calls_run_in_order_on_one_thread(worker):
    futures = [worker.submit("do", i) for i in range(50)]
    assert [f.result(5) for f in futures] == [2 * i for i in range(50)]
    assert [v for k, v in worker.driver.log] == list(range(50))
    assert worker.driver.threads == {"device-rec"}
    assert worker.call(lambda a, b=0: a + b, 3, b=4) == 7


def test_driver_errors_reach_the_future(worker):
    with pytest.raises(DeviceError, match="cable unplugged"):
        worker.call("boom")
    assert worker.call("do", 1) == 2  # the worker survives
    with pytest.raises(AttributeError, match="no command 'fly'"):
        worker.submit("fly")


def test_timeout_fails_future_naming_command_and_queue_moves_on_after_return(worker):
    slow = worker.submit("block", timeout_s=0.05)
    after = worker.submit("do", 21)
    with pytest.raises(DeviceError) as exc:
        slow.result(5)
    assert exc.value.kind == "call-timed-out" and "block()" in str(exc.value)     # names the command
    assert not after.done()  # the driver has not returned yet: the queue waits
    worker.driver.release.set()
    assert after.result(5) == 42
    assert worker.driver.log == [("block", None), ("do", 21)]


def test_calls_with_a_timeout_start_no_thread_each(worker, monkeypatch):
    """Timeouts (and held-back snapshots) run on one shared thread: a scan makes thousands of calls."""
    assert worker.call("do", 0, timeout_s=5) == 0          # the shared thread runs from here on
    started: list[str] = []
    real_start = threading.Thread.start
    monkeypatch.setattr(threading.Thread, "start", lambda self: (started.append(self.name), real_start(self))[1])
    assert [worker.call("do", i, timeout_s=5) for i in range(40)] == [2 * i for i in range(40)]
    assert started == []
    slow = worker.submit("block", timeout_s=0.05)            # and a timeout still fails its call
    with pytest.raises(DeviceError) as exc:
        slow.result(5)
    assert exc.value.kind == "call-timed-out"
    worker.driver.release.set()
    assert started == []


def test_stop_now_bypasses_queue_and_drops_queued_calls(worker):
    running = worker.submit("block")
    assert worker.driver.entered.wait(5)
    queued = [worker.submit("do", i) for i in range(3)]
    worker.stop_now()
    assert worker.driver.stop_thread == threading.current_thread().name
    assert running.result(5) == "released"
    for f in queued:
        with pytest.raises(DeviceError, match="cancelled by STOP"):
            f.result(5)
    assert ("do", 0) not in worker.driver.log
    assert worker.call("do", 5) == 10  # usable again after STOP


def test_snapshots_are_rate_bounded_and_polled_while_idle():
    driver = Recorder()
    w = DeviceWorker(driver, name="rate", publish_hz=10)
    times: list[float] = []
    got = threading.Event()

    def on_snapshot(snapshot):
        times.append(time.monotonic())
        if len(times) >= 4:
            got.set()
    w.subscribe(on_snapshot)
    # a driver pushing snapshots far faster than the bound
    for i in range(2000):
        w._offer({"pushed": i})
    assert got.wait(5)
    w.close()
    gaps = [b - a for a, b in zip(times, times[1:])]
    assert min(gaps) >= 0.1 - 0.01   # never faster than publish_hz
    assert driver.polls >= 1         # idle polling happened


def test_failing_status_publishes_generic_fault():
    driver = Recorder()
    driver.fail_status = True
    w = DeviceWorker(driver, name="flaky", publish_hz=50)
    seen = []
    ev = threading.Event()
    w.subscribe(lambda s: (seen.append(s), ev.set()))
    assert ev.wait(5)
    w.close()
    assert isinstance(seen[0], DeviceFault) and "no answer" in seen[0].message and seen[0].device == "flaky"


def test_status_listener_hook_and_close():
    class Pushing:
        status_listener = None

        def work(self):
            for i in range(3):
                self.status_listener({"step": i})
            return "done"

        def disconnect(self):
            self.disconnected = True

    driver = Pushing()
    w = DeviceWorker(driver, name="push", status_method=None, publish_hz=1000)
    seen = []
    w.subscribe(seen.append)
    assert w.call("work") == "done"
    assert {"step": 0} in seen
    w.close()
    assert driver.disconnected and driver.status_listener is None
    with pytest.raises(DeviceError, match="closed"):
        w.call("work")


def test_snapshot_held_by_the_rate_bound_is_published_during_a_long_call():
    """A status pushed right after another (inside the rate window) must not wait for the call to end."""
    seen_last = threading.Event()

    class Slow:
        status_listener = None

        def long_call(self):
            self.status_listener({"step": "first"})
            self.status_listener({"step": "camera does not answer"})   # inside the 0.1 s window
            return seen_last.wait(10)      # still inside the call: was the second one published?

    w = DeviceWorker(Slow(), name="slow", status_method=None, publish_hz=10)
    w.subscribe(lambda s: s.get("step") == "camera does not answer" and seen_last.set())
    try:
        assert w.call("long_call") is True
    finally:
        w.close()


def test_a_claimed_worker_refuses_everybody_else_but_never_stop(worker):
    stops = []
    lease = worker.claim("the scan of day1 (started 14:02)", on_stop=lambda: stops.append(worker.driver.stopped.is_set()))
    assert worker.holder == "the scan of day1 (started 14:02)"
    refused = worker.submit("do", 1)
    with pytest.raises(DeviceBusy) as info:
        refused.result(5)
    text = str(info.value)
    assert "do(1) refused" in text and "in use by the scan of day1 (started 14:02)" in text
    assert "STOP is always available" in text and info.value.holder == "the scan of day1 (started 14:02)"
    assert ("do", 1) not in worker.driver.log                 # never reached the driver
    with pytest.raises(DeviceBusy, match="in use by the scan of day1"):
        worker.claim("a second scan")
    assert lease.call("do", 2) == 4                           # the holder's calls run

    running = lease.submit("block")
    assert worker.driver.entered.wait(5)
    worker.stop_now()                                         # STOP from anybody, while claimed
    assert running.result(5) == "released" and worker.driver.stopped.is_set()
    assert stops == [False]                                   # the holder heard of it before the driver stopped

    lease.release()
    assert worker.holder is None and worker.call("do", 3) == 6
    with pytest.raises(DeviceError, match="released"):
        lease.call("do", 4)
    with worker.claim("another owner") as again:              # claimable again; a context manager releases
        assert again.call("do", 5) == 10
    assert worker.holder is None


def test_calls_accepted_before_a_claim_still_run_in_order(worker):
    running = worker.submit("block")
    assert worker.driver.entered.wait(5)
    queued = worker.submit("do", 7)
    lease = worker.claim("a scan")
    mine = lease.submit("do", 8)
    worker.driver.release.set()
    assert running.result(5) == "released" and queued.result(5) == 14 and mine.result(5) == 16
    assert [k for k, _ in worker.driver.log] == ["block", "do", "do"]
    lease.release()


class _SpyLock:
    """A lock that counts the attempts to take it (so a test can hold a caller at it, no sleeps)."""

    def __init__(self):
        self.lock = threading.Lock()
        self.cond = threading.Condition()
        self.attempts = 0

    def __enter__(self):
        with self.cond:
            self.attempts += 1
            self.cond.notify_all()
        self.lock.acquire()
        return self

    def __exit__(self, *exc):
        self.lock.release()


def test_a_call_queued_while_the_worker_closes_fails_instead_of_hanging():
    """_closed was set and read outside the lock: a call that passed the check while close() ran was
    queued behind _CLOSE, never run nor failed, and call() without a timeout blocked forever."""
    from concurrent.futures import TimeoutError as FutureTimeout

    worker = DeviceWorker(Recorder(), name="rig", publish_hz=50)
    spy = worker._lease_lock = _SpyLock()
    spy.lock.acquire()                                   # the submit below waits at the lease lock
    futures = []
    submitter = threading.Thread(target=lambda: futures.append(worker.submit("do", 21)))
    submitter.start()
    with spy.cond:
        assert spy.cond.wait_for(lambda: spy.attempts >= 1, 10)
    closer = threading.Thread(target=worker.close)
    closer.start()
    with spy.cond:                                       # close() now takes the lock too (or, before, ran past)
        spy.cond.wait_for(lambda: spy.attempts >= 2 or not closer.is_alive(), 10)
    spy.lock.release()
    submitter.join(10)
    closer.join(10)
    try:
        futures[0].result(timeout=10)                    # ran before the close, or refused: never pending
    except DeviceError:
        pass
    except FutureTimeout:
        pytest.fail("the call queued during close() was never run nor failed")
