"""The Scan panel: grid set-up (from the current plan), the path preview (its own view:
``gui/views/path_preview.py``), Start/Pause/Resume/Abort/Skip, progress with ETA, the current view
with its step timings, and the log of events.

The engine (:class:`lfstudio.scan.engine.ScanEngine`) runs on its own threads; its events reach
this panel through a queued Qt signal and are re-published, a drain's worth at a time, as
``AppState.scanEvents`` for the grid (at most 1000 / FRAME_MS drains a second: see ``_drain``). What
changes with every view repaints as little as it can: its labels are QuietLabels (no relayout of the
window), the step times show at most every STEP_TIMES_MS and the log takes new lines at most every
LOG_MS (a state change's at once).
Devices: the rig and camera connected in the Rig/Camera panels (``state.devices``), or, in the
simulated studio, a built-in simulated rig and camera started off the GUI thread (while a scan runs on
them, that rig is the window's ``state.devices["rig"]``: STOP, the rig badge and the Rig panel reach it,
see ``_publish_scan_rig``). The scan itself
runs as a :class:`lfstudio.studio.session.ScanSession` (dataset lock for the whole run, resume with
the dataset's own devices: other devices only when the operator agrees, rig checks).
"""

from __future__ import annotations

import json
import logging
import re
import threading
import time
from collections import deque
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any

from PySide6.QtCore import QSize, QTimer
from PySide6.QtGui import QAction, QKeySequence, QTextCursor
from PySide6.QtWidgets import (QCheckBox, QComboBox, QDoubleSpinBox, QFileDialog, QFormLayout, QGroupBox, QHBoxLayout,
                               QLabel, QLineEdit, QMessageBox, QPlainTextEdit, QProgressBar, QPushButton,
                               QSpinBox, QToolButton, QVBoxLayout, QWidget)

from lfstudio.dataset.bracket import Bracket, parse_bracket
from lfstudio.dataset.paths import new_dataset_folder_problem
from lfstudio.errors import DeviceError, InputError, LfError, window_message
from lfstudio.gui.bridge import GuiInbox, JobRunner
from lfstudio.gui.devices import QtDevice
from lfstudio.gui.path_field import expand_on_edit, field_path, offer_sub_folder
from lfstudio.gui.settings import read_float, read_text, settings
from lfstudio.gui.unattended import StatusPageLabel
from lfstudio.gui.views.path_preview import PathPreview
from lfstudio.gui.widgets import QuietLabel, bounds_of, number_of, readable_time, set_progress_async
from lfstudio.jobs import count, format_duration
from lfstudio.planning.scene_plan import ScenePlan
from lfstudio.rig.camera import Paced, SimulatedScene
from lfstudio.rig.motion import MotionController
from lfstudio.scan.events import EventKind, ScanRequestRefused, ScanState
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.studio.scan_options import PARAMS as SCAN_PARAMS
from lfstudio.studio.scan_options import ScanOptions

log = logging.getLogger(__name__)

ACTIVE_KEY = "scan/active_dataset"
TRIGGER_KEY = "scan/trigger"   # the Trigger choice of a continuous-motion scan (auto, hardware, software)
#: the Trigger list: lfstudio scan --trigger's values and the window's words for them
TRIGGER_CHOICES = (("auto", "Automatic (hardware where it can)"), ("hardware", "Hardware (the controller's output)"),
                   ("software", "Software (timed by this computer)"))
TRIGGER_SUMMARY = {"auto": "hardware trigger where the rig and the camera can, else software",
                   "hardware": "hardware trigger (the controller's output)",
                   "software": "software trigger (timed by this computer)"}
GRID_KEY = "scan/grid"    # the panel's grid as last set (JSON): restored with the Planner's plan after a restart
FRAME_MS = 40             # engine events are shown at most 25 times a second (each drain repaints)
DRAIN_BUDGET_S = 0.010    # GUI time one drain may take before it yields to painting and input
STEP_TIMES_MS = 500       # the step times (new with every view) are shown at most this often
STATE_LINES = 3           # the state line ("Paused: the camera failed …"): longer texts end in "…", whole in its tooltip
LOG_LINES = 8             # the scan log box shows at least this many lines
LOG_MS = 200              # a running scan's log lines are appended at most this often (each append repaints)


#: the Bracket field's tooltip while a scan runs or is paused (the field is greyed then)
BRACKET_FIXED_TIP = ("Fixed while this scan runs or is paused: every view of a dataset has the same frames. "
                     "To scan with another bracket: Abort, change it here, then Start into a new folder.")


def _tip(name: str) -> str:
    """A scan option's tip, as its description says it (lfstudio.studio.scan_options), capitalised."""
    param = SCAN_PARAMS[name]
    text = param.tip[:1].upper() + param.tip[1:]
    return f"{text} (valid: {param.valid()})" if param.number is not None else text


def _described(spin, name: str, value=None) -> None:
    """A spin box holding exactly what the scan option ``name`` accepts: range, unit and tip from its
    description, the window's own default ``value`` (else the description's)."""
    number = number_of(SCAN_PARAMS[name], name)
    low, high = bounds_of(SCAN_PARAMS[name], name)
    tick = 1 if number.integer else 10.0 ** -spin.decimals()
    spin.setRange(low + tick if number.low_open else low, high)
    if number.unit:
        spin.setSuffix(f" {number.unit}")
    spin.setValue(getattr(ScanOptions(), name) if value is None else value)
    spin.setToolTip(_tip(name))


class _CompactSpin(QDoubleSpinBox):
    """A spin box whose widest value (-100000.000) does not set the panel's width: it asks for the
    width of a usual value (the panel fits a 1366 px screen's dock) and scrolls its text beyond that."""

    def _width(self, hint):
        hint.setWidth(min(hint.width(), self.fontMetrics().horizontalAdvance("-0000.000") + 36))
        return hint

    def sizeHint(self) -> QSize:
        return self._width(super().sizeHint())

    def minimumSizeHint(self) -> QSize:
        return self._width(super().minimumSizeHint())


#: the Scan panel's line when STOP was pressed while a scan was being prepared
STOPPED_BEFORE_START = ("Not started: STOP was pressed while the scan was being prepared (the rig stopped). "
                        "Press Start when ready.")


class PreparingRig:
    """The rig a scan being prepared uses before it is the window's rig (the Scan panel's own
    simulated studio connecting and homing, a resume homing it): the window's STOP stops it without
    waiting, and a STOP pressed during the preparation keeps the scan from starting."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.rig: Any = None
        self.stopped = False

    def set(self, rig: Any) -> None:
        """The rig is known (any thread); raises when STOP was pressed already (nothing more moves it)."""
        with self._lock:
            self.rig = rig
            stopped = self.stopped
        if stopped:
            raise DeviceError(STOPPED_BEFORE_START)

    def stop(self) -> None:
        """STOP (GUI thread): the rig's stop() on a thread of its own; the scan will not start."""
        with self._lock:
            self.stopped = True
            rig = self.rig
        if rig is not None and callable(getattr(rig, "stop", None)):
            threading.Thread(target=_stop_logged, args=(rig,), name="stop-preparing-rig", daemon=True).start()


def _stop_logged(rig: Any) -> None:
    try:
        rig.stop()
    except Exception:  # noqa: BLE001 - nobody waits for this thread: the log has it
        log.exception("STOP of the rig being prepared failed")


def prepare_scan(job: dict, progress=None, cancel=None) -> dict:
    """Off the GUI thread: the simulated studio if needed, then a :class:`ScanSession` on the panel's
    devices (dataset lock, dataset created or resumed with its own devices, rig checks) and its engine.
    Returns ``{"studio", "session", "dataset", "engine", "restore"}``."""
    from lfstudio.studio.devices import link_for_camera, link_for_rig, open_studio
    from lfstudio.studio.session import (DeviceChangeRefused, RigNotHomed, RigNotWhereLeft, RigUsedSince,
                                         ScanRequest, ScanSession,
                                         SharedDevices)

    plan: ScanPlan = job["plan"]
    folder: Path = job["folder"]
    studio = job["studio"]
    started_studio = None
    restore: list = []          # calls that give the shared simulated devices their time scales back
    if job["shared"] is not None:
        rig, camera, rig_link, camera_link = job["shared"]
        if isinstance(camera.driver, SimulatedScene):   # simulated camera: centre its scene on this grid
            camera.call("set_view_region", plan.extent_mm(), timeout_s=30)
            camera_scale = camera.driver.time_scale if isinstance(camera.driver, Paced) else None
            camera.call("set_setting", "time_scale", job["time_scale"], timeout_s=30)
            if camera_scale is not None:
                restore.append(partial(camera.submit, "set_setting", "time_scale", camera_scale))
        simulator = job.get("simulator")
        if simulator is not None:                        # the Rig panel's simulated controller
            restore.append(partial(setattr, simulator, "time_scale", simulator.time_scale))
            simulator.time_scale = float(job["time_scale"])
        rig_link = rig_link or link_for_rig(rig.driver, job["rig_cfg"], simulated=simulator is not None)
        camera_link = camera_link or link_for_camera(camera.driver)
        devices = SharedDevices(rig, camera, {"rig": rig_link.record(), "camera": camera_link.record()},
                                port=rig_link.port)
        if rig_link.spec.drives:              # CiA 402 drives: their own reference may be kept instead
            devices.how_to_home = ("home it in the Rig panel (Rig → Home), or keep the drives' own reference there "
                                   "(Keep drive reference) if they were homed before and kept it, then start again")
    else:
        if studio is None:
            preparing = job.get("preparing")
            studio = started_studio = open_studio(
                "sim", "sim", job["rig_cfg"], doing="the lfstudio window", time_scale=job["time_scale"],
                exposure_s=job["exposure_s"], transfer_s=job["transfer_s"], view_region_mm=plan.extent_mm(),
                opened=preparing.set if preparing is not None else None)      # STOP stops it while it homes
        else:
            studio.set_view_region(plan.extent_mm())
        devices = SharedDevices(studio.rig, studio.camera, studio.record(), port=studio.port)
    request = ScanRequest(folder, resume=(folder / "dataset.json").is_file(), rig_config=job["rig_cfg"],
                          allow_device_change=job.get("allow_device_change", False), recapture=job["recapture"],
                          time_scale=job["time_scale"], home=job.get("home", False),
                          engine_options=dict(job.get("engine_options") or {}),
                          trust_rig_position=job.get("trust_rig_position", False), fly=job.get("fly", False),
                          keep_on_card=job.get("keep_on_card", False), blur_limit_px=job.get("blur_limit_px", 0.5),
                          fly_speed_mm_s=job.get("fly_speed_mm_s"), fly_trigger=job.get("fly_trigger", "auto"))
    session = ScanSession(request, doing="scanning", devices=devices)
    scene = job["scene"]
    try:
        engine = session.open(lambda existing, cfg: (plan, scene if isinstance(scene, ScenePlan) else None))
    except DeviceChangeRefused as exc:        # the operator decides (ScanPanel._devices_ready)
        restore_time_scales(restore)
        return {"studio": studio, "refused": exc}
    except RigNotHomed as exc:                # the operator may home first (ScanPanel._ask_home)
        restore_time_scales(restore)
        return {"studio": studio, "not_homed": exc}
    except RigNotWhereLeft as exc:            # the operator may move it back (ScanPanel._ask_move_back)
        restore_time_scales(restore)
        return {"studio": studio, "not_there": exc}
    except RigUsedSince as exc:               # the operator says whether it kept the reference (_ask_used_since)
        restore_time_scales(restore)
        return {"studio": studio, "used_since": exc}
    except BaseException:
        if started_studio is not None:
            started_studio.close()
        restore_time_scales(restore)
        raise
    return {"studio": studio, "session": session, "dataset": session.dataset, "engine": engine,
            "restore": restore}


def planner_continuous_motion() -> bool:
    """Whether the Planner's "Continuous motion (fly scan)" box is ticked (remembered by the Planner)."""
    from lfstudio.gui.panels.planner import FLY_SETTINGS_KEY

    return str(settings().value(FLY_SETTINGS_KEY, "false")).lower() == "true"


def restore_time_scales(restore: list | None) -> None:
    """Give the panels' simulated devices back the time scales they had before the scan (the Scan
    panel's time scale applies to the scan only): run the calls ``prepare_scan`` recorded."""
    for undo in restore or ():
        try:
            undo()
        except Exception:   # a closed camera needs no restoring
            pass


class ScanPanel(QWidget):
    """See the module docstring."""

    def __init__(self, state, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.setObjectName("scanPanel")
        self.engine = None
        self.studio = None              # the simulated studio this panel started (kept between scans)
        self.scan_session = None        # the ScanSession of the current scan (holds the dataset's lock)
        self._restore: list | None = None     # see prepare_scan / restore_time_scales
        self._rig_simulator: Any = None       # the simulated rig and its own time scale (_pace_simulated_rig)
        self._rig_own_scale = 1.0
        self._pending_recapture: list[tuple[int, int]] = []
        self._last_start: list[tuple[int, int]] | None = None
        self._last_allow_change = False
        self._drain_timer = QTimer(self)
        self._drain_timer.setSingleShot(True)
        self._drain_timer.timeout.connect(self._drain)
        self._last_drain_s = 0.0
        self._backlog: deque = deque()
        self.bridge = GuiInbox(self._take_events, self, every_ms=FRAME_MS // 2)   # engine events, from its threads
        self._draining = False
        self._done_batch: list[tuple[int, int]] = []     # views done in this drain (path preview)
        self._to_publish: list = []                      # this drain's events for AppState.scanEvents
        self._current_text: str | None = None           # the current view's line, as of this drain
        self._log_lines: list[str] = []             # not appended to the log yet (see _drain, _log)
        self._last_log_s = 0.0
        self._state_seen = False                    # this drain had a state change (its lines shown at once)
        self._log_timer = QTimer(self)
        self._log_timer.setSingleShot(True)
        self._log_timer.timeout.connect(self._flush_log)
        self._log_follow = True         # the log shows its newest line (see _append_log)
        self._resumable = False         # the last scan ended with views still to capture (Resume continues it)
        self._rig_device = None         # the rig whose status may end a paused scan's rig fault
        self._scan_rig: QtDevice | None = None   # the own studio's rig as the window's rig, while its scan lasts
        self._preparing: PreparingRig | None = None   # the rig of the scan being prepared (STOP reaches it)
        self._rig_unready = False       # the paused scan's rig was seen not homed or in alarm
        self.unattended = None          # notifications, status page, auto-resume, on-finish (gui/unattended.py)
        self._said = GuiInbox(lambda lines: [self._log(line) for line in lines], self)   # its lines, any thread
        self._notified_state = None     # the last scan state a desktop notification was decided for
        self.opener = JobRunner(self)
        self.opener.finished.connect(self._devices_ready)
        self.opener.failed.connect(self._devices_failed)
        self._build()
        self._load_settings()
        if not self._restore_grid() and state.plan is not None:
            self._on_plan(state.plan)       # first start: the Planner's plan (published before this panel existed)
        for w in (self.columns, self.rows, self.spacing_h, self.spacing_v, self.offset_h, self.offset_v, self.settle):
            w.valueChanged.connect(self._save_grid)
        self.order.currentIndexChanged.connect(self._save_grid)
        self.bracket.textChanged.connect(self._save_grid)
        self.folder.textChanged.connect(lambda text: state.set_scan_folder(text.strip()))
        state.set_scan_folder(self.folder.text().strip())       # the Planner's disk row measures its disk
        state.planChanged.connect(self._on_plan)
        state.recaptureRequested.connect(self.recapture)
        state.datasetChanged.connect(self._on_dataset)
        state.devicesChanged.connect(self._follow_rig)
        state.stopRequested.connect(self._stop_requested)
        state.liveVerdicts.connect(lambda entries: self.unattended is not None and self.unattended.on_verdicts(entries))
        self._follow_rig("rig")
        self._update_preview()
        self._update_buttons()
        QTimer.singleShot(0, self.offer_resume)

    # -- layout ------------------------------------------------------------------------------------
    def _build(self) -> None:
        grid_box = QGroupBox("Grid")
        form = QFormLayout(grid_box)
        self.columns = QSpinBox()
        self.rows = QSpinBox()
        _described(self.columns, "grid_columns")
        _described(self.rows, "grid_rows")
        size_row = QHBoxLayout()
        size_row.addWidget(self.columns)
        size_row.addWidget(QLabel("×"))
        size_row.addWidget(self.rows)
        form.addRow(SCAN_PARAMS["grid_columns"].label, size_row)
        self.spacing_h = self._mm_spin("spacing_mm", 0, "Horizontal spacing between neighbouring views")
        self.spacing_v = self._mm_spin("spacing_mm", 1, "Vertical spacing between neighbouring views")
        sp_row = QHBoxLayout()
        sp_row.addWidget(self.spacing_h)
        sp_row.addWidget(QLabel("×"))
        sp_row.addWidget(self.spacing_v)
        form.addRow(f"{SCAN_PARAMS['spacing_mm'].label} ({number_of(SCAN_PARAMS['spacing_mm'], 'spacing_mm').unit})", sp_row)
        self.offset_h = self._mm_spin("offset_mm", 0, "Shift of the grid from the centre of the horizontal travel")
        self.offset_v = self._mm_spin("offset_mm", 1, "Shift of the grid from the centre of the vertical travel")
        off_row = QHBoxLayout()
        off_row.addWidget(self.offset_h)
        off_row.addWidget(QLabel("×"))
        off_row.addWidget(self.offset_v)
        form.addRow(f"{SCAN_PARAMS['offset_mm'].label} ({number_of(SCAN_PARAMS['offset_mm'], 'offset_mm').unit})", off_row)
        self.order = QComboBox()
        self.order.addItems(SCAN_PARAMS["order"].choices)
        self.order.setToolTip(_tip("order"))
        form.addRow(SCAN_PARAMS["order"].label, self.order)
        self._own_order = self.order.currentText()     # the operator's choice (an opened dataset's is not saved)
        self.order.activated.connect(lambda _i: setattr(self, "_own_order", self.order.currentText()))
        self.settle = QDoubleSpinBox()
        self.settle.setDecimals(2)
        self.settle.setSingleStep(0.05)
        _described(self.settle, "settle_s", 0.3)
        form.addRow(SCAN_PARAMS["settle_s"].label, self.settle)
        self.bracket = QLineEdit()
        self.bracket.setObjectName("scanBracket")
        self.bracket.setPlaceholderText("none — e.g. -2,0,+2 or 1/500,1/125,1/30s")
        self.bracket.setToolTip(_tip("bracket"))
        form.addRow(SCAN_PARAMS["bracket"].label, self.bracket)
        self.fly = QCheckBox("Continuous motion (fly scan)")
        self.fly.setObjectName("scanFly")
        self.fly.setToolTip("Cross each row at one constant speed and trigger the camera as the carriage passes "
                            "each view, instead of stopping at every view. The speed keeps motion blur within the "
                            "Planner's Blur limit; it needs a camera with triggers and a controller that reports "
                            "its position (the Start button says why not). Views whose frame came late are taken "
                            "again standing still")
        form.addRow(self.fly)
        self.fly.toggled.connect(lambda _on: self._update_preview())
        self.trigger = QComboBox()             # lfstudio scan --trigger auto|hardware|software
        self.trigger.setObjectName("scanTrigger")
        for key, text in TRIGGER_CHOICES:
            self.trigger.addItem(text, key)
        self.trigger.setToolTip("Who fires the camera in a continuous-motion scan. Hardware: the axis controller "
                                "switches the camera's trigger line as the carriage passes each view (GRBL's spindle "
                                "output in laser mode, $32=1, wired to the camera's trigger input); nothing is timed "
                                "by this computer. Software: this computer fires the camera, timed from the "
                                "controller's position reports (a busy computer fires late; those views are taken "
                                "again standing still). Automatic: hardware where the rig and the camera can, "
                                "else software (the log says why)")
        form.addRow("Trigger", self.trigger)
        self.trigger.activated.connect(lambda _i: self._trigger_chosen())
        self.fly.toggled.connect(lambda on: self.trigger.setEnabled(on and not self.running))
        self.keep_on_card = QCheckBox("Keep pictures on the camera's card")
        self.keep_on_card.setObjectName("scanKeepOnCard")
        self.keep_on_card.setToolTip("USB cameras (gphoto2): each picture stays on the camera's card and is "
                                     "downloaded while the rig changes rows and at the end, instead of after every "
                                     "shot; a view counts as done once its file is on this computer and verified. "
                                     "Pictures a stopped scan left on the card are fetched when it resumes")
        form.addRow(self.keep_on_card)
        self.from_plan = QPushButton("Take grid from the plan")
        self.from_plan.setObjectName("fromPlanButton")
        self.from_plan.setToolTip("Copy grid, spacing and settle time from the Planner's current plan")
        self.from_plan.clicked.connect(lambda: self._on_plan(self.state.plan))
        form.addRow(self.from_plan)
        self.summary = QLabel("")
        self.summary.setObjectName("scanSummary")
        self.summary.setWordWrap(True)
        form.addRow(self.summary)

        self.preview = PathPreview()

        out_box = QGroupBox("Dataset")
        out_form = QFormLayout(out_box)
        self.folder = QLineEdit()
        self.folder.setObjectName("datasetFolder")
        self.folder.setPlaceholderText("folder for the new dataset")
        self.folder.setToolTip("The dataset folder: created for a new scan; an existing one is resumed. "
                               "~ and $VARIABLES are expanded; the absolute path is shown")
        expand_on_edit(self.folder, "Dataset folder")
        browse = QToolButton()
        browse.setText("…")
        browse.setToolTip("Choose the dataset folder")
        browse.clicked.connect(self._browse)
        f_row = QHBoxLayout()
        f_row.addWidget(self.folder, 1)
        f_row.addWidget(browse)
        out_form.addRow("Folder", f_row)
        self.time_scale = QDoubleSpinBox()
        self.time_scale.setDecimals(2)
        self.time_scale.setSingleStep(0.1)
        _described(self.time_scale, "time_scale")
        self.time_scale.setToolTip("Simulated studio only: " + self.time_scale.toolTip())
        if self.state.simulated:
            out_form.addRow(SCAN_PARAMS["time_scale"].label, self.time_scale)
            self.time_scale.setToolTip(self.time_scale.toolTip() + ". It also paces the simulated rig's "
                                       "homing, jogs and moves outside a scan.")
            self.time_scale.valueChanged.connect(lambda _v: self._pace_simulated_rig())
            self.state.devicesChanged.connect(
                lambda name: self._pace_simulated_rig() if name == "rig_simulator" else None)

        buttons = QHBoxLayout()
        self.start_button = self._button("Start", "startButton", "Start the scan (Ctrl+R); resumes an existing dataset",
                                         self.start)
        self.pause_button = self._button("Pause", "pauseButton", "Pause after the current view (Ctrl+P)", self.pause)
        self.resume_button = self._button("Resume", "resumeButton",
                                          "Continue (after a fault: reconnects the device and retries)", self.resume)
        self.abort_button = self._button("Abort", "abortButton",
                                         "Stop after the current view; everything captured is kept", self.abort)
        self.skip_button = self._button("Skip view", "skipButton",
                                        "Leave out the view the scan stopped at and go on", self.skip)
        for b in (self.start_button, self.pause_button, self.resume_button, self.abort_button, self.skip_button):
            buttons.addWidget(b)

        # text that changes with every view must not re-lay the panel out (each new QLabel text re-lays
        # out the panel, its dock and the main window): QuietLabels, room for two lines where it wraps
        self.state_label = QuietLabel("Idle", name="scanState", lines=STATE_LINES)
        self.status_page = StatusPageLabel()        # the status page's address while it serves
        self.progress = QProgressBar()
        self.progress.setObjectName("scanProgress")
        self.progress.setFormat("%v / %m views (%p%)")
        self.eta = QuietLabel("ETA –", name="scanEta", hint_text="ETA 00:00:00", min_width_px=120)
        prog_row = QHBoxLayout()
        prog_row.addWidget(self.progress, 1)
        prog_row.addWidget(self.eta)
        self.current = QuietLabel("Current view: –", name="currentView")
        self.timings = QuietLabel("Step times: –", name="stepTimings", lines=2, every_ms=STEP_TIMES_MS)
        self.log_view = QPlainTextEdit()
        self.log_view.setObjectName("scanLog")
        self.log_view.setReadOnly(True)
        self.log_view.setMaximumBlockCount(5000)
        self.log_view.setPlaceholderText("Scan events appear here")
        # never fewer than LOG_LINES lines: in a low window the panel scrolls instead (it was 4 lines at 1366 x 768)
        self.log_view.setMinimumHeight(LOG_LINES * self.log_view.fontMetrics().lineSpacing()
                                       + 2 * self.log_view.frameWidth() + 8)

        lay = QVBoxLayout(self)
        lay.addWidget(grid_box)
        lay.addWidget(self.preview, 1)
        lay.addWidget(out_box)
        lay.addLayout(buttons)
        lay.addWidget(self.state_label)
        lay.addWidget(self.status_page)
        lay.addLayout(prog_row)
        lay.addWidget(self.current)
        lay.addWidget(self.timings)
        lay.addWidget(self.log_view, 2)

        for w in (self.columns, self.rows):
            w.valueChanged.connect(self._update_preview)
        for w in (self.spacing_h, self.spacing_v, self.offset_h, self.offset_v, self.settle):
            w.valueChanged.connect(self._update_preview)
        self.order.currentIndexChanged.connect(self._update_preview)
        self.bracket.textChanged.connect(self._update_preview)

    def _mm_spin(self, name: str, index: int, tip: str) -> QDoubleSpinBox:
        """One value of the pair ``name`` (horizontal: 0, vertical: 1), range, unit and default from its
        description (lfstudio.studio.scan_options)."""
        s = _CompactSpin()
        s.setDecimals(3)
        _described(s, name, getattr(ScanOptions(), name)[index])
        s.setSuffix("")                                  # the row's label says the unit
        s.setToolTip(f"{tip} (valid: {SCAN_PARAMS[name].valid()})")
        return s

    def _button(self, text: str, name: str, tip: str, slot) -> QPushButton:
        b = QPushButton(text)
        b.setObjectName(name)
        b.setToolTip(tip)
        b.clicked.connect(slot)
        return b

    def install_menus(self, window) -> None:
        menu = window.menu("Rig")
        menu.addSeparator()
        for text, shortcut, tip, slot in (
                ("Start scan", "Ctrl+R", "Start (or resume) the scan set up in the Scan panel", self.start),
                ("Pause scan", "Ctrl+P", "Pause after the current view", self.pause),
                ("Resume scan", "Ctrl+Shift+R", "Continue a paused scan", self.resume),
                ("Abort scan", "Ctrl+.", "Stop after the current view", self.abort)):
            a = QAction(text, self)
            a.setShortcut(QKeySequence(shortcut))
            a.setToolTip(tip)
            a.triggered.connect(slot)
            menu.addAction(a)
            setattr(self, f"action_{text.split()[0].lower()}", a)
        self._update_buttons()             # each enabled only when its button in the Scan panel is

    # -- settings ----------------------------------------------------------------------------------
    def _load_settings(self) -> None:
        s = settings()
        from lfstudio.gui.preferences import datasets_folder

        self.folder.setText(read_text("scan/folder", str(datasets_folder() / "lfstudio-scan"), s))
        self.time_scale.setValue(read_float("scan/time_scale", 1.0, s))
        self.order.setCurrentText(read_text("scan/order", "row-meander", s))
        self._own_order = self.order.currentText()
        index = self.trigger.findData(read_text(TRIGGER_KEY, "auto", s))
        self.trigger.setCurrentIndex(max(index, 0))        # a garbled setting: automatic

    def _save_settings(self) -> None:
        s = settings()
        s.setValue("scan/folder", self.folder.text())
        s.setValue("scan/time_scale", self.time_scale.value())
        s.setValue("scan/order", self._own_order)      # the order the operator chose, not an opened dataset's
        s.setValue(TRIGGER_KEY, self.trigger.currentData())

    def _trigger_chosen(self) -> None:
        settings().setValue(TRIGGER_KEY, self.trigger.currentData())
        self._update_preview()

    def _grid_fields(self) -> dict[str, Any]:
        return {"columns": self.columns.value(), "rows": self.rows.value(),
                "spacing_mm": [self.spacing_h.value(), self.spacing_v.value()],
                "offset_mm": [self.offset_h.value(), self.offset_v.value()], "settle_s": self.settle.value(),
                "bracket": self.bracket.text().strip()}

    def _save_grid(self, *args) -> None:
        settings().setValue(GRID_KEY, json.dumps(self._grid_fields()))

    def _restore_grid(self) -> bool:
        """Set the grid fields as they were when lfstudio closed; False when nothing (valid) was saved."""
        try:
            saved = json.loads(str(settings().value(GRID_KEY, "") or "null"))
            columns, rows = int(saved["columns"]), int(saved["rows"])
            values = (*map(float, saved["spacing_mm"]), *map(float, saved["offset_mm"]), float(saved["settle_s"]))
        except (TypeError, ValueError, KeyError):
            return False
        self.columns.setValue(columns)
        self.rows.setValue(rows)
        for w, v in zip((self.spacing_h, self.spacing_v, self.offset_h, self.offset_v, self.settle), values):
            w.setValue(v)
        self.bracket.setText(str(saved.get("bracket") or ""))
        return True

    def _pace_simulated_rig(self) -> None:
        """The simulated rig moves and homes at the Simulation time scale (0: at once) outside a scan
        too, never slower than it was started (a scan sets it for its own run and gives it back)."""
        simulator = self.state.devices.get("rig_simulator")
        if simulator is None or self.state.scan_active:
            return
        if self._rig_simulator is not simulator:
            self._rig_simulator, self._rig_own_scale = simulator, float(simulator.time_scale)
        simulator.time_scale = min(self._rig_own_scale, float(self.time_scale.value()))

    def _browse(self) -> None:
        folder = QFileDialog.getExistingDirectory(self, "Dataset folder", str(Path(self.folder.text()).parent))
        if folder:
            self.folder.setText(folder)

    # -- plan --------------------------------------------------------------------------------------
    def rig_config(self):
        from lfstudio.rig.profile import load_rig

        dev = self.state.devices.get("rig")
        driver = dev.driver if isinstance(dev, QtDevice) else None
        return driver.config if isinstance(driver, MotionController) else load_rig()

    def current_plan(self, check: bool = True) -> ScanPlan:
        """The scan the fields describe; InputError naming the field (``Bracket``: its text)."""
        plan = ScanPlan.centered(self.columns.value(), self.rows.value(),
                                 (self.spacing_h.value(), self.spacing_v.value()), self.rig_config(),
                                 offset_mm=(self.offset_h.value(), self.offset_v.value()),
                                 order=self.order.currentText(), settle_s=self.settle.value(), check=check)
        return replace(plan, bracket=parse_bracket(self.bracket.text(), "Bracket"))

    def _on_plan(self, plan: Any) -> None:
        if plan is None or self.running:
            return
        if not isinstance(plan, ScenePlan):
            return
        grid = plan.grid
        if grid.spacing_mm is None:
            return
        self.columns.setValue(grid.columns)
        self.rows.setValue(grid.rows)
        self.spacing_h.setValue(grid.spacing_mm[0])
        self.spacing_v.setValue(grid.spacing_mm[1])
        if plan.settle_s is not None:
            self.settle.setValue(float(plan.settle_s))
        if isinstance(plan.bracket, str):
            self.bracket.setText(plan.bracket)
        fly = planner_continuous_motion()        # the Planner's "Continuous motion (fly scan)" tick
        self.fly.setChecked(fly)
        how = ""
        if fly:
            how = ", continuous motion at " + (f"{plan.fly_speed_mm_s:g} mm/s" if plan.fly_speed_mm_s
                                                  else "the fastest speed the limits allow")
        self._log(f"grid taken from the plan: {grid.columns} × {grid.rows}, "
                  f"{grid.spacing_mm[0]:g} × {grid.spacing_mm[1]:g} mm{how}")

    def _on_dataset(self, dataset: Any) -> None:
        if dataset is None or self.running:
            return
        try:
            base = ScanPlan.from_grid(dataset.grid)
        except InputError:
            return
        before = (self.columns.value(), self.rows.value(), self.spacing_h.value(), self.spacing_v.value(),
                  self.order.currentText())
        self.folder.setText(str(dataset.root))
        fields = (self.columns, self.rows, self.spacing_h, self.spacing_v, self.order)
        for w in fields:
            w.blockSignals(True)
        self.columns.setValue(base.columns)
        self.rows.setValue(base.rows)
        self.spacing_h.setValue(base.spacing_mm[0])
        self.spacing_v.setValue(base.spacing_mm[1])
        self.order.setCurrentText(base.order)
        for w in fields:
            w.blockSignals(False)
        recorded = dataset.manifest.get("bracket")
        try:
            self.bracket.setText(Bracket.from_manifest(recorded).text() if recorded else "")
        except InputError:
            pass
        self._update_preview()
        done = dataset.captured_views()
        self.preview.set_done(done)
        self._set_progress(len(done), len(dataset.views))
        after = (base.columns, base.rows, base.spacing_mm[0], base.spacing_mm[1], base.order)
        if after != before:                # said, not silent; the operator's own order stays their default
            self._log(f"the Scan panel shows {dataset.root.name}'s grid: {base.columns} × {base.rows} views, "
                      f"{base.spacing_mm[0]:g} × {base.spacing_mm[1]:g} mm, {base.order} (was {before[0]} × "
                      f"{before[1]}, {before[2]:g} × {before[3]:g} mm, {before[4]})")
        pending = len(dataset.views) - len(done)
        self._current_text = None
        self.state_label.setText(f"{dataset.root.name}: {len(done)} of {count(len(dataset.views), 'view')} captured"
                                 + (" — Start resumes it" if pending and not self._resumable else ""))

    def _update_preview(self) -> None:
        try:
            plan = self.current_plan(check=False)
        except InputError as exc:
            self.summary.setText(f"<span style='color:#e06060'>{exc}</span>")
            self.preview.set_plan(None)
            return
        self.preview.set_plan(plan)
        rig = self.rig_config()
        try:
            plan.check_limits(rig)
            problem = ""
        except InputError as exc:
            problem = f"<br><span style='color:#e06060'>{exc}</span>"
        scene = self.state.plan if isinstance(self.state.plan, ScenePlan) else None
        exposure = scene.exposure_s if scene is not None else 0.5
        transfer = scene.transfer_s if scene is not None else 2.5
        est = plan.estimate_duration_s(rig, exposure, transfer)
        frames = f" × {plan.bracket.frames} frames ({plan.bracket.describe()})" if plan.bracket else ""
        how = (f"continuous motion, {TRIGGER_SUMMARY[str(self.trigger.currentData())]}: the row speed is chosen at "
               "Start (the Planner's Fly scan line estimates the time)") if self.fly.isChecked() else \
            f"about {format_duration(est)} at {exposure:g} s exposure and {transfer:g} s transfer"
        if scene is not None and planner_continuous_motion() != self.fly.isChecked():
            how += (" (the Planner plans a fly scan: " if not self.fly.isChecked() else
                    " (the Planner plans a step-by-step scan: ") + "Take grid from the plan to follow it)"
        self.summary.setText(f"{count(len(plan), 'view')}{frames} · {how}{problem}")

    # -- running -----------------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self.engine is not None and self.engine.state not in (ScanState.FINISHED, ScanState.FAILED)

    def start(self, recapture: list[tuple[int, int]] | None = None, allow_device_change: bool = False,
              home: bool = False, trust_rig_position: bool = False) -> None:
        """Start (or resume) the scan set up in the panel. Devices, dataset and engine are prepared
        off the GUI thread; the engine starts when they are ready. ``home``: home the rig first."""
        if self.running or self.opener.running:
            return
        if not self.folder.text().strip():
            self.state.report_error("Scan", "Dataset folder: choose a folder for the dataset first.")
            return
        try:
            folder = field_path(self.folder, "Dataset folder")
        except InputError as exc:
            self.state.report_error("Scan", window_message(exc))
            return
        problem = None if (folder / "dataset.json").is_file() else new_dataset_folder_problem(folder)
        if problem:
            self._ask_other_folder(folder, problem, recapture)
            return
        try:
            plan = self.current_plan()
        except InputError as exc:
            self.state.report_error("Scan", f"{exc}\n\nChange the grid, spacing, offset or bracket in the Scan panel.")
            return
        self._save_settings()
        devices = self.state.devices
        rig_on, camera_on = devices.get("rig") is not None, devices.get("camera") is not None
        shared = rig_on and camera_on
        if rig_on != camera_on:     # never a scan on the own simulated studio beside a connected device
            have, lack = ("rig", "camera") if rig_on else ("camera", "rig")
            self.state.report_error(
                "Scan", f"The {have} is connected but the {lack} is not: connect the {lack} in the "
                        f"{lack.capitalize()} panel (Connect), then start the scan. To scan the simulated "
                        f"studio instead, disconnect the {have} in the {have.capitalize()} panel.")
            return
        if not shared and self.studio is None and not self.state.simulated:
            self.state.report_error("Scan", "No rig or camera connected: connect them in the Rig and Camera "
                                            "panels, then start the scan.")
            return
        rig_devices = (devices["rig"].worker, devices["camera"].worker, devices.get("rig_link"),
                       devices.get("camera_link")) if shared else None
        simulator = devices.get("rig_simulator") if shared and self.state.simulated else None
        scene = self.state.plan if isinstance(self.state.plan, ScenePlan) else None
        preparing = PreparingRig()            # the rig the preparation uses, for STOP (see _stop_preparing)
        job = dict(plan=plan, folder=folder, recapture=list(recapture) if recapture else None,
                   rig_cfg=self.rig_config(), scene=scene, shared=rig_devices, simulator=simulator,
                   studio=self.studio, time_scale=self.time_scale.value() if self.state.simulated else 1.0,
                   exposure_s=scene.exposure_s if scene is not None else 0.5,
                   transfer_s=scene.transfer_s if scene is not None else 2.5,
                   allow_device_change=allow_device_change, home=home, trust_rig_position=trust_rig_position,
                   fly=self.fly.isChecked(), fly_trigger=str(self.trigger.currentData()),
                   keep_on_card=self.keep_on_card.isChecked(),
                   blur_limit_px=float(scene.blur_limit_px) if scene is not None else 0.5, preparing=preparing,
                   fly_speed_mm_s=scene.fly_speed_mm_s if scene is not None else None)   # None: the fastest
        if not shared and self.studio is None:
            self._log("starting the simulated studio (GRBL simulator on a pseudo-terminal, simulated camera)…")
            self.state_label.setText("Connecting the simulated rig and camera…")
        if not self._open_unattended(folder, job):
            return
        self.start_button.setEnabled(False)
        self._last_start = (list(recapture) if recapture else None)
        self._last_allow_change = allow_device_change
        self._preparing = preparing
        if not shared and self.studio is not None:
            preparing.set(self.studio.rig)        # a resume may home it while being prepared
        self.opener.start(prepare_scan, job)

    def _stop_requested(self) -> None:
        """The window's STOP (after the window's rig was stopped): the rig of a scan on the own studio
        when it is not the window's rig, and the rig of a scan being prepared."""
        device = self._scan_rig
        if device is not None and self.state.devices.get("rig") is not device:
            device.stop_now()
        self._stop_preparing()

    def _stop_preparing(self) -> None:
        """The window's STOP while a scan is being prepared: its rig stops (the own studio's, which no
        panel holds yet; a rig connected in the Rig panel was stopped by that panel) and the scan does
        not start."""
        preparing = self._preparing
        if preparing is None or not self.opener.running:
            return
        preparing.stop()
        self._log("STOP: the scan being prepared does not start")
        self.state_label.setText("Stopping: STOP was pressed while the scan was being prepared …")

    def _ask_other_folder(self, folder: Path, problem: str, recapture) -> None:
        """A new scan into a folder holding other files: offer a new sub-folder of it, or let the
        operator choose another folder (nothing is written into ``folder``)."""
        self.state_label.setText("Choose a folder for the new dataset")
        self._log(f"not scanning into {folder}: {problem}")

        def accepted(sub: Path) -> None:
            self.folder.setText(str(sub))
            self.start(recapture=recapture)
        self.folder_box = offer_sub_folder(self, folder, stem="lfstudio-scan", verb="Scan",
                                           where="the Folder field of the Scan panel", accepted=accepted)

    def _open_unattended(self, folder: Path, job: dict) -> bool:
        """Settings → Unattended scans for this scan (checked, the status page's port bound) before
        anything starts; a refusal is one line naming the setting."""
        from lfstudio.gui.unattended import load_options
        from lfstudio.studio.unattended import Unattended

        self._close_unattended()
        self._close_status_page()               # the last scan's page, still showing its final state
        try:
            self.unattended = Unattended.open(load_options(), dataset_name=folder.name, say=self._said.post)
        except InputError as exc:
            self.state.report_error("Scan", f"{exc}\n\nChange it in File → Settings…, then start the scan.")
            return False
        if self.unattended.status is not None:
            self.status_page.show_page(self.unattended.status)
        job["engine_options"] = {"auto_resume": self.unattended.options.auto_resume}
        return True

    def _close_unattended(self) -> None:
        """Stop the status page and deliver what is queued, off the GUI thread (the end-of-day command
        may still run: its own time limit)."""
        unattended, self.unattended = self.unattended, None
        if unattended is not None:
            import threading

            board, status, linger_s = unattended.board, unattended.status, unattended.options.status_linger_s
            if status is not None and board is not None and board.outcome is not None and linger_s > 0:
                self.status_page.show_page(status, until=time.time() + linger_s)     # close() lingers
            else:
                self.status_page.clear_page()

            threading.Thread(target=unattended.close, name="unattended-close", daemon=True).start()

    def _close_status_page(self) -> None:
        """Stop a status page still showing the last scan's final state (its port is free again)."""
        server = self.status_page.server
        self.status_page.clear_page()
        if server is not None:
            server.close()

    def _desktop_notify(self, ev) -> None:
        """A desktop notification of a state worth one, when the window is not in front."""
        from lfstudio.gui.unattended import desktop_notify, desktop_wanted
        from lfstudio.scan.notify import URGENT, notice_event

        before, self._notified_state = self._notified_state, ev.state
        event = notice_event(before, ev)
        if event is None or self.window().isActiveWindow() or not desktop_wanted():
            return
        name = Path(self.engine.dataset.root).name if self.engine is not None else "lfstudio"
        desktop_notify(f"Scan of {name} {event}", f"{ev.message} ({ev.done} of {ev.total} views)",
                       urgent=event in URGENT)

    def _devices_failed(self, message: str) -> None:
        self._close_unattended()
        preparing, self._preparing = self._preparing, None
        if preparing is not None and preparing.stopped:        # the operator's own STOP: no alarm box
            self._stopped_before_start()
            return
        self.state_label.setText("Could not start the scan")
        self.state.report_error("Scan", message)
        self._update_buttons()

    def _discard_unstarted(self, engine) -> None:
        """An engine that will not start, on the own studio: its own device workers (the rig's polls the
        rig) closed off the GUI thread. Workers of the panels' devices stay with their panels."""
        studio = self.studio
        if engine is None or studio is None:
            return
        for worker, driver in ((engine.rig, studio.rig), (engine.camera, studio.camera)):
            if worker.driver is driver:
                threading.Thread(target=worker.close, kwargs={"disconnect": False}, name="close-unstarted",
                                 daemon=True).start()

    def _stopped_before_start(self) -> None:
        self.state_label.setText(STOPPED_BEFORE_START)
        self._log(STOPPED_BEFORE_START)
        self.state.show_status("STOP: the scan did not start (Start in the Scan panel starts it)", 10000)
        self._update_buttons()

    def _devices_ready(self, prepared: dict) -> None:
        if prepared.get("studio") is not None:
            self.studio = prepared["studio"]
        preparing, self._preparing = self._preparing, None
        if preparing is not None and preparing.stopped:       # STOP pressed while it was prepared: not started
            self.scan_session = prepared.get("session")
            self._end_session()
            restore_time_scales(prepared.get("restore"))
            self._discard_unstarted(prepared.get("engine"))
            self._close_unattended()
            self._stopped_before_start()
            return
        refused = prepared.get("refused")
        engine = prepared.get("engine")
        if refused is not None or prepared.get("not_homed") is not None or prepared.get("not_there") is not None \
                or prepared.get("used_since") is not None or (engine is not None and engine.remaining == 0):
            self._close_unattended()           # started again (or not at all): a new one then
        if refused is not None:
            self._ask_device_change(refused)
            self._update_buttons()
            return
        if prepared.get("not_homed") is not None:
            self._ask_home(prepared["not_homed"])
            self._update_buttons()
            return
        if prepared.get("not_there") is not None:
            self._ask_move_back(prepared["not_there"])
            self._update_buttons()
            return
        if prepared.get("used_since") is not None:
            self._ask_used_since(prepared["used_since"])
            self._update_buttons()
            return
        dataset, engine = prepared["dataset"], prepared["engine"]
        self._restore = prepared.get("restore")
        self.scan_session = prepared["session"]
        for note in self.scan_session.notes:
            self._log(note)
        if engine.remaining == 0:
            self._discard_unstarted(engine)
            self._end_session()
            self._restore_time_scales()
            self.state.set_dataset(dataset)
            self.state_label.setText("Every view of this dataset is captured.")
            self._log("nothing to capture: every view is done")
            self._update_buttons()
            return
        self.engine = engine
        self._resumable = False
        self._publish_scan_rig(engine)
        engine.subscribe(self.bridge.post)
        if self.unattended is not None:
            self.unattended.attach(engine, dataset)
        self._notified_state = None
        if self.state.dataset is not dataset:
            self.state.set_dataset(dataset)
        self.preview.set_done(dataset.captured_views())
        self.preview.set_plan(engine.plan.with_subset(None))
        settings().setValue(ACTIVE_KEY, str(dataset.root))
        self._log(f"scan of {dataset.root}: {count(engine.remaining, 'view')} to capture"
                  + ("" if engine.pipelined else " (camera without exposure signal: transfer not overlapped)"))
        engine.start()
        self._update_buttons()

    def _publish_scan_rig(self, engine) -> None:
        """A scan on this panel's own simulated studio: its rig (the engine's rig worker) is the window's
        rig (``state.devices["rig"]``) until the scan ends, so the window's STOP (toolbar, Esc, the Rig
        panel's), the rig badge and the Rig panel's position reach it as they reach a rig connected in
        the Rig panel. The scan's lease keeps every other motion command off it."""
        self._unpublish_scan_rig()
        if self.studio is None or engine.rig.driver is not self.studio.rig:
            return
        self._scan_rig = QtDevice(engine.rig, self)
        if self.state.devices.get("rig") is None:
            self.state.set_device("rig", self._scan_rig)
        # else a rig was connected in the Rig panel meanwhile (Start refuses a rig without a camera): the
        # window's STOP stops both (_stop_requested)

    def _unpublish_scan_rig(self) -> None:
        """The scan on the own studio has ended (or the move back before a resume, ``_ask_move_back``):
        its rig is no longer the window's; its worker is closed (the studio stays open)."""
        device, self._scan_rig = self._scan_rig, None
        if device is None:
            return
        if self.state.devices.get("rig") is device:
            self.state.set_device("rig", None)
        device.close(disconnect=False)

    def _request(self, name: str, *args) -> bool:
        """Ask the engine (pause, resume, ...); a request its state no longer allows goes to the log."""
        try:
            getattr(self.engine, name)(*args)
        except ScanRequestRefused as exc:
            self._log(window_message(exc))
            return False
        return True

    def _ask(self, name: str, title: str, text: str, labels: dict, default, answered, *,
             icon=QMessageBox.Icon.Question) -> QMessageBox:
        """A window-modal question opened without blocking (``open``, never ``exec``): ``labels`` maps
        each standard button to its text (None keeps Qt's), ``answered(standard button)`` runs on the
        operator's answer. Returns the box (tests and the panel keep it by name)."""
        buttons = QMessageBox.StandardButton.NoButton
        for button in labels:
            buttons |= button
        box = QMessageBox(icon, title, text, buttons, self)
        box.setObjectName(name)
        for button, label in labels.items():
            if label is not None:
                box.button(button).setText(label)
        if default is not None:
            box.setDefaultButton(default)
        box.buttonClicked.connect(lambda clicked: answered(box.standardButton(clicked)))
        box.open()
        return box

    def _ask_device_change(self, refused) -> None:
        """A resume with other devices than the dataset's: continue only if the operator says so."""
        self.state_label.setText("The dataset was captured with other devices")
        self._log(str(refused))
        recapture = self._last_start

        def answered(answer) -> None:
            if answer == QMessageBox.StandardButton.Yes:
                self.start(recapture=recapture, allow_device_change=True)
        self.device_change_box = self._ask(
            "deviceChangeBox", "Resume with other devices?",
            f"{refused}\n\nContinue the scan with the connected devices? The change is recorded in the dataset "
            "(for every view captured with them).",
            {QMessageBox.StandardButton.Yes: "Resume with these devices", QMessageBox.StandardButton.No: "Cancel"}, QMessageBox.StandardButton.No, answered,
            icon=QMessageBox.Icon.Warning)

    def _ask_home(self, problem) -> None:
        """The rig is not homed (e.g. after a restart, when the interrupted scan is offered): home it
        now as the scan's first step, or leave it to the operator."""
        self.state_label.setText("The rig is not homed")
        self._log(str(problem))
        recapture, allow = self._last_start, self._last_allow_change

        def answered(answer) -> None:
            if answer == QMessageBox.StandardButton.Yes:
                self._log("homing the rig before the scan")
                self.start(recapture=recapture, allow_device_change=allow, home=True)
            else:
                self.state_label.setText("Not started: home the rig (Rig → Home), then Start")
        self.home_box = self._ask(
            "homeFirstBox", "Home the rig first?",
            f"{problem}.\n\nHome the rig now (it drives to its limit switches) and then start the scan?",
            {QMessageBox.StandardButton.Yes: "Home, then scan", QMessageBox.StandardButton.No: "Cancel"}, QMessageBox.StandardButton.Yes, answered)

    def _ask_move_back(self, problem) -> None:
        """A resume whose rig stands elsewhere than where the last run left it: offer to drive it back to
        the last captured view (the move shows in the toolbar's rig badge; STOP stops it), then start."""
        x, y = problem.last_mm
        px, py = problem.position_mm
        self.state_label.setText(f"The rig is not where the last view ({problem.last_view}) was taken")
        self._log(str(problem))
        recapture, allow = self._last_start, self._last_allow_change

        def answered(answer) -> None:
            if answer != QMessageBox.StandardButton.Yes:
                self.state_label.setText(f"Not started: the rig is not where {problem.last_view} was taken")
                return
            devices = self.state.devices
            rig = devices.get("rig") if devices.get("camera") is not None else None    # the scan's, as start()
            if rig is None and self.studio is not None:      # the own studio's rig: the window's for the move
                from lfstudio.rig.worker import DeviceWorker

                self._scan_rig = rig = QtDevice(DeviceWorker(self.studio.rig, name="rig"), self)
                if devices.get("rig") is None:
                    self.state.set_device("rig", rig)        # else STOP reaches it through _stop_requested
            if rig is None:
                self.state.report_error("Scan", "The rig is not connected: connect it (Rig → Connect rig), "
                                        "then press Resume again.")
                return
            self._log(f"moving the rig to ({x:.3f}, {y:.3f}) mm, where {problem.last_view} was taken")
            self.state_label.setText(f"Moving the rig to {problem.last_view} (STOP: Esc) …")
            self.state.show_status(f"Rig: moving to {problem.last_view} at ({x:.3f}, {y:.3f}) mm before the scan "
                                   "(STOP: Esc)", 0)

            def arrived(_status) -> None:
                self._unpublish_scan_rig()
                self.state.show_status(f"Rig at {problem.last_view}: continuing the scan", 5000)
                self.start(recapture=recapture, allow_device_change=allow)

            def failed(message: str) -> None:
                self._unpublish_scan_rig()
                self.state_label.setText(f"Not started: the move to {problem.last_view} failed")
                self.state.report_error("Scan", f"The rig did not reach {problem.last_view}: {message}")
            rig.run("move_to", x, y, on_result=arrived, on_error=failed)
        self.move_back_box = self._ask(
            "moveBackBox", "Move the rig back?",
            f"The rig is at ({px:.3f}, {py:.3f}) mm; the last view of this dataset, {problem.last_view}, was "
            f"taken at ({x:.3f}, {y:.3f}) mm.\n\nMove the rig there and continue the scan? Do this only if its "
            "position can be trusted: if it was switched off, reset or pushed by hand since, home it first "
            "(Rig → Home), then press Resume again.",
            {QMessageBox.StandardButton.Yes: f"Move to {problem.last_view}, then scan", QMessageBox.StandardButton.No: "Cancel"}, QMessageBox.StandardButton.Yes,
            answered)

    def _ask_used_since(self, problem) -> None:
        """A resume whose rig stands where this dataset's last view was taken, but another dataset's scan
        used the rig since: the position is a coincidence lfstudio cannot vouch for. The operator who
        knows the rig kept its reference continues; otherwise Home, then scan."""
        other = problem.other
        self.state_label.setText("Another scan used the rig since this dataset's last view")
        self._log(str(problem))
        recapture, allow = self._last_start, self._last_allow_change

        def answered(answer) -> None:
            if answer == QMessageBox.StandardButton.Yes:
                self._log(f"continuing: the operator says the rig kept its reference since {problem.last_view}")
                self.start(recapture=recapture, allow_device_change=allow, trust_rig_position=True)
            elif answer == QMessageBox.StandardButton.No:
                self._log("homing the rig before the scan")
                self.start(recapture=recapture, allow_device_change=allow, home=True)
            else:
                self.state_label.setText("Not started: another scan used the rig since this dataset's last view")
        self.used_since_box = self._ask(
            "usedSinceBox", "Continue from here?",
            f"The rig stands where this dataset's last view, {problem.last_view}, was taken, but since then it "
            f"scanned another dataset ({Path(other['dataset']).name}, {readable_time(other.get('at'))}).\n\n"
            "If the rig was homed again or given another origin in between, the same numbers are another "
            "place. Continue only if you know it kept its reference; otherwise home it first and then scan "
            "(the scan continues with the next view).",
            {QMessageBox.StandardButton.Yes: "Continue from here", QMessageBox.StandardButton.No: "Home, then scan", QMessageBox.StandardButton.Cancel: None},
            QMessageBox.StandardButton.No, answered)

    def _end_session(self) -> None:
        """Release the dataset's lock (the devices stay with their panels / the simulated studio)."""
        session, self.scan_session = self.scan_session, None
        if session is not None:
            session.close()

    def pause(self) -> None:
        if self.engine is not None:
            self._request("pause")

    def resume(self) -> None:
        if self.engine is not None and self.engine.state is ScanState.PAUSED:
            self._request("resume")
        elif not self.running:
            self.start()

    def abort(self) -> None:
        if self.engine is not None:
            self._request("abort")

    def skip(self) -> None:
        if self.engine is not None and self.engine.state is ScanState.PAUSED:
            if self._request("skip"):
                self._request("resume")

    def recapture(self, cells: list[tuple[int, int]]) -> None:
        cells = [(c[0], c[1]) for c in cells]
        if self.running:
            if self._request("recapture", cells):
                self._log(f"{count(len(cells), 'view')} queued for re-capture")
        else:
            self._log(f"re-capturing {count(len(cells), 'view')}")
            self.start(recapture=cells)

    def offer_resume(self) -> None:
        """On start: if a scan was interrupted (crash, power cut), offer to resume it."""
        path = read_text(ACTIVE_KEY)
        if not path or self.running:
            return
        from lfstudio.dataset import Dataset

        try:
            ds = Dataset.open(path)
        except LfError:
            settings().remove(ACTIVE_KEY)
            return
        counts = ds.status_counts()
        if counts["pending"] == 0:
            settings().remove(ACTIVE_KEY)
            return
        from lfstudio.support.locks import DATASET_LOCK_NAME, holder_of

        holder = holder_of(Path(path) / DATASET_LOCK_NAME)
        if holder is not None:        # it is not interrupted: another lfstudio is scanning it right now
            self._log(f"the scan of {path} is running in {holder.describe()}; not offering to resume it here")
            self.state.show_status(f"{path} is being scanned by {holder.describe()}", 15000)
            return

        def answered(answer) -> None:
            self.state.set_dataset(ds)
            if answer == QMessageBox.StandardButton.Yes:
                self.folder.setText(str(ds.root))
                self.start()
        self.resume_box = self._ask(
            "resumeBox", "Resume interrupted scan",
            f"The scan of {path} was interrupted: {counts['done']} of {len(ds.views)} views are captured, "
            f"{counts['pending']} are missing.\n\nResume it now?",
            {QMessageBox.StandardButton.Yes: "Resume scan", QMessageBox.StandardButton.No: "Not now"}, None, answered)

    # -- events ------------------------------------------------------------------------------------
    def _take_events(self, events: list) -> None:
        """The engine's events (from the inbox): handled at most once a frame, see :meth:`_wake`."""
        self._backlog.extend(events)
        self._wake()

    def _wake(self) -> None:
        """Engine events are waiting: drain them now if the last drain was a frame ago, else when
        that frame is over (at most 1000 / FRAME_MS times a second however fast views come)."""
        if self._drain_timer.isActive() or self._draining:
            return
        wait_ms = FRAME_MS - (time.perf_counter() - self._last_drain_s) * 1000.0
        self._drain_timer.start(max(0, int(wait_ms)))

    def _drain(self) -> None:
        """Handle queued engine events for at most DRAIN_BUDGET_S, then yield to the event loop.
        What shows the latest state (current view, progress, done dots) is drawn once per drain."""
        self._last_drain_s = time.perf_counter()
        t_end = self._last_drain_s + DRAIN_BUDGET_S
        self._draining = True
        last_done = None
        try:
            while self._backlog and time.perf_counter() < t_end:
                ev = self._backlog.popleft()
                if ev.kind is EventKind.VIEW_DONE:
                    last_done = ev
                self._on_event(ev, batched=True)
        finally:
            self._draining = False
            self._publish_pending()
        if self._done_batch:
            cells, self._done_batch = self._done_batch, []
            self.preview.set_done(self.preview.done | set(cells))
        if self._current_text is not None:
            self.current.setText(self._current_text)
            self._current_text = None
        if last_done is not None:
            self._show_done(last_done)
        if self._log_lines:                  # each append repaints the log: at most every LOG_MS
            if self._state_seen or time.perf_counter() - self._last_log_s >= LOG_MS / 1000.0:
                self._flush_log()
            elif not self._log_timer.isActive():
                self._log_timer.start(LOG_MS)
        self._state_seen = False
        if self._backlog:                    # more than a slice: go on after the pending paints
            self._drain_timer.start(0)

    def _show_done(self, ev) -> None:
        self._set_progress(ev.done, ev.total)
        self.eta.setText(f"ETA {format_duration(ev.eta_s)}")
        self.timings.setText("Step times: " + ", ".join(f"{k.replace('_', ' ')} {v:.2f} s"     # "camera wait"
                                                       for k, v in ev.timings_s.items()))
        self.preview.update()

    def _on_event(self, ev, batched: bool = False) -> None:
        kind = ev.kind
        if not batched:
            self.state.publish_scan_events([ev])
        elif kind is EventKind.STATE:       # listeners see every event before a state change is acted on
            self._publish_pending()
            self.state.publish_scan_events([ev])
        else:
            self._to_publish.append(ev)
        if kind is EventKind.STATE:
            self._desktop_notify(ev)
            self._state_seen = True
            self._show_state(ev.state, ev.message)
            self._log(ev.describe())
        elif kind is EventKind.VIEW_STARTED:
            self._set_current(f"Current view: row {ev.row}, column {ev.column} "
                              f"(#{ev.index + 1 if ev.index is not None else '?'}) — moving", batched)
            self.preview.current = (ev.row, ev.column)
            self.preview.update()
        elif kind is EventKind.VIEW_EXPOSED:
            self._set_current(f"Current view: row {ev.row}, column {ev.column} — exposed, transferring", batched)
        elif kind is EventKind.VIEW_DONE:
            if batched:
                self._done_batch.append((ev.row, ev.column))
            else:
                self.preview.mark_done(ev.row, ev.column)
                self._show_done(ev)
            self._log(ev.describe())
        elif kind in (EventKind.VIEW_FAILED, EventKind.FAULT, EventKind.VIEW_SKIPPED, EventKind.LOG):
            self._log(("⚠ " if kind in (EventKind.FAULT, EventKind.VIEW_FAILED) else "") + ev.describe())

    def _publish_pending(self) -> None:
        events, self._to_publish = self._to_publish, []
        self.state.publish_scan_events(events)

    def _set_current(self, text: str, batched: bool) -> None:
        if batched:
            self._current_text = text       # shown once, at the end of the drain
        else:
            self.current.setText(text)

    def _show_state(self, st: ScanState, message: str) -> None:
        colors = {ScanState.RUNNING: "#60c070", ScanState.PAUSED: "#f0b030", ScanState.PAUSING: "#f0b030",
                  ScanState.STOPPING: "#f0b030", ScanState.FAILED: "#e06060", ScanState.FINISHED: "#80a0ff"}
        engine_fault = None if self.engine is None else self.engine.fault
        fault = engine_fault is not None and st is ScanState.PAUSED
        stopped = fault and engine_fault is not None and engine_fault.stop_pressed    # the operator's own STOP
        fault = fault and not stopped
        if st is ScanState.PAUSED:
            self._rig_unready = False          # see _rig_status: "ready again" only after it was not
            from lfstudio.rig.motion import RigState, RigStatus

            # the rig's alarm may have been published before the scan said it paused: its latest status counts
            latest = self._rig_device.latest if isinstance(self._rig_device, QtDevice) else None
            if isinstance(latest, RigStatus) and (not latest.homed or
                                                  latest.state in (RigState.ALARM, RigState.DISCONNECTED)):
                self._rig_unready = True
        color = "#e06060" if fault else colors.get(st, "#c0c0c0")
        word = st.value.capitalize()
        said = re.match(r"([A-Z][a-z]+): (.*)", message, re.S)    # "Aborted: 4 of 27 …" names the state itself
        if said is not None:
            word, message = said.group(1), said.group(2)
        self.state_label.setText(f"<b style='color:{color}'>{word}</b> {message}")
        if st in (ScanState.PAUSED, ScanState.FINISHED, ScanState.FAILED):
            self._current_text = None
            self.current.setText("Current view: –")
            self.preview.current = None
            self.preview.update()
        if st in (ScanState.FINISHED, ScanState.FAILED):
            self._unpublish_scan_rig()
            self._restore_time_scales()
            self._end_session()
            self._close_unattended()
            self._resumable = self.engine is not None and self.engine.dataset.status_counts()["pending"] > 0
        if st is ScanState.FINISHED and self.engine is not None:
            if self.engine.dataset.status_counts()["pending"] == 0:
                settings().remove(ACTIVE_KEY)
            self.current.setText("Current view: –")
            self.preview.current = None
            self.eta.setText("ETA –")
            if self._pending_recapture:
                cells, self._pending_recapture = self._pending_recapture, []
                QTimer.singleShot(0, lambda: self.start(recapture=cells))
        if fault and self.engine is not None and not self.engine.resumes_by_itself:    # auto-resume waits: no message box to answer
            self.state.report_error("Scan paused", message)
        elif stopped:
            self.state.show_status("STOP: the scan is paused (Resume in the Scan panel continues it)", 10000)
        self._update_buttons()

    def _follow_rig(self, name: str) -> None:
        """Listen to the connected rig's status (see :meth:`_rig_status`)."""
        if name != "rig":
            return
        device = self.state.devices.get("rig")
        if device is self._rig_device:
            return
        if self._rig_device is not None:
            try:
                self._rig_device.statusChanged.disconnect(self._rig_status)
            except (RuntimeError, TypeError):
                pass
        self._rig_device = device
        if isinstance(device, QtDevice):
            device.statusChanged.connect(self._rig_status)

    def _rig_status(self, snapshot: Any) -> None:
        """A scan paused by a rig fault (alarm, not homed) says so only while it is true: once the
        rig is homed and idle again the line says that Resume continues."""
        engine = self.engine
        fault = engine.fault if engine is not None else None
        if engine is None or engine.state is not ScanState.PAUSED or fault is None or fault.device != "rig":
            return
        from lfstudio.rig.motion import RigState, RigStatus

        status = snapshot if isinstance(snapshot, RigStatus) else None        # else a DeviceFault
        state = status.state if status is not None else None
        homed = status.homed if status is not None else False
        if not homed or state in (RigState.ALARM, RigState.DISCONNECTED):
            self._rig_unready = True           # lost its reference or in alarm: say so when it is back
        elif self._rig_unready and state is RigState.IDLE:
            text = "<b style='color:#f0b030'>Paused</b> The rig is ready again (homed): press Resume to continue."
            if self.state_label.text() != text:
                self.state_label.setText(text)
                self._log("the rig is homed again: Resume continues the scan")

    def _restore_time_scales(self) -> None:
        restore, self._restore = self._restore, None
        restore_time_scales(restore)

    def _set_progress(self, done: int, total: int) -> None:
        set_progress_async(self.progress, done, max(total, 1))

    def _update_buttons(self) -> None:
        st = self.engine.state if self.engine is not None else ScanState.IDLE
        running = self.running
        self.start_button.setEnabled(not running and not self.opener.running)
        self.pause_button.setEnabled(st is ScanState.RUNNING)
        # "Resume the scan" (after Abort, a failure or a restart) is always a button that works
        self.resume_button.setEnabled(st is ScanState.PAUSED or (not running and not self.opener.running
                                                                   and self._resumable))
        self.abort_button.setEnabled(st in (ScanState.RUNNING, ScanState.PAUSING, ScanState.PAUSED))
        self.skip_button.setEnabled(st is ScanState.PAUSED and self.engine is not None and self.engine.fault is not None)
        for w in (self.columns, self.rows, self.spacing_h, self.spacing_v, self.offset_h, self.offset_v,
                  self.order, self.settle, self.bracket, self.fly, self.keep_on_card, self.folder, self.from_plan, self.time_scale):
            w.setEnabled(not running)
        self.trigger.setEnabled(not running and self.fly.isChecked())     # only a fly scan has triggers
        self.bracket.setToolTip(BRACKET_FIXED_TIP if running else _tip("bracket"))
        for name, button in (("start", self.start_button), ("pause", self.pause_button),   # Rig → … scan
                             ("resume", self.resume_button), ("abort", self.abort_button)):
            action = getattr(self, f"action_{name}", None)
            if action is not None:
                action.setEnabled(button.isEnabled())

    def _log(self, text: str) -> None:
        """A line for the log: at once, or with a drain's lines (see :meth:`_drain`), in order."""
        from datetime import datetime

        self._log_lines.append(f"{datetime.now():%H:%M:%S}  {text}")
        if not self._draining:
            self._flush_log()

    def _flush_log(self) -> None:
        self._log_timer.stop()
        self._last_log_s = time.perf_counter()
        if self._log_lines:
            lines, self._log_lines = self._log_lines, []
            self._append_log("\n".join(lines))

    def _append_log(self, text: str) -> None:
        """Add lines to the log, following them like a terminal: when the log was scrolled to its end
        it stays there (wherever the text cursor is), otherwise it stays where the operator scrolled."""
        bar = self.log_view.verticalScrollBar()
        if self.log_view.isVisible():       # hidden (a tab behind another panel): as it was when last seen
            self._log_follow = bar.value() >= bar.maximum() - 1
        kept = bar.value()
        self.log_view.appendPlainText(text)
        if self._log_follow:
            if not self.log_view.textCursor().hasSelection():
                self.log_view.moveCursor(QTextCursor.MoveOperation.End)     # where Qt scrolls to when the log is shown
            bar.setValue(bar.maximum())
        else:
            bar.setValue(min(kept, bar.maximum()))

    def shutdown(self) -> None:
        if self.engine is not None and self.running:
            self._request("abort")
            self.engine.wait(30)
        self._unpublish_scan_rig()
        self._end_session()
        self._close_unattended()
        self._close_status_page()
        if self.studio is not None:
            self.studio.close()
            self.studio = None
