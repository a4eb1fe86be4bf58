"""Fly scanning: each row crossed at one constant speed, a frame as the carriage passes each view.

:class:`FlyScanEngine` is the scan engine (:class:`lfstudio.scan.engine.ScanEngine`: same state
machine, requests, STOP, store stage, journal, resume and auto-resume) with rows instead of views as
the unit of motion:

1. the rig goes (``move_to``) to the row's run-up start, outside the grid: ``v²/2a`` to reach the
   speed plus :attr:`FlyScanEngine.run_up_margin_s` of travel at speed, so every view is crossed at
   speed (clamped to the soft limits), and settles; the camera is armed
   (:class:`lfstudio.rig.camera.TriggeredCamera`);
2. ``fly_to`` the run-down end at the speed (:class:`lfstudio.rig.motion.FlyingController`); a
   poller thread asks the controller's position all along (time-stamped :class:`PositionReport`);
3. for each view, the engine predicts from the latest reports (speed measured from them; the
   acceleration profile while still speeding up) when the carriage passes it, and fires the
   camera's software trigger its nominal latency and half the exposure earlier — from the engine
   thread itself, never queued behind a transfer;
4. once the row is flown, each frame's position is interpolated from the reports at the frame's
   exposure centre (the camera's exposure timestamps, else the trigger time + latency); the view's
   record keeps ``commanded_mm``, the recorded position as ``reported_mm`` and ``fly`` (recorded
   position, its uncertainty, speed, time, how far from the commanded position);
5. a frame that missed its trigger, or came so late or early that it lies more than
   :attr:`FlyScanEngine.tolerance_mm` from its view, is not stored as that view: the view is taken
   again standing still (a step capture), its record flagged ``fly.retaken`` with the reason.

With ``trigger="hardware"`` the controller drives the camera's trigger line itself
(:class:`lfstudio.rig.motion.PulsesAtPositions`: GRBL's spindle output in laser mode, rising as the
carriage passes each view; the camera armed with ``arm_line``, :class:`lfstudio.rig.camera.LineTriggered`).
Nothing is timed by this computer then: the row's G-code is streamed, the frames are fetched as they
come, and each frame's position is the view's (where the line rose) plus the travel during the
camera's line latency and half its exposure, checked against the position reports as before. A
pause or an abort takes effect at the row's end (the controller holds the row); STOP at once.

A pause, an abort or STOP during a row: no further trigger; the frames already triggered are stored
(their positions are recorded), the row's other views go back to the queue and are flown on
resume from a new run-up.
"""

from __future__ import annotations

import logging
import math
import statistics
import sys
import threading
import time
from concurrent.futures import Future
from dataclasses import replace
from typing import Any

from lfstudio.dataset.paths import view_label, view_stem
from lfstudio.errors import DeviceError
from lfstudio.rig.camera import CaptureResult, TriggeredCamera
from lfstudio.rig.grbl_protocol import GrblError
from lfstudio.rig.motion import FlyingController, Latch, LatchesPositions, PositionReport
from lfstudio.scan.engine import ScanEngine, _Interrupted
from lfstudio.scan.events import EventKind, ScanState
from lfstudio.scan.faults import ScanFault, clears_by_itself, error_text, fault_text
from lfstudio.scan.scan_plan import PlannedView
from lfstudio.scan.store import StoreJob

log = logging.getLogger(__name__)

#: how often the poller asks the controller's position (real time; the controller's answer takes longer)
POLL_S = 0.002
#: the interpreter's thread switch interval while a row is flown (see _fly_row)
SWITCH_INTERVAL_S = 0.0002


class NotFlyable(Exception):
    """Devices that cannot fly a scan (no trigger, no constant-speed move): said before the scan."""


def fly_problem(rig: Any, camera: Any) -> str | None:
    """Why ``rig``/``camera`` (drivers or their workers) cannot fly a scan, or None."""
    rig = getattr(rig, "driver", rig)
    camera = getattr(camera, "driver", camera)
    if not isinstance(camera, TriggeredCamera):
        return (f"the camera ({getattr(camera, 'name', type(camera).__name__)}) takes no triggered frames "
                "(it has no trigger mode lfstudio drives); use a step scan")
    if not isinstance(rig, FlyingController):
        return (f"the axis controller ({type(rig).__name__}) cannot move at a set speed and report its position "
                "while it moves; use a step scan")
    return None


def interpolate(reports: list[PositionReport], t: float,
                speed_mm_s: float = 0.0) -> tuple[float, float, float] | None:
    """(x, y, uncertainty in mm) at ``t`` from the two reports around it (linear: constant speed
    between reports); None when ``t`` is not between two reports. Reports whose question and answer
    lay far apart (more than twice the median, and over 1 ms: the controller or this computer was
    busy, so when the position was taken is vague) are left out when better ones are near.

    The uncertainty bounds what the reports' timing can do: each was taken up to its ``uncertainty_s``
    before or after its timestamp, so the point is off by up to v ((1 - w) ua + w ub) at weight w. v is
    the carriage's speed: ``speed_mm_s`` (the row's, on this clock) when given, or the two reports' own
    if faster (theirs alone is off with their timing: up to 1 / (1 - (ua + ub) / gap))."""
    if len(reports) > 4:
        limit = max(0.001, 2.0 * statistics.median(r.uncertainty_s for r in reports))
        sharp = [r for r in reports if r.uncertainty_s <= limit]
        if len(sharp) >= 2 and sharp[0].t_s <= t <= sharp[-1].t_s:
            reports = sharp
    for a, b in zip(reports, reports[1:]):
        if a.t_s <= t <= b.t_s and b.t_s > a.t_s:
            w = (t - a.t_s) / (b.t_s - a.t_s)
            x = a.x_mm + w * (b.x_mm - a.x_mm)
            y = a.y_mm + w * (b.y_mm - a.y_mm)
            speed = math.hypot(b.x_mm - a.x_mm, b.y_mm - a.y_mm) / (b.t_s - a.t_s)
            # a report taken up to its uncertainty before or after its timestamp is that far along at the
            # speed; each report weighs in the interpolation as it does in the position, so the point can
            # be off by up to v × ((1 - w) ua + w ub) (their RMS, as before, understated it near the
            # vaguer report: by up to 1/√2)
            unc = max(speed, speed_mm_s) * ((1.0 - w) * a.uncertainty_s + w * b.uncertainty_s)
            return x, y, unc
    return None


class FlyScanEngine(ScanEngine):
    """See the module docstring. ``speed_mm_s``: the row speed (decided by
    :func:`lfstudio.planning.fly.plan_fly`); ``tolerance_mm``: how far a frame may lie from its view
    before the view is taken again (default: a quarter of the horizontal spacing)."""

    def __init__(self, *args: Any, speed_mm_s: float, tolerance_mm: float | None = None,
                 run_up_margin_s: float = 0.1, trigger: str = "software", **kwargs: Any):
        super().__init__(*args, **kwargs)
        if trigger not in ("software", "hardware"):
            raise ValueError(f"trigger must be 'software' or 'hardware', got {trigger!r}")
        self.trigger = trigger
        if not (math.isfinite(speed_mm_s) and speed_mm_s > 0):
            raise ValueError(f"speed_mm_s must be positive, got {speed_mm_s!r}")
        if self.time_scale <= 0:
            raise ValueError("a fly scan needs simulated time to pass (time_scale > 0)")
        self.speed_mm_s = float(speed_mm_s)
        self.tolerance_mm = float(tolerance_mm) if tolerance_mm is not None else 0.25 * self.plan.spacing_mm[0]
        self.run_up_margin_s = float(run_up_margin_s)
        #: cell -> ("retaken" or "standing_still", why): views taken standing still, and why
        self._step_cells: dict[tuple[int, int], tuple[str, str]] = {}
        self._late: dict[tuple[int, int], float] = {}         # cell -> trigger sent after its time (s)
        self.rows_flown = 0
        self.retaken = 0
        self.rig_s = 0.0           # the rig's part: moves, settles and rows (not waiting for the camera)
        self.camera_wait_s = 0.0   # rows' frames still being delivered when the row was flown

    # -- the loop: rows --------------------------------------------------------------------------
    def _take_next(self) -> bool:
        """Fly the next row (or take its only view standing still); False when nothing is queued."""
        row = self._next_row()
        if row is None:
            return False
        if len(row) == 1 or row[0].cell in self._step_cells:
            self._step_cells.setdefault(row[0].cell, ("standing_still", "the only view of its row left"))
            self._step(row[0])
            for view in reversed(row[1:]):
                self._queue.appendleft(view)
            return True
        try:
            self._fly_row(row)
        except ScanFault as fault:
            self._raise_fault(fault)
        except _Interrupted:
            pass
        return True

    def _next_row(self) -> list[PlannedView] | None:
        """The next views of one row in queue order (a retried view alone)."""
        if self._retry:
            return [self._retry.popleft()]
        first = self._next_view()
        if first is None:
            return None
        row = [first]
        while self._queue and self._queue[0].row == first.row and first.cell not in self._step_cells:
            view = self._queue.popleft()
            if view.cell in self._skip_cells:
                self._record_skip(view)
                continue
            if view.cell in self._step_cells:
                self._queue.appendleft(view)
                break
            row.append(view)
        return row

    def _step(self, view: PlannedView) -> None:
        """One view taken standing still (a single view, or a fly frame taken again)."""
        t0 = time.monotonic()
        try:
            self._take_view(view)
        finally:
            self.rig_s += time.monotonic() - t0

    def _expose(self, view: PlannedView, attempt: int, stem: Any) -> Future:
        fut = super()._expose(view, attempt, stem)
        why = self._step_cells.pop(view.cell, None)
        if why is None:
            return fut
        self.retaken += why[0] == "retaken"
        return _with_record(fut, {"fly": {why[0]: why[1]}})

    def _report_rounding_mm(self) -> float:
        """How far a position report can be from the carriage by rounding alone: half the horizontal axis'
        position unit (a CiA 402 drive's increments_per_mm; GRBL's steps/mm, $100 for X), else half of
        the 0.001 mm GRBL reports in."""
        driver = self.rig.driver
        axis = driver.config.horizontal
        per_mm = float(getattr(axis, "increments_per_mm", 0.0) or 0.0)
        settings = getattr(driver, "settings", None)
        letter = str(getattr(axis, "letter", "")).upper()
        if per_mm <= 0 and isinstance(settings, dict) and letter in ("X", "Y", "Z"):
            per_mm = float(settings.get(100 + "XYZ".index(letter), 0.0) or 0.0)
        return 0.5 / per_mm if per_mm > 0 else 0.0005

    # -- one row ---------------------------------------------------------------------------------
    def _requeue(self, views: list[PlannedView]) -> None:
        for view in reversed(views):
            self._queue.appendleft(view)

    def _rig_fault(self, exc: BaseException, what: str) -> ScanFault:
        self._handle_inbox()
        if self._state is not ScanState.RUNNING:
            raise _Interrupted()
        message = f"{what}: {error_text(exc)}"
        return ScanFault(fault_text("rig", message, 1), "rig", clears_by_itself("rig", exc))

    def _fly_row(self, row: list[PlannedView]) -> None:
        # every thread of the process shares one GIL: with Python's default 5 ms switch interval the
        # engine thread (and the simulated camera's shutter) wake up to 5 ms late, 0.4 mm at 80 mm/s
        previous = sys.getswitchinterval()
        sys.setswitchinterval(min(previous, SWITCH_INTERVAL_S))
        try:
            self._fly_row_now(row)
        finally:
            sys.setswitchinterval(previous)

    def _fly_row_now(self, row: list[PlannedView]) -> None:
        rig, cam = self.rig.driver, self.camera.driver
        config = rig.config
        h = config.horizontal
        scale = self.time_scale
        v = self.speed_mm_s
        a = float(h.acceleration_mm_s2)
        direction = 1.0 if row[-1].x_mm >= row[0].x_mm else -1.0
        y = row[0].y_mm
        run = v * v / (2.0 * a) + v * self.run_up_margin_s
        start_x = min(max(row[0].x_mm - direction * run, h.soft_min_mm), h.soft_max_mm)
        end_x = min(max(row[-1].x_mm + direction * run, h.soft_min_mm), h.soft_max_mm)
        self._check_card()
        self.store.check_disk()
        self._handle_inbox()
        if self._state is not ScanState.RUNNING:
            self._requeue(row)
            raise _Interrupted()
        t_row0 = time.monotonic()
        self._emit(EventKind.LOG, f"row {row[0].row}: flying {len(row)} views at {v:.3g} mm/s "
                                  f"from x = {start_x:.1f} to {end_x:.1f} mm")
        self._moving = True
        try:
            self._rig_call("move_to", start_x, y, timeout_s=self.move_timeout_s)
        except (ScanFault, _Interrupted):
            self._requeue(row)
            raise
        except Exception as exc:
            self._requeue(row)
            raise self._rig_fault(exc, f"the move to the run-up of row {row[0].row}") from None
        finally:
            self._moving = False
        settle = self.plan.settle_s * scale
        if settle > 0:
            self._wait(lambda: self._state is not ScanState.RUNNING, settle)
        hardware = self.trigger == "hardware"
        try:
            self._camera_call("arm_line" if hardware else "arm", len(row), timeout_s=30)
        except Exception as exc:
            self._requeue(row)
            raise ScanFault(f"Camera: arming it for row {row[0].row} failed: {error_text(exc)}. Check the "
                            "camera, then Resume.", "camera", clears_by_itself("camera", exc)) from None
        reports: list[PositionReport] = []
        poll_error: list[BaseException] = []
        done = threading.Event()

        def poll() -> None:
            while not done.is_set():
                try:
                    reports.append(rig.report())
                except Exception as exc:  # STOP's reset, a lost link: the row ends on its own error
                    poll_error.append(exc)
                    return
                done.wait(POLL_S)

        poller = threading.Thread(target=poll, name="fly-position-reports", daemon=True)
        poller.start()
        latency = float(getattr(cam, "trigger_latency_s", 0.0)) * scale
        half_exposure = 0.5 * float(getattr(cam, "exposure_s", 0.0) or 0.0) * scale
        triggered: list[tuple[PlannedView, float]] = []
        fetches: list[Future] = []
        interrupted = False
        expected_s = (2 * v / a + abs(end_x - start_x) / v) * scale
        try:
            t_cmd = time.monotonic()
            self._moving = True
            if hardware:                      # the controller fires the camera: nothing to time here
                # the fetches wait on the camera's worker for their edges, so each frame is delivered
                # (rendered, on the simulated camera) while the row is still flown
                wait_s = self.capture_call_timeout_s() + 2 * expected_s
                for view in row:
                    triggered.append((view, t_cmd))
                    fetches.append(self._camera_submit("fetch", self._stem(view), wait_s, timeout_s=wait_s + 10))
                self._rig_call("fly_pulsing", [view.x_mm for view in row], end_x, y, v,
                               timeout_s=max(30.0, 3 * expected_s + 30))
            else:
                self._rig_call("fly_to", end_x, y, v, timeout_s=30)
            for view in (row if not hardware else []):
                t_fire = self._fire_time(reports, view.x_mm, direction, v / scale, a / scale ** 2,
                                         latency + half_exposure, t_cmd, expected_s)
                if t_fire is None:            # STOP, a pause, an abort, a fault, or the rig stopped moving
                    interrupted = True
                    break
                t_sent = cam.trigger()
                triggered.append((view, t_sent))
                self._late[view.cell] = t_sent - t_fire
                fetches.append(self._camera_submit("fetch", self._stem(view), self.capture_call_timeout_s(),
                                                   timeout_s=self.capture_call_timeout_s() + 10))
            status = self._rig_call("wait_arrival", end_x, y, max(10.0, 3 * expected_s + 10),
                                    timeout_s=max(10.0, 3 * expected_s + 20))
            if hardware:
                self._rig_call("pulse_off", timeout_s=60)
        except (ScanFault, _Interrupted):
            done.set()
            self._end_line_waits(hardware)
            self._settle_row(row, triggered, fetches, reports, v, interrupted=True, direction=direction)
            raise
        except Exception as exc:
            done.set()
            self._end_line_waits(hardware)
            self._settle_row(row, triggered, fetches, reports, v, interrupted=True, direction=direction)
            fault = self._rig_fault(exc, f"flying row {row[0].row}")
            if isinstance(exc, GrblError):
                # a line refused: what GRBL said and where the carriage stands, not advice about cables
                fault = ScanFault(f"Flying row {row[0].row}: {error_text(exc).rstrip('.')}.",
                                  fault.device, fault.clears)
            if hardware:
                fault = ScanFault(f"{str(fault).rstrip('.')}. The row's views not taken are flown again from "
                                  "its run-up when the scan goes on.", fault.device, fault.clears)
            raise fault from None
        finally:
            self._moving = False
            done.set()
            poller.join(5)
        del status
        t_flown = time.monotonic()
        self.rows_flown += 1
        self._settle_row(row, triggered, fetches, reports, v, interrupted=interrupted, direction=direction)
        self.camera_wait_s += time.monotonic() - t_flown
        self.rig_s += t_flown - t_row0
        if poll_error and not interrupted:
            log.info("fly row %d: position reports ended: %s", row[0].row, poll_error[0])

    def _end_line_waits(self, hardware: bool) -> None:
        """A hardware-triggered row ended early (a refused line, STOP, a lost link): the line's remaining
        edges never come, so the camera's waiting fetches end now instead of at their timeouts."""
        if not hardware:
            return
        stop = getattr(self.camera.driver, "stop", None)
        if callable(stop):
            stop()

    def _stem(self, view: PlannedView) -> Any:
        return self.dataset.root / "raw" / view_stem(view.row, view.column)

    def _fire_time(self, reports: list[PositionReport], x: float, direction: float, v_real: float, a_real: float,
                   lead_s: float, t_cmd: float, expected_s: float) -> float | None:
        """Wait until the trigger for the view at ``x`` is due (predicted afresh from the newest reports
        while waiting); its time, or None when the row must end (a request, a fault, no motion)."""
        while True:
            self._handle_inbox()
            if self._state is not ScanState.RUNNING:
                return None
            now = time.monotonic()
            if now - t_cmd > 2 * expected_s + 10:
                return None
            t_pass = _predict(reports, x, direction, v_real, a_real)
            if t_pass is None:
                self._wait(lambda: self._state is not ScanState.RUNNING, POLL_S)
                continue
            t_fire = t_pass - lead_s
            wait = t_fire - now
            if wait > 0.004:                  # refresh the prediction with newer reports
                self._wait(lambda: self._state is not ScanState.RUNNING, min(wait - 0.002, 0.02))
                continue
            while time.monotonic() < t_fire:  # the last few ms spun: a sleep may wake up ms late
                pass
            return t_fire

    def _settle_row(self, row: list[PlannedView], triggered: list[tuple[PlannedView, float]],
                    fetches: list[Future], reports: list[PositionReport], speed: float, interrupted: bool,
                    direction: float = 1.0) -> None:
        """Store each triggered frame at its recorded position, or mark its view to be taken again;
        the views never triggered go back to the queue."""
        taken = {view.cell for view, _ in triggered}
        rest = [view for view in row if view.cell not in taken]
        latches = self._row_latches()
        if latches:                              # each frame's latch, one to one (all frames first)
            for fut in fetches:
                self._await(fut, self.capture_call_timeout_s() + 10)
            paired = _pair_latches(latches, [_exposure_of(fut, speed) for fut in fetches])
        else:
            paired = [None] * len(fetches)
        for k, ((view, t_sent), fut) in enumerate(zip(triggered, fetches)):
            self._await(fut, self.capture_call_timeout_s() + 10)
            attempt = self._attempts.get(view.cell, 0) + 1
            self._attempts[view.cell] = attempt
            try:
                result: CaptureResult = fut.result(timeout=0)
            except Exception as exc:
                if interrupted and self.trigger == "hardware":
                    rest.append(view)           # the row ended before its edge: flown again from the run-up
                    self._attempts[view.cell] = attempt - 1
                    continue
                self._retake(view, f"missed trigger ({error_text(exc)})")
                continue
            meta = result.metadata if isinstance(result.metadata, dict) else {}
            start, end = meta.get("exposure_start_s"), meta.get("exposure_end_s")
            if isinstance(start, (int, float)) and isinstance(end, (int, float)):
                t_mid, t_unc = (float(start) + float(end)) / 2.0, 0.0
            else:                              # the camera does not tell: its nominal latency, jitter unknown
                cam = self.camera.driver
                t_mid = t_sent + (float(getattr(cam, "trigger_latency_s", 0.0)) +
                                  0.5 * float(meta.get("shutter_s") or 0.0)) * self.time_scale
                t_unc = float(getattr(cam, "trigger_jitter_s", 0.0)) * self.time_scale
            latch = paired[k]
            where = interpolate(reports, t_mid, speed / self.time_scale) if latch is None else None
            if latch is not None:               # latched by the drive on the camera's exposure output
                x, y, unc, source = latch.x_mm, latch.y_mm, latch.uncertainty_mm, "touch probe"
                if latch.edges == "rising":     # the exposure's start: its centre half the exposure on
                    x += direction * 0.5 * speed * float(meta.get("shutter_s") or 0.0)
            elif self.trigger == "hardware":
                # the line rose where the controller passed the view (to the step); the frame's centre is
                # the line latency and half the exposure further along, at the row's speed
                cam = self.camera.driver
                lead_s = float(getattr(cam, "line_trigger_latency_s", 0.0)) + 0.5 * float(
                    meta.get("shutter_s") or getattr(cam, "exposure_s", 0.0) or 0.0)
                x, y, unc, source = view.x_mm + direction * speed * lead_s, view.y_mm, 0.01, "trigger line"
                # the reports judge it within what their own interpolation can be off by: a carriage
                # speeding up at the axis' acceleration strays a·gap²/8 from the line between two reports
                gap = _gap_around(reports, t_mid)
                accel = float(self.rig.driver.config.horizontal.acceleration_mm_s2) / self.time_scale ** 2
                # ... but never by half a spacing or more: frames pair with views in order, so a missed edge
                # puts every later frame of the row a whole spacing from where the line says
                allowed = min(self.tolerance_mm + accel * gap * gap / 8.0, 0.5 * self.plan.spacing_mm[0])
                if where is None:       # nothing to check the pairing with: never stored unchecked
                    self._retake(view, "no position reports around the frame's time to check the trigger line by")
                    continue
                if math.hypot(where[0] - x, where[1] - y) > allowed:
                    self._retake(view, f"the position reports put the frame {math.hypot(where[0] - x, where[1] - y):.3f} "
                                       f"mm from where the trigger line says (tolerance {allowed:.3g} mm): "
                                       "the carriage was not at speed, or a frame was missed")
                    continue
            else:
                if where is None:
                    self._retake(view, "no position reports around the frame's time")
                    continue
                x, y, unc = where
                # the reports count whole steps (GRBL) or position units (CiA 402): rounded by up to half of one
                unc, source = math.hypot(unc, speed / self.time_scale * t_unc) + self._report_rounding_mm(), "reports"
            off = math.hypot(x - view.x_mm, y - view.y_mm)
            if off > self.tolerance_mm:
                self._retake(view, f"late or early trigger: the frame is {off:.3f} mm from its position "
                                   f"(tolerance {self.tolerance_mm:.3g} mm; trigger sent "
                                   f"{1000 * self._late.get(view.cell, 0.0):.2f} ms after its time)")
                continue
            fly = {"recorded_mm": [round(x, 4), round(y, 4)], "uncertainty_mm": round(unc, 4),
                   "trigger": self.trigger,
                   "trigger_late_ms": (None if self.trigger == "hardware" else
                                       round(1000 * self._late.get(view.cell, 0.0), 3)),
                   "offset_mm": round(off, 4), "speed_mm_s": round(speed, 4),
                   "t_s": round(t_mid, 6), "pass": self.rows_flown, "source": source}
            done_fut: Future = Future()
            done_fut.set_result(replace(result, record={**(result.record or {}), "fly": fly}))
            job = StoreJob(view, attempt, done_fut, t_sent, [round(x, 4), round(y, 4)],
                           {"trigger_to_store": time.monotonic() - t_sent})
            self._emit(EventKind.VIEW_EXPOSED, index=view.index, row=view.row, column=view.column,
                       timings_s=dict(job.timings_s))
            self.store.submit(job)
        try:
            self._camera_call("disarm", timeout_s=30)
        except Exception as exc:
            log.info("disarming the camera: %s", exc)
        order = {view.cell: k for k, view in enumerate(row)}
        rest.sort(key=lambda view: order[view.cell])
        self._requeue(rest)
        if interrupted and rest:
            self._emit(EventKind.LOG, f"row {row[0].row}: {len(rest)} views not taken; flown again from the "
                                      "run-up when the scan goes on")

    def _row_latches(self) -> list[Latch]:
        """The positions the rig's drives latched during the row (CiA 402 touch probe), [] without."""
        rig = self.rig.driver
        if not isinstance(rig, LatchesPositions):
            return []
        try:
            return rig.latches()
        except Exception as exc:  # noqa: BLE001 - the row's positions then come from the reports
            log.info("fly row: the drives' latched positions: %s", exc)
            return []

    def _retake(self, view: PlannedView, reason: str) -> None:
        self._step_cells[view.cell] = ("retaken", reason)
        self._queue.appendleft(view)
        self._emit(EventKind.LOG, f"view {view_label(view.row, view.column)}: {reason}; taken again standing still")


def _gap_around(reports: list[PositionReport], t: float) -> float:
    """The time between the two reports around ``t`` (s; 0 when ``t`` is not between two)."""
    for a, b in zip(reports, reports[1:]):
        if a.t_s <= t <= b.t_s:
            return b.t_s - a.t_s
    return 0.0


def _predict(reports: list[PositionReport], x: float, direction: float, v_real: float, a_real: float
             ) -> float | None:
    """When (monotonic) the carriage passes ``x``, from the newest reports: their own speed once it is
    at speed, else speeding up at ``a_real`` to ``v_real``; None while it has not started."""
    if len(reports) < 2:
        return None
    b = reports[-1]
    ahead = direction * (x - b.x_mm)
    a = next((r for r in reversed(reports[:-1]) if b.t_s - r.t_s >= 0.003), reports[0])
    dt = b.t_s - a.t_s
    if dt <= 0:
        return None
    u = direction * (b.x_mm - a.x_mm) / dt
    if ahead <= 0:                           # already passed: when it did (the trigger is late)
        for p, q in zip(reversed(reports[:-1]), reversed(reports)):
            if direction * (x - p.x_mm) >= 0 >= direction * (x - q.x_mm) and q.t_s > p.t_s:
                span = direction * (q.x_mm - p.x_mm)
                return p.t_s + (q.t_s - p.t_s) * (direction * (x - p.x_mm) / span if span > 0 else 0.0)
        return b.t_s
    if u <= 0.02 * v_real:
        return None
    if u >= 0.97 * v_real:
        return b.t_s + ahead / u
    u = max(u, 0.0)
    t_c = (v_real - u) / a_real
    d_c = u * t_c + 0.5 * a_real * t_c * t_c
    if ahead <= d_c:
        return b.t_s + (-u + math.sqrt(u * u + 2 * a_real * ahead)) / a_real
    return b.t_s + t_c + (ahead - d_c) / v_real


def _exposure_of(fut: Future, speed: float) -> tuple[float, float, float] | None:
    """A fetched frame's exposure (start, end on the monotonic clock) and the travel during it (mm); None
    when the frame did not come or does not say when it was exposed."""
    if not fut.done() or fut.cancelled() or fut.exception() is not None:
        return None
    meta = getattr(fut.result(), "metadata", None)
    meta = meta if isinstance(meta, dict) else {}
    start, end = meta.get("exposure_start_s"), meta.get("exposure_end_s")
    if not isinstance(start, (int, float)) or not isinstance(end, (int, float)):
        return None
    return float(start), float(end), speed * float(meta.get("shutter_s") or 0.0)


def _latch_fits(latch: Latch, start: float, end: float, travel_mm: float, slack_s: float = 0.002) -> bool:
    """The latch can be the frame's exposed from ``start`` to ``end``: its window (after the driver last
    saw nothing, until it saw the edges) holds the exposure, and its two edges lie the exposure's
    ``travel_mm`` apart (edges of two frames, as when one came while the probe was being armed again,
    lie a spacing apart)."""
    return (latch.t_after_s - slack_s <= start and (end if latch.edges == "both" else start) <= latch.t_seen_s + slack_s
            and (latch.edges != "both" or abs(latch.span_mm - travel_mm) <= 0.5 * travel_mm + 2.0 * latch.uncertainty_mm))


def _pair_latches(latches: list[Latch], exposures: list[tuple[float, float, float] | None]) -> list[Latch | None]:
    """Each frame's latch, one to one: a frame gets the latch that alone fits it (:func:`_latch_fits`) and
    fits no other frame; else None (its position then comes from the reports). Two frames close together
    (a late trigger, then one on time) can both fall in one latch's window: neither takes it."""
    fits = [[i for i, latch in enumerate(latches) if e is not None and _latch_fits(latch, *e)] for e in exposures]
    claims: dict[int, int] = {}
    for found in fits:
        for i in found:
            claims[i] = claims.get(i, 0) + 1
    return [latches[found[0]] if len(found) == 1 and claims[found[0]] == 1 else None for found in fits]


def _with_record(fut: Future, extra: dict[str, Any]) -> Future:
    """``fut``'s CaptureResult with ``extra`` merged into its record (a view taken again, flagged)."""
    out: Future = Future()

    def done(f: Future) -> None:
        try:
            result = f.result()
        except BaseException as exc:  # noqa: BLE001  (handed on as it is)
            out.set_exception(exc)
            return
        out.set_result(replace(result, record={**(result.record or {}), **extra}))

    fut.add_done_callback(done)
    return out


__all__ = ["DeviceError", "FlyScanEngine", "NotFlyable", "fly_problem", "interpolate"]
