"""gui/bridge.py: items posted from other threads reach the GUI thread in order, batched; a job's
reports arrive as signals on the GUI thread, exactly one final signal."""

from __future__ import annotations

import threading

from PySide6.QtCore import QThread

from lfstudio.errors import InputError
from lfstudio.gui.bridge import GuiInbox, JobRunner, run_off_gui


def test_inbox_delivers_every_item_in_order_on_the_gui_thread_in_few_batches(qtbot, qapp):
    batches: list[list] = []
    threads_seen: set = set()

    def handle(items: list) -> None:
        threads_seen.add(QThread.currentThread())
        batches.append(items)

    inbox = GuiInbox(handle)
    n_threads, per_thread = 4, 500
    go = threading.Event()

    def producer(k: int) -> None:
        go.wait()
        for i in range(per_thread):
            inbox.post((k, i))

    workers = [threading.Thread(target=producer, args=(k,)) for k in range(n_threads)]
    for w in workers:
        w.start()
    go.set()
    for w in workers:
        w.join()
    qtbot.waitUntil(lambda: sum(len(b) for b in batches) == n_threads * per_thread)
    assert threads_seen == {qapp.thread()}
    items = [x for b in batches for x in b]
    for k in range(n_threads):
        assert [i for kk, i in items if kk == k] == list(range(per_thread))     # each thread's order kept
    # the GUI thread was busy (joining) while all was posted: one wake-up, one batch
    assert len(batches) == 1
    inbox.close()
    inbox.post(("late", 0))
    qapp.processEvents()
    assert ("late", 0) not in [x for b in batches for x in b]


def test_job_runner_reports_progress_then_one_final_signal(qtbot):
    runner = JobRunner()
    seen: list = []
    runner.progress.connect(lambda d, t, m, eta: seen.append(("progress", d, t, m)))

    def job(n, *, progress, cancel):
        for i in range(n):
            progress(i + 1, n, f"step {i + 1}")
        return n * 10

    with qtbot.waitSignal(runner.finished) as blocker:
        runner.start(job, 3)
    assert blocker.args == [30]
    assert seen == [("progress", i, 3, f"step {i}") for i in (1, 2, 3)]
    assert not runner.running

    with qtbot.waitSignal(runner.failed) as blocker:
        runner.start(lambda *, progress, cancel: (_ for _ in ()).throw(InputError("views", "none chosen")))
    assert "views" in blocker.args[0] and "none chosen" in blocker.args[0]

    stop = threading.Event()

    def waits(*, progress, cancel):
        while not stop.wait(0.01):
            cancel.check()
        raise AssertionError("not cancelled")

    with qtbot.waitSignal(runner.cancelled):
        runner.start(waits)
        runner.cancel()
    stop.set()
    assert runner.wait(5)


def test_run_off_gui_hands_the_value_to_the_gui_thread(qtbot, qapp):
    got: list = []
    runner = run_off_gui(None, lambda: threading.current_thread().name, lambda v: got.append((v, QThread.currentThread())))
    qtbot.waitUntil(lambda: bool(got))
    assert got[0][0].startswith("job-") and got[0][1] is qapp.thread()
    assert runner.wait(5)
