"""The camera's card as the buffer (``lfstudio scan --keep-on-card``): capture without waiting for the
download; fetch the files during the row changes and at the end.

:class:`CardBufferEngine` is the scan engine (:class:`lfstudio.scan.engine.ScanEngine`) with a camera
that keeps its pictures on its card (:class:`lfstudio.rig.camera.CardBuffered`, e.g. gphoto2 bodies
whose capture target can be the card). Per view: move, settle, ``capture_to_card``; the rig moves on as
soon as the camera reports the shutter closed (its ``on_exposed``), not when the call returns (a body is
still writing the picture to its card), and the paths of its files on the camera are journaled as soon
as the call returns, on the camera's worker (the view's ``on_card``; it is not done yet). When the next view is on another row (the rig moves to it meanwhile),
at a pause, an abort and at the end, the files of every view taken since are downloaded on the camera's
worker (``download_from_card``: size checked, deleted on the card; at a row change only as many as
fit into the vertical move and the settle at the transfer time measured, the others at the end, so the
downloads never hold up the captures) and the store stage checksums and
journals each view as usual: a view is done only when its file is on disk and verified. A download
that fails makes the store take the view again. A run that ended before its downloads (kill -9, a
pulled cable) leaves ``on_card`` in the journal: the next run with ``--keep-on-card`` fetches those
files first, and takes again the views whose files are no longer there. A capture refused because the
card is full (the camera says so) downloads every picture waiting on the card first, then takes that
view again: a full card costs time, never a view.
"""

from __future__ import annotations

import logging
import threading
import time
from concurrent.futures import Future
from dataclasses import replace
from pathlib import Path
from typing import Any

from lfstudio.dataset.manifest import is_finished
from lfstudio.dataset.paths import view_label, view_stem
from lfstudio.rig.camera import CardBuffered
from lfstudio.scan.engine import ScanEngine
from lfstudio.scan.events import EventKind
from lfstudio.scan.faults import error_text
from lfstudio.scan.scan_plan import PlannedView
from lfstudio.scan.store import StoreJob

log = logging.getLogger(__name__)


def card_problem(camera: Any) -> str | None:
    """Why ``camera`` (a driver or its worker) cannot keep its pictures on its card, or None."""
    driver = getattr(camera, "driver", camera)
    if isinstance(driver, CardBuffered):
        return None
    return (f"the camera ({getattr(driver, 'name', type(driver).__name__)}) cannot keep its pictures on its card "
            "and download them later (gphoto2 cameras can)")


def _card_full(exc: BaseException) -> bool:
    """Whether a failed capture says the camera's card (or its buffer) is full (gphoto2's -115 / -3, the
    simulated card)."""
    return "is full" in str(exc) or "card is full" in error_text(exc)


class _OnCard(Future):
    """A view's capture: ``done()`` as soon as its files are on the card (the camera may take the next
    picture), its result (the downloaded files) once they are downloaded."""

    def __init__(self) -> None:
        super().__init__()
        self.on_card = True

    def done(self) -> bool:
        return self.on_card or super().done()


class _Captured:
    """A picture taken to the card: its view, its store future, and its files once the call returned."""

    def __init__(self, view: PlannedView, stem: Path) -> None:
        self.view = view
        self.stem = stem
        self.pending = _OnCard()
        self.files: list[str] = []
        self.exposed = threading.Event()       # the shutter has closed: the rig may move
        self.returned = threading.Event()      # the capture call has ended (files journaled, or failed)


class CardBufferEngine(ScanEngine):
    """See the module docstring."""

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self._on_card: list[_Captured] = []
        self._card_ready = False
        self.fetched_on_resume = 0
        self.downloads = 0
        self._transfer_s: list[float] = []     # measured download times (simulated seconds on a simulator)
        # the store stage takes a view once its download has begun (it holds at most two pictures: one
        # waiting on a file still on the card would hold up the scan)
        self._held: dict[int, StoreJob] = {}
        submit = self.store.submit

        def hold_on_card(job: StoreJob) -> None:
            if isinstance(job.future, _OnCard) and job.future.on_card:
                self._held[id(job.future)] = job
            else:
                submit(job)

        self._submit_to_store = submit
        self.store.submit = hold_on_card      # type: ignore[method-assign]

    def _loop(self) -> None:
        if not self._card_ready:
            self._card_ready = True
            where = self._camera_call("keep_on_card", timeout_s=30)
            self._emit(EventKind.LOG, f"pictures stay on the camera's card ({where}); downloaded at the row "
                                      "changes and at the end")
            self._fetch_left_on_card()
        super()._loop()

    def _fetch_left_on_card(self) -> None:
        """Views an earlier run left on the card (journaled, never downloaded): fetched first."""
        for record in list(self.dataset.views):
            files = record.get("on_card")
            if not files or is_finished(record):
                continue
            cell = (record["row"], record["column"])
            view = next((v for v in self._queue if v.cell == cell), None)
            if view is None:
                continue
            stem = self.dataset.root / "raw" / view_stem(*cell)
            try:
                result = self._camera_call("download_from_card", list(files), stem,
                                           timeout_s=self.capture_call_timeout_s() + 60)
            except Exception as exc:
                self._emit(EventKind.LOG, f"view {view_label(*cell)}: its files on the card could not be fetched "
                                          f"({error_text(exc)}); taken again")
                continue
            self._queue.remove(view)
            done: Future = Future()
            done.set_result(replace(result, record={**(result.record or {}), "on_card": []}))
            self.store.submit(StoreJob(view, 1, done, time.monotonic(), None, {"fetched_on_resume": 1.0}))
            self.fetched_on_resume += 1
            self._emit(EventKind.LOG, f"view {view_label(*cell)}: fetched from the card, where the last run left it")

    def _expose(self, view: PlannedView, attempt: int, stem: Path) -> Future:
        """Trigger the picture and return as soon as the shutter has closed (the camera's ``on_exposed``),
        so the rig moves on while the camera finishes the capture call (a body writes the picture to its
        card; gphoto2 lists the files it added). The files' paths are journaled (``on_card``) when the call
        returns, on the camera's worker; the view is done only once its file is downloaded and verified."""
        fut, captured = self._capture_to_card(view, stem)
        if not captured.exposed.is_set():      # the call ended before the shutter closed: it failed
            try:
                fut.result()
            except Exception as exc:           # a failed capture raises here: retried as any capture
                if not self._on_card or not _card_full(exc):
                    raise
                self._emit(EventKind.LOG, f"the camera's card is full: downloading the {len(self._on_card)} "
                                          f"pictures waiting on it now, then view {view_label(view.row, view.column)} "
                                          "again")
                self._download_all()           # on the camera's worker, before the capture queued next
                fut, captured = self._capture_to_card(view, stem)
                if not captured.exposed.is_set():
                    fut.result()               # raises its error
        self._on_card.append(captured)
        return captured.pending

    def _capture_to_card(self, view: PlannedView, stem: Path) -> tuple[Future, "_Captured"]:
        """Submit ``capture_to_card`` and wait until the shutter has closed or the call ended."""
        captured = _Captured(view, Path(stem))

        def on_exposed(*_: Any) -> None:
            captured.exposed.set()
            self._wake()

        def on_returned(f: Future) -> None:    # the camera's worker: the picture is on the card
            try:
                files = list(f.result())
            except BaseException as exc:  # noqa: BLE001 - the store takes the view again
                captured.pending.on_card = False
                captured.pending.set_exception(exc)
            else:
                try:
                    self.dataset.record_view(view.row, view.column, on_card=files)   # durable before the download
                except Exception as exc:       # the download still makes the view done; a kill would retake it
                    log.warning("view %s: its files on the card not journaled: %s",
                                view_label(view.row, view.column), error_text(exc))
                captured.files = files
            finally:
                captured.returned.set()
                self._wake()

        fut = self._camera_submit("capture_to_card", stem, on_exposed=on_exposed,
                                  timeout_s=self.capture_call_timeout_s())
        fut.add_done_callback(on_returned)
        self._wait(lambda: captured.exposed.is_set() or captured.returned.is_set())
        return fut, captured

    def _next_view(self) -> PlannedView | None:
        view = super()._next_view()
        if view is None:
            self._download_all()
        elif self._on_card and view.row != self._on_card[-1].view.row:
            self._download_all(self._fit_in_row_change())     # the rig moves to the next row meanwhile
        return view

    def _fit_in_row_change(self) -> int:
        """How many downloads fit into a row change (the vertical move and the settle) at the transfer
        time measured so far (one while none is known): the rest waits for the end, so that the
        downloads never hold up the captures (the camera takes one call at a time)."""
        if not self._transfer_s:
            return 1
        from lfstudio.optics import move_time_s

        v = self.rig.driver.config.vertical
        change_s = move_time_s(self.plan.spacing_mm[1], v.max_speed_mm_s, v.acceleration_mm_s2) + self.plan.settle_s
        mean = sum(self._transfer_s) / len(self._transfer_s)
        return len(self._on_card) if mean <= 0 else int(change_s / mean)

    def _drain_store(self) -> None:
        self._download_all()                   # a pause, an abort, the end: nothing stays behind on the card
        super()._drain_store()

    def _download_all(self, at_most: int | None = None) -> None:
        if at_most is None:
            pending, self._on_card = self._on_card, []
        else:
            pending, self._on_card = self._on_card[:at_most], self._on_card[at_most:]
        for captured in pending:
            self._wait(captured.returned.is_set)     # the capture call has returned (its files are known)
            out = captured.pending
            if not out.on_card:                      # the capture failed after the shutter closed
                job = self._held.pop(id(out), None)
                if job is not None:
                    self._submit_to_store(job)       # the store takes the view again
                continue
            real = self._camera_submit("download_from_card", captured.files, captured.stem,
                                       timeout_s=self.capture_call_timeout_s() + 60)
            self.downloads += 1

            def chain(f: Future, out: _OnCard = out) -> None:
                try:
                    result = f.result()
                except BaseException as exc:  # noqa: BLE001 - the store takes the view again
                    out.on_card = False
                    out.set_exception(exc)
                    return
                out.on_card = False
                self._transfer_s.append(float(result.transfer_s) / max(self.time_scale, 1e-9)
                                        if self.time_scale > 0 else float(result.transfer_s))
                out.set_result(replace(result, record={**(result.record or {}), "on_card": []}))

            real.add_done_callback(chain)
            job = self._held.pop(id(out), None)
            if job is not None:
                self._submit_to_store(job)
