"""The scan's store stage: each captured view's file on disk, checksummed, thumbnailed and journaled.

:class:`ScanStore` owns the **store thread** and its state (the views in flight, the largest view
stored so far, the frames of a bracketed view stored so far, the views the journal refused). The
engine thread hands it each capture (:meth:`ScanStore.submit`, a :class:`StoreJob` whose future
resolves when the camera has delivered the file) and goes on moving the rig; the store thread waits
for the file (download/transfer; an array camera's frame it writes itself: Bayer as DNG, mono and
RGB as 16-bit PNG, :func:`lfstudio.rig.camera.stored`), checksums it, writes its thumbnail and journals the view (fsync'd),
overlapping the next move and settle.

The store talks to the engine only through the engine's inbox (``post``: a fault to pause on, a view
to capture again, its own crash) and a counter (:attr:`ScanStore.inflight`, the views handed over and
not yet stored; ``wake`` tells the engine it changed), besides the scan's events (``emit``). Disk
faults (full, read-only, failing) and free space are the store's: the engine asks it before each view
(:meth:`check_disk`) and when an error may be the disk's (:meth:`disk_fault`).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import traceback
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from lfstudio.dataset import Dataset
from lfstudio.dataset.manifest import FrameRecord, ViewUpdate, is_done, now_iso
from lfstudio.dataset.paths import view_label, view_stem
from lfstudio.dataset.storage import disk_problem, megabytes, mount_point, storage_error
from lfstudio.dataset.store import free_bytes, sha256_file
from lfstudio.dataset.thumbs import THUMB_WIDTH_PX, make_thumbnail
from lfstudio.errors import DeviceError, DeviceTimeout, LfError
from lfstudio.rig.camera import CaptureResult, HasCardSpace
from lfstudio.rig.camera import stored as frame_written
from lfstudio.rig.worker import CallTimedOut, DeviceWorker
from lfstudio.scan.events import EventKind, Trigger
from lfstudio.scan.faults import CLEARS_CAMERA, CLEARS_DISK, ScanFault, error_text, fault_text
from lfstudio.scan.preflight import MIN_FREE_BYTES, ViewSize, disk_shortfall, floor_bytes
from lfstudio.scan.scan_plan import PlannedView

log = logging.getLogger(__name__)

#: the engine's inbox: a view whose transfer failed, to capture again (posted by the store thread)
RETRY = "retry"
_STOP = object()


@dataclass
class StoreJob:
    """One picture in flight from the engine thread to the store thread."""

    view: PlannedView
    attempt: int
    future: Future                       # resolves to the camera's CaptureResult (the file delivered)
    exposed_at: float
    reported_mm: list[float] | None
    timings_s: dict[str, float] = field(default_factory=dict)
    frame: int | None = None             # an exposure bracket's frame (0-based; None: no bracket)
    frames: int = 1                      # the view's frames
    shutter_s: float | None = None       # the shutter time the engine set for this frame
    reference_frame: int = 0             # a bracket's frame that is the view's file


def free_hung_camera(camera: DeviceWorker, exc: BaseException | None = None) -> None:
    """A capture that timed out (``exc`` a :class:`CallTimedOut`, or None: any) may still hang in
    the driver: stop it so the camera is usable."""
    if exc is not None and not isinstance(exc, CallTimedOut):
        return
    if camera.current_command == "capture":
        try:
            camera.stop_now()
        except Exception as exc:
            log.debug("stopping the camera: %s", exc)


def reported_exposure_s(result: CaptureResult) -> float | None:
    """The shutter time the camera reported for a shot (its metadata), else how long it exposed."""
    meta = result.metadata if isinstance(result.metadata, dict) else {}
    exposure = meta.get("shutter_s") or meta.get("exposure_s") or result.exposure_s
    return float(exposure) if exposure else None


def stored_view_bytes(dataset: Dataset, sample: int = 8) -> int:
    """Bytes of the largest of the last ``sample`` views stored in ``dataset`` (file, sidecars, thumbnail)."""
    done = dataset.done_views()[-sample:]
    largest = 0
    for v in done:
        total = 0
        frames = [rel for f in (v.get("frames") or ()) if isinstance(f, dict)
                  for rel in (f.get("file"), *(f.get("sidecars") or ())) if rel != v.get("file")]
        for rel in (v.get("file"), *(v.get("sidecars") or ()), v.get("thumb"), *frames):
            try:
                total += dataset.path_of(rel).stat().st_size if rel else 0
            except (OSError, LfError):
                pass
        largest = max(largest, total)
    return largest


class ScanStore:
    """The store stage of a scan of ``dataset`` whose pictures ``camera`` (its worker) delivers.

    ``post(kind, payload)``: the engine's inbox (``Trigger.FAULT`` with ``(fault, view or None)``,
    :data:`RETRY` with a view, ``Trigger.CRASH`` with the exception); ``wake()``: the engine looks at
    :attr:`inflight` again; ``emit(kind, message, **fields)``: a scan event to the listeners;
    ``eta_s()``: the engine's estimate for VIEW_DONE events; ``silent(view, exc)``: the fault of a
    camera that stopped answering; ``remaining()``: the views still to capture in this run. ``retries``: a failed transfer is captured again while its
    attempt is at most this; a view needs ``2 x`` the largest stored view (and a manifest copy),
    at least ``min_free_bytes``, free on the disk (``free_bytes_fn``) before it is taken."""

    def __init__(self, dataset: Dataset, camera: DeviceWorker, *, post: Callable[[Trigger | str, Any], None],
                 wake: Callable[[], None], emit: Callable[..., Any], eta_s: Callable[[], float | None],
                 silent: Callable[[PlannedView, BaseException], ScanFault], remaining: Callable[[], int],
                 retries: int = 2, min_free_bytes: int = MIN_FREE_BYTES, thumb_width_px: int = THUMB_WIDTH_PX,
                 checkpoint_s: float = 5.0, free_bytes_fn: Callable[[Path], int] = free_bytes):
        self.dataset = dataset
        self.camera = camera
        self._post, self._wake, self._emit, self._eta_s, self._silent = post, wake, emit, eta_s, silent
        self._remaining = remaining
        self.retries = retries
        self.min_free_bytes = int(min_free_bytes)
        self.thumb_width_px = int(thumb_width_px)
        self.checkpoint_s = float(checkpoint_s)
        self.free_bytes_fn = free_bytes_fn
        self._lock = threading.Lock()
        self._queue: queue.Queue = queue.Queue(maxsize=2)
        self._thread: threading.Thread | None = None
        # shared with the engine thread (under _lock)
        self._inflight = 0
        self.done = len(dataset.done_views())     # views done in the dataset
        self.captured_this_run = 0
        self._unrecorded: list[tuple[PlannedView, ViewUpdate]] = []   # stored, journal refused (disk)
        self._view_bytes = stored_view_bytes(dataset)   # the largest view stored so far (file, sidecars, thumb)
        self._dropping = False           # the camera was stopped for an abort: failed transfers are dropped
        self._card_frame_bytes: int | None = None   # measured on the first view: the camera's card is checked next
        # the store thread's own
        self._whole_checked = False     # the views left checked against the free space (after the first view)
        self._last_done_t: float | None = None
        self._last_save = time.monotonic()
        self._frames_of: dict[tuple[int, int], tuple[int, list[FrameRecord]]] = {}
        self._failed_attempts: set[tuple[tuple[int, int], int]] = set()
        self._frame_results: dict[tuple[tuple[int, int], int], CaptureResult] = {}

    # -- the engine thread's side ------------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._loop, name="scan-store", daemon=True)
        self._thread.start()

    def close(self, timeout_s: float = 30) -> None:
        """Let the store thread finish what it holds and end (at most ``timeout_s``)."""
        self._queue.put(_STOP)
        if self._thread is not None:
            self._thread.join(timeout_s)

    def submit(self, job: StoreJob) -> None:
        """Hand a picture over (blocks while two wait already: the camera is far ahead of the disk)."""
        with self._lock:
            self._inflight += 1
        self._queue.put(job)

    @property
    def inflight(self) -> int:
        """Pictures handed over and not yet stored (the engine waits for 0 at its checkpoints)."""
        return self._inflight

    @property
    def unrecorded(self) -> int:
        """Views stored whose journal line the disk refused (journaled on Resume, not captured again)."""
        return len(self._unrecorded)

    def drop_transfers(self) -> None:
        """abort(grace_s) stopped the camera: a transfer that fails from now on is dropped (its view is
        taken on resume), not failed."""
        with self._lock:
            self._dropping = True

    def record_kept(self) -> None:
        """On Resume (engine thread, nothing in flight): journal the views the disk refused to record;
        raises the fault when it refuses again (the rest stay kept)."""
        with self._lock:
            kept, self._unrecorded = self._unrecorded, []
        for i, (view, fields) in enumerate(kept):
            refused = self.record(view, fields)
            if refused is not None:
                with self._lock:
                    self._unrecorded[:0] = kept[i:]
                raise refused
            self._emit(EventKind.VIEW_DONE, "recorded after the disk fault (kept meanwhile)", index=view.index,
                       row=view.row, column=view.column, eta_s=self._eta_s(), timings_s=fields.get("timings_s", {}),
                       file=fields.get("file"), thumb=fields.get("thumb"))

    def save(self) -> None:
        """Rewrite the manifest (the journal keeps every view when it cannot)."""
        try:
            self.dataset.save()
        except OSError as exc:
            self._emit(EventKind.LOG, f"saving {self.dataset.manifest_path} failed ({exc}); "
                                      "the journal keeps every captured view")
        self._last_save = time.monotonic()

    def repair_thumbnails(self) -> None:
        """Thumbnails of captured views a full disk kept from being written (the views are kept)."""
        missing = [v for v in self.dataset.done_views() if not v.get("thumb")]
        for v in missing:
            rel = f"thumbs/{view_stem(v['row'], v['column'])}.jpg"
            try:
                files = [self.dataset.path_of(f) for f in (v, *(v.get("sidecars") or ()))]
                if make_thumbnail(files, self.dataset.root / rel, self.thumb_width_px) is not None:
                    self.dataset.record_view(v["row"], v["column"], thumb=rel)
            except Exception as exc:       # a thumbnail is a convenience: the scan goes on without it
                log.info("thumbnail of %s not made: %s", v.get("file"), exc)

    # -- disk --------------------------------------------------------------------------------------
    def need_bytes(self) -> int:
        """Free space the next view needs: room for two views at the size of the largest stored so far
        (its file, sidecars and thumbnail) plus a copy of the manifest (a save writes a whole new one);
        at least ``min_free_bytes``."""
        try:
            manifest = self.dataset.manifest_path.stat().st_size
        except OSError:
            manifest = 0
        return floor_bytes(self._view_bytes, manifest, self.min_free_bytes)

    def has_room(self, need_bytes: int = 0) -> bool:
        """Whether the disk has room for the next view, and ``need_bytes`` (a disk fault's: auto-resume)."""
        return self.free_bytes_fn(self.dataset.root) >= max(self.need_bytes(), need_bytes)

    def whole_scan_fault(self, view_bytes: int, frames: int) -> ScanFault | None:
        """The pause when the views still to capture, at ``view_bytes`` each (measured on the view just
        stored), do not fit the free space (:func:`lfstudio.scan.preflight.disk_shortfall`); it clears
        when the disk has that much free. Checked once a run, right after its first view is stored: a
        Resume after it goes on (and pauses again only when the disk is really full)."""
        views = self._remaining()
        try:
            free = self.free_bytes_fn(self.dataset.root)
            manifest = self.dataset.manifest_path.stat().st_size
        except OSError as exc:
            log.info("free space not checked after the first view: %s", exc)
            return None
        short = disk_shortfall(self.dataset.root, views, ViewSize(view_bytes, "measured on the first view stored",
                                                                  frames),
                               free, min_free_bytes=self.min_free_bytes, manifest_bytes=manifest)
        if short is None:
            return None
        return ScanFault(f"{short} Then Resume (Resume now captures what fits and pauses when the disk is full).",
                         "disk", CLEARS_DISK, need_bytes=short.need_bytes)

    def take_card_frame_bytes(self) -> int | None:
        """A frame's bytes measured on this run's first view, once, when the camera keeps its pictures
        on a card (the engine thread then checks the card: ``ScanEngine._check_card``); else None."""
        with self._lock:
            frame_bytes, self._card_frame_bytes = self._card_frame_bytes, None
        return frame_bytes

    def check_disk(self) -> None:
        """Raise the fault to pause on when the disk has not room for the next view."""
        need = self.need_bytes()
        try:
            free = self.free_bytes_fn(self.dataset.root)
        except OSError as exc:
            raise ScanFault(f"Disk: cannot check free space in {self.dataset.root}: {exc}.", "disk") from None
        if free < need:
            per_view = f"a view takes about {megabytes(self._view_bytes)} here" if self._view_bytes else \
                "no view captured yet"
            raise ScanFault(f"Disk almost full: {megabytes(free)} free on the disk at {mount_point(self.dataset.root)}; "
                            f"{megabytes(need)} needed to go on ({per_view}). Free disk space, then Resume.", "disk",
                            CLEARS_DISK)

    def disk_fault(self, exc: BaseException, folder: Path, doing: str) -> ScanFault | None:
        """The disk fault ``exc`` stands for: a storage error, or a device error while the disk cannot
        take the write (read-only, not writable, full) — a device is never blamed for the disk."""
        problem = storage_error(exc, doing=doing, need_bytes=self.need_bytes(), at=folder)
        if problem is None and isinstance(exc, (DeviceError, OSError)) and not isinstance(exc, DeviceTimeout):
            problem = disk_problem(folder if folder.is_dir() else self.dataset.root, min(self.need_bytes(), 2**20))
        if problem is None:
            return None
        return ScanFault(str(problem), "disk", CLEARS_DISK if getattr(problem, "kind", "") == "full" else "")

    # -- the store thread --------------------------------------------------------------------------
    def _loop(self) -> None:
        try:
            while True:
                job = self._queue.get()
                if job is _STOP:
                    return
                try:
                    self._store(job)
                except Exception as exc:
                    log.info("storing a view failed:\n%s", traceback.format_exc())   # the fault says it
                    where = view_label(job.view.row, job.view.column)
                    fault = self.disk_fault(exc, self.dataset.root / "raw", f"storing view {where}") or \
                        ScanFault(f"Storing view {where} failed: {error_text(exc)}.", "disk")
                    self._failed(job, fault)
                finally:
                    with self._lock:
                        self._inflight -= 1
                    self._wake()
        except BaseException as exc:  # the store stage itself broke: the engine thread fails the scan
            self._post(Trigger.CRASH, exc)

    def _failed(self, job: StoreJob | None, fault: ScanFault) -> None:
        """Pause on ``fault``; ``job``'s view is captured again (None: it is kept, nothing to redo)."""
        self._post(Trigger.FAULT, (fault, None if job is None else job.view))

    def _transfer_failed(self, job: StoreJob, exc: Exception) -> None:
        """The camera did not deliver ``job``'s file: retry the view, or pause on the camera's (or the
        disk's) fault; dropped after an abort's stop."""
        view = job.view
        if job.frame is not None:
            self._failed_attempts.add((view.cell, job.attempt))
        if self._dropping:      # abort(grace_s) stopped the camera: not captured, taken on resume
            self._emit(EventKind.LOG, f"view r{view.row:02d} c{view.column:03d}: its transfer was cut short "
                                      "by the stop; not captured (taken when the scan resumes)")
            return
        free_hung_camera(self.camera, exc)
        message = error_text(exc)
        disk = self.disk_fault(exc, self.dataset.root / "raw", f"storing view {view_label(view.row, view.column)}")
        if disk is not None:          # the view is captured again after Resume (its file never arrived)
            self._failed(job, disk)
            return
        will_retry = job.attempt <= self.retries and not isinstance(exc, DeviceTimeout)
        if isinstance(exc, DeviceTimeout):
            self._emit(EventKind.VIEW_FAILED, message, index=view.index, row=view.row, column=view.column,
                       will_retry=False, extra={"attempt": job.attempt, "device": "camera"})
            self._failed(job, self._silent(view, exc))
            return
        self._emit(EventKind.VIEW_FAILED, message, index=view.index, row=view.row, column=view.column,
                   will_retry=will_retry, extra={"attempt": job.attempt, "device": "camera"})
        if will_retry:
            self._post(RETRY, view)
        else:
            self._failed(job, ScanFault(fault_text("camera", message, job.attempt), "camera", CLEARS_CAMERA))

    def _store(self, job: StoreJob) -> None:
        view = job.view
        if job.frame == 0:     # a new take of the view: a Resume starts the attempt numbers again, so an
            self._failed_attempts.discard((view.cell, job.attempt))   # earlier take's failure is not this one's
        if job.frame is not None and (view.cell, job.attempt) in self._failed_attempts:
            return             # an earlier frame of this attempt failed: the view is taken again whole
        try:
            result: CaptureResult = job.future.result()
        except Exception as exc:
            self._transfer_failed(job, exc)
            return
        result = frame_written(result)    # an array camera's frame written here (DNG or 16-bit PNG)
        t_transferred = time.monotonic()
        extra: ViewUpdate = {}
        sha: str | None = None
        view_bytes = 0
        if job.frame is not None:
            stored = self._store_frame(job, job.frame, result)
            if stored is None:
                return                           # not the view's last frame: journaled as a frame
            result, extra, sha, view_bytes = stored   # the reference frame is the view's file
        path = Path(result.path).resolve()
        rel = path.relative_to(self.dataset.root).as_posix()
        sha = sha or sha256_file(path)
        view_bytes += sum(Path(f).stat().st_size for f in result.files if Path(f).is_file())
        thumb_rel = f"thumbs/{view_stem(view.row, view.column)}.jpg"
        preview = result.metadata.get("preview") if isinstance(result.metadata, dict) else None
        later: ScanFault | None = None        # a disk fault after the capture is safe: recorded, then pause
        try:
            thumb = make_thumbnail(result.files, self.dataset.root / thumb_rel, self.thumb_width_px, preview)
            view_bytes += thumb.stat().st_size if thumb is not None else 0
        except Exception as exc:
            log.info("thumbnail of %s failed: %s", rel, exc)
            thumb = None                      # made again when the scan resumes (repair_thumbnails)
            later = self.disk_fault(exc, self.dataset.root / "thumbs", f"writing the thumbnail of {rel}")
        self._view_bytes = max(self._view_bytes, view_bytes)
        timings = dict(job.timings_s)
        timings["transfer"] = t_transferred - job.exposed_at
        now = time.monotonic()
        timings["store"] = now - t_transferred
        if self._last_done_t is not None:
            timings["period"] = now - self._last_done_t
        self._last_done_t = now
        fields: ViewUpdate = {"status": "done", "file": rel, "sha256": sha, "captured_at": now_iso(),
                  "exposure_s": reported_exposure_s(result),
                  "commanded_mm": [view.x_mm, view.y_mm], "reported_mm": job.reported_mm,
                  "thumb": thumb_rel if thumb is not None else None, "attempts": job.attempt,
                  "timings_s": {k: round(v, 4) for k, v in timings.items()}}
        sidecars = [Path(f).resolve().relative_to(self.dataset.root).as_posix() for f in result.files[1:]]
        if sidecars:
            fields["sidecars"] = sidecars
        driver: ViewUpdate = getattr(result, "record", None) or {}     # the driver's extras (camera, its settings)
        fields = {**driver, **fields, **extra}
        refused = self.record(view, fields)
        if refused is not None:
            with self._lock:
                self._unrecorded.append((view, fields))
            self._failed(None, refused)
            return
        if later is None and time.monotonic() - self._last_save > self.checkpoint_s:
            try:
                self.dataset.checkpoint()      # journal-first: the manifest is rewritten only now and then
            except Exception as exc:              # the journal holds the view: it is kept whatever happens here
                later = self.disk_fault(exc, self.dataset.root, f"saving {self.dataset.manifest_path.name}") or \
                    ScanFault(f"Saving {self.dataset.manifest_path} failed: {error_text(exc)}.", "disk")
            self._last_save = time.monotonic()
        frames = [{k: f.get(k) for k in ("index", "file", "exposure_s", "shutter_s")} for f in fields.get("frames") or ()]
        self._emit(EventKind.VIEW_DONE, index=view.index, row=view.row, column=view.column, eta_s=self._eta_s(),
                   timings_s=timings, file=rel, thumb=fields.get("thumb"), extra={"frames": frames} if frames else {})
        if later is None and not self._whole_checked:     # the first view of this run: does the rest fit?
            self._whole_checked = True
            later = self.whole_scan_fault(view_bytes, job.frames)
            if isinstance(self.camera.driver, HasCardSpace):
                with self._lock:
                    self._card_frame_bytes = max(1, view_bytes // max(1, job.frames))
        if later is not None:
            self._failed(None, later)

    def _store_frame(self, job: StoreJob, frame_no: int, result: CaptureResult
                     ) -> tuple[CaptureResult, ViewUpdate, str | None, int] | None:
        """Store frame ``frame_no`` (``job.frame``) of a bracketed view (store thread): checksum it and
        journal the view's frames so far (the view stays not done). For the last frame: (the reference
        frame's result, the view's ``frames`` and ``reference_frame`` fields, the reference frame's
        sha256, the bytes of the other frames) for the view's done record."""
        view = job.view
        cell = view.cell
        attempt, frames = self._frames_of.get(cell, (None, []))
        if attempt != job.attempt or frame_no == 0:
            frames = []                          # a new attempt takes every frame again
        self._frames_of[cell] = (job.attempt, frames)
        path = Path(result.path).resolve()
        root = self.dataset.root
        frame: FrameRecord = {"index": frame_no, "file": path.relative_to(root).as_posix(),
                              "sha256": sha256_file(path), "shutter_s": job.shutter_s,
                              "exposure_s": reported_exposure_s(result), "captured_at": now_iso()}
        sidecars = [Path(f).resolve().relative_to(root).as_posix() for f in result.files[1:]]
        if sidecars:
            frame["sidecars"] = sidecars
        settings = (getattr(result, "record", None) or {}).get("camera_settings")
        if isinstance(settings, dict):
            frame["camera_settings"] = settings
        taken = (getattr(result, "record", None) or {}).get("camera_frame")
        if isinstance(taken, dict):
            frame["camera_frame"] = taken
        frames.append(frame)
        self._frame_results[(cell, frame_no)] = result
        if frame_no < job.frames - 1:
            fields: ViewUpdate = {"frames": [f.copy() for f in frames]}
            # a done view taken again (re-capture): its first new frame has replaced a file of its
            # record, so the record no longer holds; it is pending until all its new frames are in
            # (a failure or a crash now leaves it to be taken again, never 'done' with one frame)
            demoted = frame_no == 0 and is_done(self.dataset.view(view.row, view.column))
            if demoted:
                fields["status"] = "pending"
            try:
                self.dataset.record_view(view.row, view.column, **fields)
                if demoted:
                    with self._lock:
                        self.done -= 1
            except Exception as exc:              # the view is not done: its frames are taken again
                self._failed_attempts.add((cell, job.attempt))
                fault = self.disk_fault(exc, root, f"recording a frame of view {view_label(view.row, view.column)}") \
                    or ScanFault(f"Recording a frame of view {view_label(view.row, view.column)} failed: "
                                 f"{error_text(exc)}.", "disk")
                self._failed(job, fault)
            return None
        self._frames_of.pop(cell, None)
        indices = [f["index"] for f in frames]
        if indices != list(range(job.frames)):    # cannot happen: frames arrive in order, a failure stops the rest
            raise LfError(f"view {view_label(view.row, view.column)}: frames {indices} stored, "
                          f"{job.frames} expected; the view is taken again")
        ref_index = job.reference_frame
        results = [self._frame_results.pop((cell, i), None) for i in range(job.frames)]
        ref = results[ref_index] or result
        others = sum(Path(f).stat().st_size for i, r in enumerate(results) if r is not None and i != ref_index
                     for f in r.files if Path(f).is_file())
        return ref, {"frames": [f.copy() for f in frames], "reference_frame": ref_index}, \
            frames[ref_index].get("sha256"), others

    def record(self, view: PlannedView, fields: ViewUpdate) -> ScanFault | None:
        """Journal a stored view (store thread, or the engine thread on Resume); the fault when the
        journal cannot be written. Such a view is kept in memory with its files (``_unrecorded``) and
        journaled on Resume, not captured again; the scan pauses on the fault meanwhile."""
        was_done = is_done(self.dataset.view(view.row, view.column))
        try:
            self.dataset.record_view(view.row, view.column, **fields)
        except Exception as exc:
            return self.disk_fault(exc, self.dataset.root, f"recording view {view_label(view.row, view.column)} "
                                   "in the journal") or \
                ScanFault(f"Recording view {view_label(view.row, view.column)} failed: {error_text(exc)}.", "disk")
        with self._lock:
            if not was_done:                   # a view captured again (recapture) still counts once
                self.done += 1
            self.captured_this_run += 1
        return None
