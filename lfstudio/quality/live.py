"""Scan-time checking: judge each view as the scan captures it, on a thread of its own.

``LiveChecker(dataset)`` listens to the scan engine's events (``engine.subscribe(checker.on_event)``,
see :mod:`lfstudio.scan.events`): a ``view-done`` event only puts the view on a queue, so the scan
never waits for the check. The checker's thread (at a lower CPU priority where the system allows it)
decodes the view, compares its focus and brightness with the neighbours captured before it, tracks
it into them and locates it with the neighbours around it (:class:`lfstudio.quality.check.GridCheck`,
the same measurements as ``lfstudio check``), then tells its listeners the view's verdict at once.

Verdicts can change as neighbours arrive (the first view of a scan has nothing to be compared with
yet): every listener call carries the view's current ``quality.json``-style entry, and views whose
verdict changed are published again. A new view is located against the neighbours already located;
when a row is complete (and on :meth:`LiveChecker.settle`, e.g. when the scan ends) every view so
far is located together, as ``lfstudio check`` does, which keeps small errors from adding up. Listeners run on the checker's thread; a GUI posts them to
its own thread. :meth:`LiveChecker.document` returns what has been judged so far in the layout of
``quality.json`` (no dataset-wide figures: those come from the full check after the scan).

:class:`LiveCheckerProcess` runs a ``LiveChecker`` in a process of its own with the same inputs and
outputs, for the GUI: a checker thread in the GUI's process holds the GIL for most of its work (small
numpy calls, Python bookkeeping), and the GUI thread waits for it; in a process of its own the checker
shares only the cores (at a lower priority, where it no longer makes every thread wait for it).
"""

from __future__ import annotations

import itertools
import logging
import multiprocessing
import os
import queue
import threading
from multiprocessing.process import BaseProcess
from typing import Any, Callable

import numpy as np

from lfstudio.dataset.manifest import FrameRecord
from lfstudio.dataset.paths import resolve_inside
from lfstudio.errors import LfError
from lfstudio.quality import verdicts
from lfstudio.quality.check import RING, Geometry, GridCheck, PositionFit, calibration_homography
from lfstudio.quality.measure import DEFAULT_WORK_WIDTH_PX, bracket_frames, measure_view, with_frames
from lfstudio.quality.positions import robust_affine
from lfstudio.quality.tracks import WINDOW
from lfstudio.quality.verdicts import Thresholds
from lfstudio.support.listeners import Listeners

log = logging.getLogger(__name__)

Cell = tuple[int, int]     # a grid cell (row, column); a dataset View is one
Listener = Callable[[dict[str, Any]], None]
_SETTLE = object()             # queue item: solve every view checked so far
#: views kept with their working image: this many rows around the newest view
KEEP_ROWS = 2
MIN_LOCATED = 4        # views a free local position solve needs before it judges positions
MIN_ANCHORS = 2        # located neighbours that anchor a new view's position


class _Published:
    """What a live check publishes (:class:`LiveChecker`, :class:`LiveCheckerProcess`): ``results``,
    the entry of every view judged, and the listeners told of each new or changed one. Subclasses
    set ``results`` and ``_lock`` (which guards ``results``)."""

    results: dict[Cell, dict[str, Any]]
    _lock: threading.Lock
    _listeners: Listeners[dict[str, Any]]

    def subscribe(self, listener: Listener) -> Callable[[], None]:
        """Call ``listener(entry)`` for each new or changed view verdict (on the checker's thread,
        or a LiveCheckerProcess's reader thread)."""
        return self._listeners.add(listener)

    def flagged(self) -> dict[Cell, dict[str, Any]]:
        with self._lock:
            return {c: e for c, e in self.results.items() if e["verdict"] in (verdicts.WARN, verdicts.FAIL)}

    def _publish(self, entries: list[dict[str, Any]]) -> None:
        for entry in entries:
            self._listeners.notify(entry)


class LiveChecker(_Published):
    """Checks views of ``dataset`` as they arrive (see the module docstring)."""

    def __init__(self, dataset, *, thresholds: Thresholds | None = None,
                 work_width_px: int = DEFAULT_WORK_WIDTH_PX, lower_priority: bool = True):
        self.dataset = dataset
        self.work_width_px = int(work_width_px)
        H, size, _doc = calibration_homography(dataset)
        self.grid = GridCheck(Geometry.from_dataset(dataset), thresholds, homography_full=H, calibration_size_px=size)
        self.results: dict[Cell, dict[str, Any]] = {}
        self.errors: dict[Cell, str] = {}
        # where each located view stood, in the frame of the first views (mm), and the robust affine
        # map from the commanded positions into that frame
        self.measured_mm: dict[Cell, tuple[float, float]] = {}
        self._residual_px: dict[Cell, float | None] = {}
        self._tracks: dict[Cell, int] = {}
        self._frame = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
        self._last_row: int | None = None
        self._solved = 0               # views in the last solve of all views
        self._listeners = Listeners("live quality listener", log)
        self._lock = threading.Lock()
        self._queue: queue.Queue = queue.Queue()
        self._pending = 0
        self._idle = threading.Condition(self._lock)
        self._lower = lower_priority
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="quality-live", daemon=True)
        self._thread.start()

    # -- inputs (any thread, never blocking) ---------------------------------------------------------
    def on_event(self, event: Any) -> None:
        """A scan engine listener: queue each finished view."""
        view = _view_done(event)
        if view is not None:
            self.submit(*view)

    def submit(self, row: int, column: int, file: str | None = None, frames: list[FrameRecord] | None = None) -> None:
        """Queue view (``row``, ``column``) (``file``: relative to the dataset; default: the manifest's;
        ``frames``: an exposure bracket's frame records, as the view-done event tells them; default:
        the manifest's)."""
        with self._lock:
            self._pending += 1
        self._queue.put((int(row), int(column), file, frames))

    def settle(self) -> None:
        """Queue a solve of every view checked so far (as at each new row): the final positions after
        a scan. Does not wait (:meth:`wait_idle` does)."""
        with self._lock:
            self._pending += 1
        self._queue.put(_SETTLE)

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Block until every queued view is judged (True) or ``timeout_s`` passed (False)."""
        with self._idle:
            return self._idle.wait_for(lambda: self._pending == 0, timeout_s)

    def close(self, timeout_s: float | None = 10.0, drain: bool = True) -> None:
        """Stop the thread after the views already queued (``drain``) or after the current one,
        dropping the rest; join it up to ``timeout_s`` (0: do not wait)."""
        if not drain:
            self._stop.set()
        self._queue.put(None)
        if timeout_s != 0:
            self._thread.join(timeout_s)

    # -- results --------------------------------------------------------------------------------------
    def document(self) -> dict[str, Any]:
        """The views judged so far, in the layout of ``quality.json``."""
        with self._lock:
            views = [dict(self.results[c]) for c in sorted(self.results)]
        return live_document(self.header(), views)

    def header(self) -> dict[str, Any]:
        """What :meth:`document` says besides the views: the grid and the thresholds."""
        t = self.grid.thresholds
        g = self.grid.geometry
        warn, fail = t.position_limits_mm(g.repeatability_um, g.spacing_mm)
        return {"grid": {"columns": g.columns, "rows": g.rows},
                "thresholds": {**t.as_dict(), "position_warn_mm": warn, "position_fail_mm": fail}}

    # -- the checker's thread ---------------------------------------------------------------------------
    def _run(self) -> None:
        if self._lower and hasattr(os, "setpriority"):
            try:   # Linux: a thread's id is a process id for setpriority; the scan keeps its CPU share
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 10)
            except (OSError, AttributeError):
                pass
        while True:
            item = self._queue.get()
            if item is None:
                return
            if self._stop.is_set():
                with self._idle:
                    self._pending -= 1
                    self._idle.notify_all()
                continue
            if item is _SETTLE:
                try:
                    self._resolve_all()
                except Exception:
                    log.exception("live check: solving all views failed")
                finally:
                    with self._idle:
                        self._pending -= 1
                        self._idle.notify_all()
                continue
            row, column, file, frames = item
            try:
                if self._last_row is not None and row != self._last_row:
                    self._resolve_all()            # a row is complete: locate every view together
                self._last_row = row
                self._check((row, column), file, frames)
            except LfError as exc:
                self.errors[(row, column)] = str(exc)
                log.warning("live check of row %d, column %d: %s", row, column, exc)
            except Exception:   # a bug must not stop the checks of the next views
                log.exception("live check of row %d, column %d failed", row, column)
            finally:
                with self._idle:
                    self._pending -= 1
                    self._idle.notify_all()

    def _resolve_all(self) -> None:
        """Solve every view checked so far together (like ``lfstudio check``), take the positions as
        the new anchors and publish the verdicts this changes."""
        cells = sorted(self.grid.measures)
        if len(cells) < MIN_LOCATED or len(cells) == self._solved:
            return
        self._solved = len(cells)
        fit = self.grid.solve(cells)
        if len(fit.error_mm) < MIN_LOCATED:
            return
        self.measured_mm = {c: fit.measured_mm[c] for c in fit.error_mm}
        self._residual_px = {c: fit.residual_rms_px.get(c) for c in fit.error_mm}
        self._tracks = {c: fit.tracks.get(c, 0) for c in fit.error_mm}
        self._refit_frame()
        self._publish(self._rejudge(sorted(self.results)))

    def _rejudge(self, cells) -> list[dict[str, Any]]:
        """Judge ``cells`` again with the current positions; the entries whose verdict changed."""
        located = self._located(cells)
        typical_px = self._typical_residual()
        changed = []
        for c in cells:
            old = self.results.get(c)
            if old is None or c not in self.grid.measures:
                continue
            entry = self.grid.judge_view(c, located, typical_px, self.grid.geometry.near_m)
            entry["file"] = old.get("file")
            with self._lock:
                self.results[c] = entry
            if entry["verdict"] != old["verdict"] or entry["reasons"] != old["reasons"]:
                changed.append(entry)
        return changed

    def _typical_residual(self) -> float | None:
        values = sorted(v for v in self._residual_px.values() if v is not None)
        return values[len(values) // 2] if values else None

    def _refit_frame(self) -> None:
        cells = sorted(self.measured_mm)
        cmd = np.array([self.grid.geometry.commanded_mm[c] for c in cells], float)
        meas = np.array([self.measured_mm[c] for c in cells], float)
        self._frame, _ = robust_affine(cmd, meas)

    def _located(self, cells) -> PositionFit:
        """The position figures of the located ``cells``: errors in the commanded frame."""
        A = self._frame
        errors, measured = {}, {}
        for c in cells:
            if c in self.measured_mm:
                p = np.asarray(self.measured_mm[c], float)
                back = np.linalg.solve(A[:, :2], p - A[:, 2])
                cmd = self.grid.geometry.commanded_mm[c]
                errors[c] = (float(back[0] - cmd[0]), float(back[1] - cmd[1]))
                measured[c] = self.measured_mm[c]
        return PositionFit(sorted(errors), measured, errors, {c: True for c in errors},
                           {c: v for c, v in self._residual_px.items() if c in errors and v is not None},
                           {c: self._tracks.get(c, 0) for c in errors}, np.zeros(0), np.zeros(0), np.zeros(0, int),
                           float("nan"))

    def _path(self, cell: Cell, file: str | None):
        if file is None:
            file = self.dataset.view(*cell).get("file")
        if not file:
            raise LfError(f"row {cell[0]}, column {cell[1]} has no file to check")
        return resolve_inside(self.dataset.root, file)

    def _check(self, cell: Cell, file: str | None, frames: list[FrameRecord] | None = None) -> None:
        grid = self.grid
        path = self._path(cell, file)
        m = measure_view(path, *cell, work_width_px=self.work_width_px)
        # an exposure bracket: clipping judged on what the merge keeps, as `lfstudio check` does
        if frames is None:
            frames = self.dataset.view(*cell).get("frames")
        m = with_frames(m, bracket_frames(frames, lambda f: resolve_inside(self.dataset.root, f)), path)
        m.small_luminance = None
        grid.add(m)
        r = cell[0]
        grid.drop_images(lambda c: abs(c[0] - r) <= KEEP_ROWS)
        # the views whose judgement this one can change: its ring and its position window
        around = {(r + dr, cell[1] + dc) for dr, dc in set(RING) | set(WINDOW)} | {cell}
        window = sorted(c for c in around if c in grid.measures)
        anchors = [c for c in window if c != cell and c in self.measured_mm]
        fit = None
        if len(anchors) >= MIN_ANCHORS:
            # neighbours already located anchor the new view where they really stood
            fit = grid.solve([cell, *anchors], fixed=anchors, known_mm=self.measured_mm)
            new = [cell] if cell in fit.error_mm else []
        elif len(window) >= MIN_LOCATED:
            # the first views of a scan: solve the window freely; its frame becomes the scan's frame
            fit = grid.solve(window)
            new = [c for c in fit.error_mm if c not in self.measured_mm]
            if len(fit.error_mm) < MIN_LOCATED:
                fit, new = None, []
        else:
            new = []
        if fit is not None:
            for c in new:
                self.measured_mm[c] = fit.measured_mm[c]
                self._residual_px[c] = fit.residual_rms_px.get(c)
                self._tracks[c] = fit.tracks.get(c, 0)
            self._refit_frame()
        entry = self.grid.judge_view(cell, self._located([cell]), self._typical_residual(), grid.geometry.near_m)
        entry["file"] = file
        with self._lock:
            self.results[cell] = entry
        self._publish([entry] + self._rejudge([c for c in window if c != cell]))


def live_document(header: dict[str, Any], views: list[dict[str, Any]]) -> dict[str, Any]:
    """A live check's ``quality.json``-style document: ``header`` (:meth:`LiveChecker.header`) and the
    entries of the views judged so far, in cell order."""
    typical = [v["checks"]["residual"]["value"] for v in views if v["checks"]["residual"]["value"] is not None]
    return {"format": "lfstudio-quality", "live": True, **header,
            "tracks": {"typical_view_residual_px": sorted(typical)[len(typical) // 2] if typical else None},
            "views": views}


def _view_done(event: Any) -> tuple[int, int, str, list[FrameRecord] | None] | None:
    """(row, column, file, the bracket's frame records or None) of a scan engine's ``view-done`` event
    with a file; None for any other."""
    kind = getattr(getattr(event, "kind", None), "value", getattr(event, "kind", None))
    if kind == "view-done" and event.row is not None and event.file:
        frames = (getattr(event, "extra", None) or {}).get("frames")
        return int(event.row), int(event.column or 0), event.file, frames
    return None


class LiveCheckerProcess(_Published):
    """A :class:`LiveChecker` on ``dataset`` in a process of its own (see the module docstring).

    Inputs as a ``LiveChecker``'s (:meth:`on_event`, :meth:`submit`, :meth:`settle`), none of which
    blocks: commands go to the process through a writer thread, which also starts it (spawn: a second
    or so of imports, off the caller's thread). Listeners get each new or changed entry on a reader
    thread; :attr:`results`, :meth:`flagged` and :meth:`document` mirror what the process published.
    A checker that cannot start (the dataset unreadable) logs why and leaves ``failed`` set."""

    def __init__(self, dataset, *, lower_priority: bool = True):
        self.root = str(dataset.root)
        self.results: dict[Cell, dict[str, Any]] = {}
        self.errors: dict[Cell, str] = {}            # as of the last wait_idle()
        self.failed: str | None = None
        self._header: dict[str, Any] = {}
        self._listeners = Listeners("live quality listener", log)
        self._lock = threading.Lock()
        self._commands: queue.Queue = queue.Queue()
        self._answers: dict[int, threading.Event] = {}
        self._numbers = itertools.count(1)
        self._ended = threading.Event()              # the reader saw the process's end
        self._lower = lower_priority
        self.process: BaseProcess | None = None
        self._reader: threading.Thread | None = None
        self._writer = threading.Thread(target=self._write, name="quality-live-writer", daemon=True)
        self._writer.start()

    # -- inputs (any thread, never blocking) -----------------------------------------------------------
    def on_event(self, event: Any) -> None:
        """A scan engine listener: queue each finished view."""
        view = _view_done(event)
        if view is not None:
            self.submit(*view)

    def submit(self, row: int, column: int, file: str | None = None, frames: list[FrameRecord] | None = None) -> None:
        self._commands.put(("submit", int(row), int(column), file, frames))

    def settle(self) -> None:
        self._commands.put(("settle",))

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Block until every view queued so far is judged and its entries are here (True), or
        ``timeout_s`` passed or the process ended (False)."""
        number = next(self._numbers)
        answered = threading.Event()
        with self._lock:
            self._answers[number] = answered
        self._commands.put(("idle", number))
        return answered.wait(timeout_s) and not self._ended.is_set()

    def close(self, timeout_s: float | None = 10.0, drain: bool = True) -> None:
        """Stop the process after the views already queued (``drain``) or after the current one;
        wait up to ``timeout_s`` for it (0: do not wait)."""
        self._commands.put(("stop", bool(drain)))
        if timeout_s == 0:
            return
        self._writer.join(timeout_s)
        if self.process is not None:
            self.process.join(timeout_s)
        if self._reader is not None:
            self._reader.join(timeout_s)

    # -- results --------------------------------------------------------------------------------------
    def document(self) -> dict[str, Any]:
        """The views judged so far, in the layout of ``quality.json``."""
        with self._lock:
            views = [dict(self.results[c]) for c in sorted(self.results)]
        return live_document(self._header, views)

    # -- the writer and reader threads ----------------------------------------------------------------
    def _write(self) -> None:
        ctx = multiprocessing.get_context("spawn")
        commands_in, commands_out = ctx.Pipe(duplex=False)
        results_in, results_out = ctx.Pipe(duplex=False)
        process = ctx.Process(target=_checker_process, args=(self.root, commands_in, results_out, self._lower),
                              name="lfstudio-live-check", daemon=True)
        try:
            process.start()
        except Exception as exc:   # noqa: BLE001 - no process, no live check: say so, the scan goes on
            self._fail(f"the live check could not start: {exc}")
            self._ended.set()
            self._release_waiters()
            return
        finally:
            commands_in.close()
            results_out.close()
        self.process = process
        self._reader = threading.Thread(target=self._read, args=(results_in,), name="quality-live-reader",
                                        daemon=True)
        self._reader.start()
        with commands_out:
            while True:
                item = self._commands.get()
                try:
                    commands_out.send(item)
                except OSError:           # the process has ended
                    return
                if item[0] == "stop":
                    return

    def _read(self, conn) -> None:
        with conn:
            while True:
                try:
                    message = conn.recv()
                except (EOFError, OSError):
                    break
                kind = message[0]
                if kind == "entry":
                    entry = message[1]
                    with self._lock:
                        self.results[(int(entry["row"]), int(entry["column"]))] = entry
                    self._publish([entry])
                elif kind == "header":
                    self._header = message[1]
                elif kind == "idle":
                    self.errors = {tuple(cell): text for cell, text in message[2]}
                    with self._lock:
                        answered = self._answers.pop(message[1], None)
                    if answered is not None:
                        answered.set()
                elif kind == "failed":
                    self._fail(message[1])
        self._ended.set()
        self._release_waiters()

    def _fail(self, message: str) -> None:
        self.failed = message
        log.warning("live check of %s: %s", self.root, message)

    def _release_waiters(self) -> None:
        with self._lock:
            waiting, self._answers = list(self._answers.values()), {}
        for answered in waiting:
            answered.set()


def _checker_process(root: str, commands, results, lower_priority: bool) -> None:
    """The live checker's process (started by :class:`LiveCheckerProcess`): a LiveChecker on the
    dataset at ``root``; commands arrive on ``commands``, entries leave on ``results``."""
    if lower_priority and hasattr(os, "nice"):
        try:       # the whole process: its threads share no GIL with the scan, so this slows only the check
            os.nice(10)
        except OSError:
            pass
    send_lock = threading.Lock()

    def send(message) -> None:
        with send_lock:
            try:
                results.send(message)
            except OSError:         # the GUI has gone; the commands pipe ends this process next
                pass

    try:
        from lfstudio.dataset import Dataset

        checker = LiveChecker(Dataset.open(root), lower_priority=False)
    except Exception as exc:   # noqa: BLE001 - an unreadable dataset: the GUI says so and scans on
        send(("failed", str(exc)))
        return
    send(("header", checker.header()))
    checker.subscribe(lambda entry: send(("entry", entry)))
    drain = False
    while True:
        try:
            item = commands.recv()
        except (EOFError, OSError):      # the GUI has gone
            break
        kind = item[0]
        if kind == "submit":
            checker.submit(*item[1:])
        elif kind == "settle":
            checker.settle()
        elif kind == "idle":
            checker.wait_idle()
            send(("idle", item[1], list(checker.errors.items())))
        elif kind == "stop":
            drain = item[1]
            break
    checker.close(timeout_s=None if drain else 10.0, drain=drain)
    results.close()
