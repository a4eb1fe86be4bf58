"""The Rig panel: connect, home / set origin, live position, jog (buttons, hold, keys), go-to, STOP.

All driver calls go through a :class:`lfstudio.rig.worker.DeviceWorker` wrapped in a
:class:`lfstudio.gui.devices.QtDevice`; the GUI thread never waits for the controller. STOP bypasses
the queue: the driver's ``stop()`` is dispatched on a thread of its own (``QtDevice.stop_now``), so a
stalled drive link never holds the GUI thread; its action
(``stop_action``, Esc) is also the main window's always-visible STOP button.

Where the connected controller's own settings and the rig profile disagree (the driver's
``RigStatus.extra["warnings"]``, e.g. another maximum speed, homing off, a shorter travel), a
wrapping warning line under the connection says so (the first two, and how many more; all of them
in its tooltip); it goes when a status no longer carries them (disconnected, or reconnected with a
profile that matches).

While a scan owns the rig (``AppState.scan_owns_rig``) every motion control — jog buttons and keys,
Go, Home, Set origin, Recover, Connect/Disconnect and their menu entries — is disabled, with a
tooltip saying why; the core refuses such commands anyway (the scan holds the rig worker's lease).
"""

from __future__ import annotations

import logging
from typing import Any

from PySide6.QtCore import QPointF, QRectF, Qt, QTimer, Signal
from PySide6.QtGui import QAction, QBrush, QColor, QFont, QKeySequence, QPainter, QPen
from PySide6.QtWidgets import (QButtonGroup, QComboBox, QDoubleSpinBox, QGridLayout, QGroupBox, QHBoxLayout,
                               QLabel, QPushButton, QRadioButton, QSizePolicy, QToolButton,
                               QVBoxLayout, QWidget)

from lfstudio.errors import LfError, window_message
from lfstudio.gui.devices import QtDevice
from lfstudio.gui.kind_form import KindForm
from lfstudio.gui.settings import read_float, read_text, settings
from lfstudio.gui.state import AppState
from lfstudio.gui.widgets import PageStack, number_of, show_lock_note, tab_after
from lfstudio.rig.motion import RigConfig, RigState, RigStatus
from lfstudio.rig.worker import DeviceFault, DeviceWorker

log = logging.getLogger(__name__)

SIMULATED = "Simulated GRBL"
#: the Rig panel's line while the window's rig is the Scan panel's own simulated one (see RigPanel._follow_published)
BORROWED_TEXT = ("The Scan panel's simulated rig, used by its scan: STOP (Esc) stops it. Connect a rig here "
                 "once that scan has ended (finished or aborted).")


def simulated_ports() -> tuple[tuple[str, str, str], ...]:
    """The Port list's simulated devices: every registered rig kind that runs in this process and takes no
    argument (:mod:`lfstudio.studio.kinds`: Simulated GRBL, Simulated drives, ...), as (text in the
    list, device word, tooltip); one spelling for both."""
    from lfstudio.studio.kinds import rig_kinds

    return tuple((kind.label or kind.name, kind.name, kind.help or kind.label) for kind in rig_kinds().values()
                 if kind.simulated and not kind.argument)


def simulated_words() -> tuple[str, ...]:
    return tuple(word for _, word, _ in simulated_ports())


def _port_word(text: str) -> str:
    """A port as typed or remembered → its device word (the list's texts, and "Simulated" of older
    versions, name the simulated devices)."""
    text = (text or "").strip()
    for shown, word, _ in simulated_ports():
        if text.lower() in (shown.lower(), word):
            return word
    return "sim" if text in ("", "Simulated") else text


STEP_SIZES_MM = (0.1, 1.0, 10.0, 100.0)
FINE_STEP_MM = 0.1
WARNINGS_SHOWN = 2              # controller-vs-profile warnings in the panel's line (all in its tooltip)
WARNINGS_TIP = ("The controller's own settings ($$) and the rig profile (resources/presets/rigs.toml) disagree: "
                "change the controller's setting, or disconnect and choose the profile of this rig.")
KEEP_TIP = ("CiA 402 drives: take the position the drives report as the rig's reference without homing (for "
            "drives homed earlier that kept their position, e.g. after a crash). Logged; the badge says "
            "'reference kept from the drive'. Home the rig instead when in doubt")
HOLD_MS = 350                   # press longer than this: continuous jog until release
_STATE_COLOURS = {RigState.IDLE: "#2e7d32", RigState.MOVING: "#1565c0", RigState.JOGGING: "#1565c0",
                  RigState.HOMING: "#1565c0", RigState.HOLD: "#b35900", RigState.ALARM: "#b00020",
                  RigState.DISCONNECTED: "#6b7280"}
NOT_HOMED_COLOUR = "#b35900"     # amber, as rig_badge.BADGE_COLOURS["not homed"]


class RigDiagram(QWidget):
    """The travel, the soft limits (dashed) and the camera position (red dot), y pointing down."""

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.config: RigConfig | None = None
        self.position_mm: tuple[float, float] | None = None
        self.target_mm: tuple[float, float] | None = None
        self.setMinimumSize(220, 90)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Preferred)
        self.setToolTip("The rig seen from the front: travel (grey), soft limits (dashed), camera (red)")

    def sizeHint(self):  # noqa: N802 - Qt naming
        from PySide6.QtCore import QSize
        return QSize(320, 110)

    def set_config(self, config: RigConfig | None) -> None:
        self.config = config
        self.update()

    def set_position(self, position_mm: tuple[float, float] | None) -> None:
        self.position_mm = position_mm
        self.update()

    def set_target(self, target_mm: tuple[float, float] | None) -> None:
        self.target_mm = target_mm
        self.update()

    @staticmethod
    def _map(area: QRectF, config: RigConfig, x_mm: float, y_mm: float) -> QPointF:
        h, v = config.horizontal, config.vertical
        return QPointF(area.left() + area.width() * x_mm / h.travel_mm,
                       area.top() + area.height() * y_mm / v.travel_mm)

    def paintEvent(self, event) -> None:  # noqa: N802
        p = QPainter(self)
        p.setRenderHint(QPainter.RenderHint.Antialiasing)
        fm = p.fontMetrics()
        area = QRectF(8, 6, self.width() - 16, self.height() - 12 - fm.height())
        p.fillRect(self.rect(), QColor("#f7f8fa"))
        config = self.config
        if config is None:
            p.setPen(QColor("#6b7280"))
            p.drawText(self.rect(), Qt.AlignmentFlag.AlignCenter, "no rig")
            return
        h, v = config.horizontal, config.vertical
        p.setPen(QPen(QColor("#9aa1ab"), 1))
        p.setBrush(QBrush(QColor("#e3e6eb")))
        p.drawRect(area)
        soft = QRectF(self._map(area, config, h.soft_min_mm, v.soft_min_mm),
                      self._map(area, config, h.soft_max_mm, v.soft_max_mm))
        p.setBrush(Qt.BrushStyle.NoBrush)
        p.setPen(QPen(QColor("#b35900"), 1, Qt.PenStyle.DashLine))
        p.drawRect(soft.adjusted(1, 1, -1, -1))
        p.setPen(QColor("#4b5563"))
        p.drawText(QRectF(area.left(), area.bottom() + 1, area.width(), fm.height()), Qt.AlignmentFlag.AlignLeft,
                   f"0 ← x {h.travel_mm:g} mm →")
        p.drawText(QRectF(area.left(), area.bottom() + 1, area.width(), fm.height()), Qt.AlignmentFlag.AlignRight,
                   f"y ↓ {v.travel_mm:g} mm")
        if self.target_mm is not None:
            t = self._map(area, config, *self.target_mm)
            p.setPen(QPen(QColor("#1565c0"), 1))
            p.drawLine(QPointF(t.x() - 6, t.y()), QPointF(t.x() + 6, t.y()))
            p.drawLine(QPointF(t.x(), t.y() - 6), QPointF(t.x(), t.y() + 6))
        if self.position_mm is not None:
            c = self._map(area, config, min(max(self.position_mm[0], 0), h.travel_mm),
                          min(max(self.position_mm[1], 0), v.travel_mm))
            p.setPen(QPen(QColor("#7f0000"), 1))
            p.setBrush(QBrush(QColor("#e53935")))
            p.drawEllipse(c, 5, 5)


class RigPanel(QWidget):
    """Dock panel "Rig". ``state.devices["rig"]`` holds the QtDevice while connected (and
    ``state.devices["rig_simulator"]`` the GrblSimulator in simulated mode)."""

    connectedChanged = Signal(bool)

    def __init__(self, state: AppState, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.device: QtDevice | None = None
        self.borrowed: QtDevice | None = None      # the window's rig when this panel did not connect it
        self._retired: list[QtDevice] = []
        self.simulator: Any = None
        self.link: Any = None          # lfstudio.studio.devices.RigLink while connected (driver, simulator, lock)
        self.sim_time_scale = 1.0          # simulated rig: real-time motion (tests speed it up)
        self.last_status: RigStatus | None = None
        self._hold_timer = QTimer(self)
        self._hold_timer.setSingleShot(True)
        self._hold_timer.timeout.connect(self._start_continuous)
        self._pressed: tuple[int, int] | None = None
        self._continuous = False
        self.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
        self.setObjectName("rigPanel")
        from lfstudio.rig.profile import DEFAULT_RIG, load_rig
        s = settings()
        try:
            self.rig_config = load_rig(str(s.value("rig/profile", DEFAULT_RIG)))
        except Exception:
            self.rig_config = load_rig(DEFAULT_RIG)
        self._build()
        self._make_actions()
        self._lock_shown: str | None = None
        self._problem_shown = ""           # the message of a status problem (alarm, no connection) shown now
        self._base_tips = [(w, w.toolTip()) for w in self._motion_controls()]
        state.scanStateChanged.connect(self._on_scan_state)
        state.devicesChanged.connect(self._follow_published)
        self.refresh_ports()
        self.port_combo.activated.connect(self._port_chosen)
        self.port_combo.currentTextChanged.connect(self._show_options)
        self._show_options()
        self._on_status(RigStatus(RigState.DISCONNECTED))
        self._fit_profile_to_port(self.chosen_port(), remembered=True)   # a remembered pair that no longer fits

    # -- layout ------------------------------------------------------------------------------------
    def _build(self) -> None:
        root = QVBoxLayout(self)
        root.setContentsMargins(6, 6, 6, 6)
        root.setSpacing(6)

        self.stop_button = QPushButton("STOP")
        self.stop_button.setObjectName("stopButton")
        self.stop_button.setMinimumHeight(46)
        self.stop_button.setToolTip("Stop all motion now (Esc). Never waits behind other commands.")
        self.stop_button.setFocusPolicy(Qt.FocusPolicy.NoFocus)
        self.stop_button.clicked.connect(self.stop)
        root.addWidget(self.stop_button)
        self.lock_label = QLabel("")
        self.lock_label.setObjectName("rigLockLabel")
        self.lock_label.setWordWrap(True)
        self.lock_label.setProperty("role", "warning")
        self.lock_label.setVisible(False)
        root.addWidget(self.lock_label)

        conn = QGroupBox("Connection")
        cl = QGridLayout(conn)
        self.port_combo = QComboBox()
        self.port_combo.setToolTip("Serial port of the axis controller, or the built-in simulated controller")
        self.port_combo.setSizeAdjustPolicy(QComboBox.SizeAdjustPolicy.AdjustToMinimumContentsLengthWithIcon)
        self.port_combo.setMinimumContentsLength(14)
        self.port_combo.setEditable(True)
        self.refresh_button = QToolButton()
        self.refresh_button.setText("↻")
        self.refresh_button.setToolTip("Look for serial ports again")
        self.refresh_button.clicked.connect(self.refresh_ports)
        self.connect_button = QPushButton("Connect")
        self.connect_button.setToolTip("Connect to the controller on the chosen port")
        self.connect_button.clicked.connect(self.toggle_connection)
        from lfstudio.rig.profile import rig_names
        self.rig_combo = QComboBox()
        self.rig_combo.addItems(rig_names())
        self.rig_combo.setCurrentText(self.rig_config.name)
        self.rig_combo.currentTextChanged.connect(self._rig_chosen)
        self.rig_label = QLabel(self.rig_config.label or self.rig_config.name)
        self.rig_label.setObjectName("rigProfileLabel")
        self.rig_label.setWordWrap(True)
        self._show_profile()
        cl.addWidget(QLabel("Port"), 0, 0)
        cl.addWidget(self.port_combo, 0, 1)
        cl.addWidget(self.refresh_button, 0, 2)
        cl.addWidget(self.connect_button, 0, 3)
        cl.addWidget(QLabel("Rig"), 1, 0)
        cl.addWidget(self.rig_combo, 1, 1, 1, 3)
        cl.addWidget(self.rig_label, 2, 0, 1, 4)
        self._fitting = False               # the profile is being chosen to fit the port (not by the operator)
        self.profile_note = QLabel("")      # the profile chosen to fit the port, and why
        self.profile_note.setObjectName("rigProfileNote")
        self.profile_note.setWordWrap(True)
        self.profile_note.setProperty("role", "warning")
        self.profile_note.setVisible(False)
        cl.addWidget(self.profile_note, 4, 0, 1, 4)
        self.warning_label = QLabel("")
        self.warning_label.setObjectName("rigWarningLabel")
        self.warning_label.setWordWrap(True)
        self.warning_label.setProperty("role", "warning")
        self.warning_label.setTextFormat(Qt.TextFormat.PlainText)
        self.warning_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.warning_label.setToolTip(WARNINGS_TIP)
        self.warning_label.setVisible(False)
        cl.addWidget(self.warning_label, 3, 0, 1, 4)
        # the connection options of the port's kind, built from its described options (lfstudio.studio.kinds)
        self.options_button = QToolButton()
        self.options_button.setObjectName("rigOptionsButton")
        self.options_button.setCheckable(True)
        self.options_button.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextBesideIcon)
        self.options_button.setArrowType(Qt.ArrowType.RightArrow)
        self.options_button.toggled.connect(self._toggle_options)
        self.options_stack = PageStack()          # the room of the shown form only
        self.options_stack.setVisible(False)
        self.option_forms: dict[str, KindForm] = {}
        cl.addWidget(self.options_button, 5, 0, 1, 4)
        cl.addWidget(self.options_stack, 6, 0, 1, 4)
        cl.setColumnStretch(1, 1)
        root.addWidget(conn)

        pos = QGroupBox("Position")
        pl = QGridLayout(pos)
        big = QFont("DejaVu Sans Mono")
        big.setStyleHint(QFont.StyleHint.Monospace)
        big.setPointSize(15)
        big.setBold(True)
        self.x_label = QLabel("—")
        self.y_label = QLabel("—")
        for lab in (self.x_label, self.y_label):
            lab.setFont(big)
            lab.setProperty("role", "value")
            lab.setAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
            lab.setMinimumWidth(120)
        self.x_label.setToolTip("Horizontal position in mm from the left end")
        self.y_label.setToolTip("Vertical position in mm from the top end (down is positive)")
        self.state_label = QLabel("disconnected")
        self.state_label.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.state_label.setMinimumWidth(90)
        self.message_label = QLabel("")
        self.message_label.setWordWrap(True)
        self.message_label.setProperty("role", "error")
        self.home_button = QPushButton("Home")
        self.home_button.setToolTip("Run the homing cycle ($H): find the limit switches; allows motion (Ctrl+H)")
        self.home_button.clicked.connect(self.home)
        self.origin_button = QPushButton("Set origin")
        self.origin_button.setToolTip("Make the current position (0, 0) — for rigs without limit switches")
        self.origin_button.clicked.connect(self.set_origin)
        self.recover_button = QPushButton("Recover")
        self.recover_button.setToolTip("Leave the alarm or reconnect after a lost connection")
        self.recover_button.clicked.connect(self.recover)
        self.recover_button.setVisible(False)
        self.keep_button = QPushButton("Keep drive reference")
        self.keep_button.setToolTip(KEEP_TIP)
        self.keep_button.clicked.connect(self.keep_reference)
        self.keep_button.setVisible(False)
        self.drive_label = QLabel("")          # CiA 402 drives: each one's power state and error code (603Fh)
        self.drive_label.setObjectName("rigDriveLabel")
        self.drive_label.setWordWrap(True)
        self.drive_label.setToolTip("Power state (from the status word 6041h) and error code (603Fh) of each drive")
        self.drive_label.setVisible(False)
        self.borrowed_label = QLabel(BORROWED_TEXT)     # a rig published by the Scan panel (see _follow_published)
        self.borrowed_label.setObjectName("rigBorrowedLabel")
        self.borrowed_label.setWordWrap(True)
        self.borrowed_label.setProperty("role", "warning")
        self.borrowed_label.setVisible(False)
        pl.addWidget(QLabel("x"), 0, 0)
        pl.addWidget(self.x_label, 0, 1)
        pl.addWidget(QLabel("mm"), 0, 2)
        pl.addWidget(self.state_label, 0, 3, 2, 1)
        pl.addWidget(QLabel("y"), 1, 0)
        pl.addWidget(self.y_label, 1, 1)
        pl.addWidget(QLabel("mm"), 1, 2)
        buttons = QHBoxLayout()
        buttons.addWidget(self.home_button)
        buttons.addWidget(self.origin_button)
        buttons.addWidget(self.recover_button)
        buttons.addWidget(self.keep_button)
        pl.addLayout(buttons, 2, 0, 1, 4)
        pl.addWidget(self.message_label, 3, 0, 1, 4)
        pl.addWidget(self.drive_label, 4, 0, 1, 4)
        pl.addWidget(self.borrowed_label, 5, 0, 1, 4)
        pl.setColumnStretch(1, 1)
        root.addWidget(pos)

        self.diagram = RigDiagram()
        self.diagram.set_config(self.rig_config)
        root.addWidget(self.diagram)

        jog = QGroupBox("Jog")
        jl = QVBoxLayout(jog)
        steps = QHBoxLayout()
        steps.addWidget(QLabel("Step"))
        self.step_group = QButtonGroup(self)
        saved_step = read_float("rig/step_mm", 10.0)
        for size in STEP_SIZES_MM:
            b = QRadioButton(f"{size:g} mm")
            b.setFocusPolicy(Qt.FocusPolicy.NoFocus)
            b.setToolTip(f"Each click or arrow key moves {size:g} mm; holding a button jogs continuously")
            b.setProperty("step_mm", size)
            b.setChecked(abs(size - saved_step) < 1e-9)
            self.step_group.addButton(b)
            steps.addWidget(b)
        if self.step_group.checkedButton() is None:
            self.step_group.buttons()[2].setChecked(True)
        self.step_group.buttonToggled.connect(lambda *_: settings().setValue("rig/step_mm", self.step_mm))
        steps.addStretch(1)
        jl.addLayout(steps)
        pad = QGridLayout()
        self.jog_buttons: dict[tuple[int, int], QPushButton] = {}
        for (dx, dy), (r, c), text, tip in (((0, -1), (0, 1), "▲", "up (y −)"), ((-1, 0), (1, 0), "◀", "left (x −)"),
                                            ((1, 0), (1, 2), "▶", "right (x +)"), ((0, 1), (2, 1), "▼", "down (y +)")):
            b = QPushButton(text)
            b.setFocusPolicy(Qt.FocusPolicy.NoFocus)
            b.setMinimumSize(44, 34)
            b.setToolTip(f"Jog {tip}: click for one step, hold to move until released (arrow keys; "
                         f"Shift for {FINE_STEP_MM:g} mm steps)")
            b.pressed.connect(lambda d=(dx, dy): self._jog_pressed(d))
            b.released.connect(self._jog_released)
            pad.addWidget(b, r, c)
            self.jog_buttons[(dx, dy)] = b
        centre = QLabel("jog")
        centre.setAlignment(Qt.AlignmentFlag.AlignCenter)
        centre.setProperty("role", "value")
        pad.addWidget(centre, 1, 1)
        padbox = QHBoxLayout()
        padbox.addStretch(1)
        padbox.addLayout(pad)
        padbox.addStretch(1)
        jl.addLayout(padbox)
        root.addWidget(jog)

        goto = QGroupBox("Go to")
        gl = QHBoxLayout(goto)
        self.goto_x = QDoubleSpinBox()
        self.goto_y = QDoubleSpinBox()
        for spin, axis, key in ((self.goto_x, self.rig_config.horizontal, "rig/goto_x"),
                                (self.goto_y, self.rig_config.vertical, "rig/goto_y")):
            spin.setDecimals(3)
            self._fit_target(spin, axis)
            spin.setValue(read_float(key, axis.soft_min_mm))
            spin.valueChanged.connect(lambda v, k=key: settings().setValue(k, v))
        self.goto_button = QPushButton("Go")
        self.goto_button.setToolTip("Move to this position (absolute, rig frame)")
        self.goto_button.clicked.connect(self.go_to)
        gl.addWidget(QLabel("x"))
        gl.addWidget(self.goto_x, 1)
        gl.addWidget(QLabel("y"))
        gl.addWidget(self.goto_y, 1)
        gl.addWidget(self.goto_button)
        root.addWidget(goto)
        root.addStretch(1)

    def _rig_chosen(self, name: str) -> None:
        from lfstudio.rig.profile import load_rig

        if self.device is not None or not name:
            return
        try:
            self.rig_config = load_rig(name)
        except Exception as exc:  # noqa: BLE001 - a broken user preset: say which, keep the old one
            self._show_message(str(exc), "error")
            return
        settings().setValue("rig/profile", name)
        if not self._fitting:
            self._show_profile_note("")              # the operator's own choice: the note is over
        self.rig_label.setText(self.rig_config.label or name)
        self._show_profile()
        self.diagram.set_config(self.rig_config)
        for spin, axis in ((self.goto_x, self.rig_config.horizontal), (self.goto_y, self.rig_config.vertical)):
            self._fit_target(spin, axis)
        self._update_enabled()

    def _show_profile(self) -> None:
        """The profile's settings in the Rig combo's and label's tooltips, each with the label and unit
        of its one description (lfstudio.rig.motion.AxisConfig / RigConfig)."""
        from lfstudio.rig.profile import preset_source, profile_lines

        source = preset_source(self.rig_config.name)
        text = "\n".join([f"Rig profile ({source or 'resources/presets/rigs.toml'}), horizontal × vertical:",
                          *profile_lines(self.rig_config)])
        self.rig_combo.setToolTip(text)
        self.rig_label.setToolTip(text)

    @staticmethod
    def _fit_target(spin: QDoubleSpinBox, axis) -> None:
        """A Go-to field: the axis's soft limits, in the unit of their description."""
        from lfstudio.rig.profile import AXIS_PARAMS

        unit = number_of(AXIS_PARAMS["soft_min_mm"], "soft_min_mm").unit
        spin.setRange(axis.soft_min_mm, axis.soft_max_mm)
        spin.setSuffix(f" {unit}")
        spin.setToolTip(f"{axis.name} target, inside the rig profile's soft limits {axis.soft_min_mm:g} … "
                        f"{axis.soft_max_mm:g} {unit}")

    def _make_actions(self) -> None:
        self.stop_action = QAction("&STOP all motion", self)
        self.stop_action.setShortcut(QKeySequence(Qt.Key.Key_Escape))
        self.stop_action.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
        self.stop_action.setToolTip("Stop the rig now (feed hold + jog cancel)")
        self.stop_action.triggered.connect(self.stop)
        self.addAction(self.stop_action)
        self.connect_action = QAction("&Connect rig", self)
        self.connect_action.setToolTip("Connect to (or disconnect from) the axis controller")
        self.connect_action.triggered.connect(self.toggle_connection)
        self.home_action = QAction("&Home rig", self)
        self.home_action.setShortcut(QKeySequence("Ctrl+H"))
        self.home_action.setToolTip("Run the homing cycle")
        self.home_action.triggered.connect(self.home)
        self.origin_action = QAction("Set &origin here", self)
        self.origin_action.setToolTip("Make the current position (0, 0)")
        self.origin_action.triggered.connect(self.set_origin)
        self.recover_action = QAction("&Recover (unlock / reconnect)", self)
        self.recover_action.setToolTip("Leave an alarm or reconnect after a lost connection")
        self.recover_action.triggered.connect(self.recover)
        self.keep_action = QAction("&Keep the drives' reference", self)
        self.keep_action.setToolTip(KEEP_TIP)
        self.keep_action.triggered.connect(self.keep_reference)

    def _motion_controls(self) -> list[QWidget | QAction]:
        """Everything that commands the rig except STOP (disabled while a scan owns the rig)."""
        return [self.connect_button, self.home_button, self.origin_button, self.recover_button, self.keep_button,
                self.goto_button, *self.jog_buttons.values(), self.connect_action, self.home_action,
                self.origin_action, self.recover_action, self.keep_action]

    def install_menus(self, window) -> None:
        menu = window.menu("Rig")
        for action in (self.connect_action, self.home_action, self.origin_action, self.recover_action,
                       self.keep_action):
            menu.addAction(action)
        menu.addSeparator()
        menu.addAction(self.stop_action)

    # -- connection --------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self.device is not None

    def refresh_ports(self) -> None:
        from lfstudio.rig.connect import available_ports

        current = self.chosen_port() if self.port_combo.count() or self.port_combo.currentText() else ""
        self.port_combo.clear()
        for text, word, tip in simulated_ports():
            self.port_combo.addItem(text, word)
            self.port_combo.setItemData(self.port_combo.count() - 1, tip, Qt.ItemDataRole.ToolTipRole)
        try:
            ports = available_ports()
        except Exception:  # noqa: BLE001 - listing ports must never break the panel
            ports = []
        for port in ports:
            self.port_combo.addItem(port.device, port.device)
            self.port_combo.setItemData(self.port_combo.count() - 1, port.description, Qt.ItemDataRole.ToolTipRole)
        from lfstudio.studio.kinds import rig_kinds

        for kind in rig_kinds().values():      # the kinds whose word names its device (dryve:, canopen:, plugins')
            if kind.catch_all or not kind.argument or kind.simulated:
                continue
            self.port_combo.addItem(f"{kind.name}:", f"{kind.name}:")
            self.port_combo.setItemData(self.port_combo.count() - 1, f"{kind.label or kind.name}: type its "
                                        f"{kind.argument} after the colon ({kind.origin})",
                                        Qt.ItemDataRole.ToolTipRole)
        remembered = _port_word(read_text("rig/port", ""))
        if self.state.simulated and not current:      # the simulated studio: a simulated rig, the one used last
            wanted = remembered if remembered in simulated_words() else "sim"
        else:
            wanted = current or remembered
        index = self.port_combo.findData(wanted) if wanted else -1
        if index >= 0:
            self.port_combo.setCurrentIndex(index)
        elif wanted:
            self.port_combo.setEditText(wanted)

    def chosen_port(self) -> str:
        """The port to connect to: a device path or a device word ("sim": the built-in simulated GRBL
        controller, "sim-dryve": the emulated drive pair), whether picked from the list or typed."""
        text = self.port_combo.currentText().strip()
        index = self.port_combo.findText(text)
        if index >= 0 and self.port_combo.itemData(index):
            return str(self.port_combo.itemData(index))
        return _port_word(text)

    def _port_chosen(self, _index: int = -1) -> None:
        """A port picked from the list: the rig profile follows it when it does not fit (as on the CLI)."""
        if self.device is None:
            self._fit_profile_to_port(self.chosen_port())

    def _fit_profile_to_port(self, port: str, remembered: bool = False) -> bool:
        """Choose the rig profile that fits ``port`` when the chosen one does not, as the command line
        does: the preset drive pair for the simulated drives, the reference gantry for a GRBL controller
        (a serial port, the simulated GRBL). Said in the panel (never a message box); ``remembered``: the
        pair came from the last session. False when the operator must choose (a pair of real drives
        and a GRBL profile: lfstudio never guesses a real rig's feed constants)."""
        from lfstudio.studio.devices import RigSpec, drive_profile_names, implied_rig_profile

        try:
            spec = RigSpec.parse(port)
        except LfError:
            return True                  # not a device word yet: the connection says what is wrong
        for_drives = self.rig_config.driver == "cia402"
        if spec.drives == for_drives:
            return True
        where = self.port_combo.currentText().strip() or port
        old = self.rig_config.name
        if spec.drives and not spec.info.profile:          # real drives: their profile is never guessed
            names = drive_profile_names()
            self._show_message(f"Port {where} is a pair of CiA 402 drives and the rig profile {old!r} is for a "
                               "GRBL controller: choose the drives' own profile in the Rig list"
                               + (f" ({' or '.join(repr(n) for n in names)})" if names else
                                  " (add it to rigs.toml with driver = \"cia402\": lfstudio never guesses a real "
                                  "rig's feed constants)"), "error")
            return False
        name = implied_rig_profile(spec)
        self._fitting = True
        try:
            self.rig_combo.setCurrentText(name)
        finally:
            self._fitting = False
        if self.rig_config.name != name:       # the preset could not be read: _rig_chosen said why
            return False
        kind = "CiA 402 drives" if for_drives else "a GRBL controller"
        self._show_profile_note(f"Rig profile {name!r} chosen for port {where}: "
                                + (f"the one remembered from last time, {old!r}, is for {kind}." if remembered
                                   else f"{old!r} is for {kind}."))
        return True

    def _options_form(self, port: str) -> KindForm | None:
        """The Options form of the kind ``port`` names (None: not a device word yet, or a kind without
        options), made the first time it is needed. Its kind's name is enough: 'dryve:' as the Port
        list offers it, before its addresses are typed, has the drives' options."""
        from lfstudio.studio.kinds import rig_word

        try:
            kind, _argument = rig_word(port)
        except LfError:
            return None
        if kind.options is None:
            return None
        form = self.option_forms.get(kind.name)
        if form is None:
            form = self.option_forms[kind.name] = KindForm(kind, argument=False)
            self.options_stack.addWidget(form)
            tab_after(self.options_button, form)      # made late, its fields were last in the panel's tab order
        return form

    def _show_options(self, _text: str = "") -> None:
        """The Options button and form follow the port's kind."""
        form = self._options_form(self.chosen_port())
        if form is not None:
            self.options_stack.setCurrentWidget(form)
            self.options_button.setText(f"Options: {form.kind.label or form.kind.name}")
            self.options_button.setToolTip("Connection options of this kind of rig (empty: its default); used at "
                                           "the next Connect")
        else:
            self.options_button.setText("Options: none for this port")
            self.options_button.setToolTip("This kind of rig has no connection options")
        self.options_button.setEnabled(form is not None)
        self.options_stack.setVisible(form is not None and self.options_button.isChecked())

    def _toggle_options(self, shown: bool) -> None:
        self.options_button.setArrowType(Qt.ArrowType.DownArrow if shown else Qt.ArrowType.RightArrow)
        self.options_stack.setVisible(shown and self.options_button.isEnabled())

    def _show_profile_note(self, text: str) -> None:
        self.profile_note.setText(text)
        self.profile_note.setVisible(bool(text))

    def toggle_connection(self) -> None:
        if self.connected:
            self.disconnect_rig()
        else:
            self.connect_rig()

    def connect_rig(self) -> None:
        """Start the simulator if chosen, then connect on the device thread."""
        from lfstudio.studio.devices import open_rig

        if self.connected or self.borrowed is not None:     # the Scan panel's own rig is the window's now
            return
        port = self.chosen_port()
        if not self._fit_profile_to_port(port):
            self.state.show_status("Rig: choose the rig profile of these drives in the Rig panel", 10000)
            return
        try:
            form = self._options_form(port)
            options = form.options() if form is not None else {}
        except LfError as exc:              # a field of the Options form, named by its label
            self._show_message(f"{window_message(exc)} (Options of the port)", "error")
            return
        settings().setValue("rig/port", port)
        if form is not None:
            form.save()
        try:   # the simulator for "sim"; the port locked for this window (refused while another process has it)
            self.link = open_rig(port, self.rig_config, doing="the lfstudio window", time_scale=self.sim_time_scale,
                                 connect=False, **options)
        except LfError as exc:
            self._show_message(window_message(exc), "error")
            self.state.report_error("Rig", window_message(exc))
            return
        self.simulator = self.link.simulator
        if self.simulator is not None:
            self.state.set_device("rig_simulator", self.simulator)
        controller = self.link.controller
        worker = DeviceWorker(controller, name="rig", publish_hz=10,
                              error_snapshot=lambda message: RigStatus(RigState.DISCONNECTED, message=message))
        self.device = QtDevice(worker)
        self.device.statusChanged.connect(self._on_status)
        self.device.busyChanged.connect(lambda _busy: self._update_enabled())
        self._show_message(f"Connecting to {port if port not in simulated_words() else self.port_combo.currentText()} …",
                           "warning")
        self.connect_button.setText("Disconnect")
        self.connect_action.setText("Dis&connect rig")
        self.device.run("connect", on_result=lambda _r: self._connected(port),
                        on_error=self._connect_failed)
        self.state.set_device("rig", self.device)
        self.state.set_device("rig_link", self.link)
        self._update_enabled()

    def _connected(self, port: str) -> None:
        if self.message_label.text().startswith("Connecting to "):
            self._show_message("")      # only its own line: the first status (an alarm) may be here first
        self.state.show_status(f"Rig connected ({self.port_combo.currentText().strip() or port})")
        self.connectedChanged.emit(True)

    def _connect_failed(self, message: str) -> None:
        self.disconnect_rig()
        self._show_message(message, "error")
        self.state.report_error("Rig", message)

    def disconnect_rig(self) -> None:
        device, self.device = self.device, None
        link, self.link = self.link, None
        # the simulator and the port's lock, once the worker has disconnected (never waited for here)
        close_link = None if link is None else (lambda: link.close(disconnect=False))
        if device is not None:
            device.stop_now()
            device.close(disconnect=True, then=close_link)
            self._retired.append(device)   # released with the panel, on the GUI thread
        elif close_link is not None:
            close_link()
        self.simulator = None
        self.state.set_device("rig", None)
        self.state.set_device("rig_simulator", None)
        self.state.set_device("rig_link", None)
        self.connect_button.setText("Connect")
        self.connect_action.setText("&Connect rig")
        self.last_status = None
        self._on_status(RigStatus(RigState.DISCONNECTED))
        self.connectedChanged.emit(False)

    def shutdown(self) -> None:
        self._hold_timer.stop()
        if self.device is not None or self.link is not None:
            self.disconnect_rig()

    # -- commands ----------------------------------------------------------------------------------
    def _run(self, method: str, *args, done_message: str = "", **kwargs) -> None:
        if self.device is None:
            self._show_message("Connect the rig first (Rig ▸ Connect rig)", "error")
            return
        self._show_message("")

        def ok(_result) -> None:
            if done_message:
                self.state.show_status(done_message)

        self.device.run(method, *args, on_result=ok, on_error=self._command_failed, **kwargs)

    def _command_failed(self, message: str) -> None:
        self._show_message(message, "error")
        self.state.show_status(f"Rig: {message.splitlines()[0]}", 10000)

    def stop(self) -> None:
        """STOP: the driver's stop dispatched at once on its own thread (never queued), queued commands
        dropped."""
        self._hold_timer.stop()
        self._pressed = None
        self._continuous = False
        self.diagram.set_target(None)
        device = self.device if self.device is not None else self.borrowed
        if device is not None:
            device.stop_now()
            self.state.show_status("Rig: STOP", 5000)
        self.state.stopRequested.emit()        # a rig no panel holds yet (a scan being prepared) stops too

    def home(self) -> None:
        self._run("home", done_message="Rig homed")

    def set_origin(self) -> None:
        self._run("set_origin", done_message="Rig origin set here")

    def recover(self) -> None:
        st = self.last_status
        if self.device is None:
            self.connect_rig()
        elif st is not None and st.state is RigState.ALARM and isinstance(st.extra, dict) and "power_state" in st.extra:
            self._run("reset", done_message="Drive fault reset: home the rig before moving")
        elif st is not None and st.state is RigState.DISCONNECTED:
            if self.simulator is not None and not self.simulator.running:
                self.disconnect_rig()          # the simulated port vanished: start a new one
                self.connect_rig()
            else:
                self._run("connect", done_message="Rig reconnected: home it (or set the origin) before moving")
        elif self.rig_config.homing:
            self._run("home", done_message="Rig homed")
        else:
            self._run("unlock", done_message="Rig unlocked: set the origin before moving")

    def keep_reference(self) -> None:
        """CiA 402 drives: accept the position the drives report as the reference (logged by the driver)."""
        self._run("accept_reference", done_message="Rig: reference kept from the drives (not homed by lfstudio)")

    def go_to(self) -> None:
        x, y = self.goto_x.value(), self.goto_y.value()
        self.diagram.set_target((x, y))
        self._run("move_to", x, y, done_message=f"Rig at ({x:g}, {y:g}) mm")

    @property
    def step_mm(self) -> float:
        b = self.step_group.checkedButton()
        return float(b.property("step_mm")) if b is not None else 1.0

    def jog_step(self, dx: int, dy: int, step_mm: float | None = None) -> None:
        step = self.step_mm if step_mm is None else step_mm
        self._run("jog", dx * step, dy * step)

    def _jog_pressed(self, direction: tuple[int, int]) -> None:
        self._pressed = direction
        self._continuous = False
        self._hold_timer.start(HOLD_MS)

    def _start_continuous(self) -> None:
        if self._pressed is None or self.device is None:
            return
        self._continuous = True
        dx, dy = self._pressed
        far = 1e6                                  # clamped to the soft limit by the driver
        h, v = self.rig_config.horizontal, self.rig_config.vertical
        fraction = {0.1: 0.05, 1.0: 0.2, 10.0: 0.5, 100.0: 1.0}.get(self.step_mm, 0.5)
        speed = fraction * (h.max_speed_mm_s if dx else v.max_speed_mm_s)
        self._run("jog", dx * far, dy * far, speed_mm_s=speed)

    def _jog_released(self) -> None:
        direction, self._pressed = self._pressed, None
        if self._hold_timer.isActive():
            self._hold_timer.stop()
            if direction is not None:
                self.jog_step(*direction)
        elif self._continuous:
            self._continuous = False
            if self.device is not None:
                self._run("jog_cancel")

    def keyPressEvent(self, event) -> None:  # noqa: N802
        keys = {Qt.Key.Key_Left: (-1, 0), Qt.Key.Key_Right: (1, 0), Qt.Key.Key_Up: (0, -1), Qt.Key.Key_Down: (0, 1)}
        direction = keys.get(event.key())
        if direction is None:
            super().keyPressEvent(event)
            return
        event.accept()
        if self.state.scan_owns_rig:                  # the scan has the rig: say so, send nothing
            self.state.show_status(self.state.motion_lock_reason(), 8000)
            return
        if event.isAutoRepeat() and self.device is not None and self.device.busy:
            return                                # don't pile up steps while the rig is busy
        fine = bool(event.modifiers() & Qt.KeyboardModifier.ShiftModifier)
        self.jog_step(*direction, step_mm=FINE_STEP_MM if fine else None)

    def _follow_published(self, name: str) -> None:
        """A rig this panel did not connect, published as the window's rig (``state.devices["rig"]``: the
        Scan panel's own simulated studio while its scan lasts): its status and position show here and
        STOP reaches it; the motion controls stay off (it is the scan's) and Connect waits until it is
        gone, so no other rig takes its place while its scan is paused. Once it is gone the panel shows
        no device again."""
        if name != "rig":
            return
        device = self.state.devices.get("rig")
        if (device is not None and device is self.device) or device is self.borrowed:
            return
        old, self.borrowed = self.borrowed, None
        if old is not None:
            try:
                old.statusChanged.disconnect(self._on_status)
            except (RuntimeError, TypeError):
                pass
        self.borrowed_label.setVisible(False)
        if isinstance(device, QtDevice) and self.device is None:
            self.borrowed = device
            device.statusChanged.connect(self._on_status)
            self.borrowed_label.setVisible(True)
            if isinstance(device.latest, RigStatus):
                self._on_status(device.latest)
            else:
                self._update_enabled()
        elif old is not None and self.device is None:
            self.last_status = None
            self._on_status(RigStatus(RigState.DISCONNECTED))

    # -- status ------------------------------------------------------------------------------------
    def _on_status(self, snapshot: Any) -> None:
        if isinstance(snapshot, DeviceFault):
            snapshot = RigStatus(RigState.DISCONNECTED, message=snapshot.message)
        if not isinstance(snapshot, RigStatus):
            return
        self.last_status = snapshot
        self._show_warnings(snapshot.extra.get("warnings") if isinstance(snapshot.extra, dict) else None,
                            drives=isinstance(snapshot.extra, dict) and "power_state" in snapshot.extra)
        if snapshot.position_mm is not None:
            self.x_label.setText(f"{snapshot.position_mm[0]:.3f}")
            self.y_label.setText(f"{snapshot.position_mm[1]:.3f}")
        else:
            self.x_label.setText("—")
            self.y_label.setText("—")
        kept = isinstance(snapshot.extra, dict) and snapshot.extra.get("reference") == "kept"
        word = ("reference kept\nfrom the drive" if kept else "homed") \
            if snapshot.state is RigState.IDLE and snapshot.homed else snapshot.state.value
        text = word + ("" if snapshot.homed or snapshot.state is RigState.DISCONNECTED else "\nnot homed")
        self.state_label.setText(text)
        colour = _STATE_COLOURS.get(snapshot.state, "#333")
        if snapshot.state is RigState.IDLE and not snapshot.homed:
            colour = NOT_HOMED_COLOUR           # idle but not homed: not ready, not green (as the STOP bar's badge)
        self.state_label.setStyleSheet(f"color: white; background: {colour}; border-radius: 4px; "
                                       "padding: 4px 8px; font-weight: 600;")
        self.diagram.set_position(snapshot.position_mm)
        if snapshot.state is RigState.IDLE and snapshot.position_mm is not None and self.diagram.target_mm:
            tx, ty = self.diagram.target_mm
            if abs(tx - snapshot.position_mm[0]) < 0.05 and abs(ty - snapshot.position_mm[1]) < 0.05:
                self.diagram.set_target(None)
        problem = snapshot.state in (RigState.ALARM, RigState.DISCONNECTED) and self.device is not None
        # the Home button already recovers an alarm on a rig with switches
        drives = snapshot.extra.get("power_state") if isinstance(snapshot.extra, dict) else None
        self._show_drives(drives, snapshot.extra.get("fault_code") if drives else None,
                          snapshot.extra.get("homing") if drives else None)
        drive_fault = snapshot.state is RigState.ALARM and isinstance(drives, dict)
        show_recover = problem and (snapshot.state is RigState.DISCONNECTED or not self.rig_config.homing or drive_fault)
        if problem:
            self._show_message(snapshot.message or snapshot.state.value, "error")
            self._problem_shown = self.message_label.text()
        elif self._problem_shown and self.message_label.text() == self._problem_shown:
            self._show_message("")          # the alarm or lost connection it named is over
            self._problem_shown = ""
        elif snapshot.message and not self.message_label.text():
            self._show_message(snapshot.message, "warning")
        elif not snapshot.message and self.message_label.property("role") == "warning":
            self._show_message("")
        self.recover_button.setVisible(show_recover)
        if show_recover:
            self.recover_button.setText("Reconnect" if snapshot.state is RigState.DISCONNECTED else
                                        "Reset fault" if drive_fault else "Unlock")
        self._update_enabled()

    def _show_drives(self, power: Any, codes: Any, homing: Any = None) -> None:
        """CiA 402 drives: "x: operation enabled · y: fault 8611h" (hidden for other controllers); while
        they home, each one's progress ("x: operation enabled, homing · y: …, at reference")."""
        text = ""
        if isinstance(power, dict):
            codes = codes if isinstance(codes, dict) else {}
            homing = homing if isinstance(homing, dict) else {}
            text = "Drives — " + " · ".join(
                f"{axis}: {str(state).lower()}" + (f" {codes.get(axis)}" if codes.get(axis, "0000h") != "0000h" else "")
                + (f", {homing[axis]}" if axis in homing else "")
                for axis, state in power.items())
        if text != self.drive_label.text():
            self.drive_label.setText(text)
            self.drive_label.setVisible(bool(text))

    def _show_warnings(self, warnings: Any, drives: bool = False) -> None:
        """The controller-vs-profile warnings of the latest status; none: hidden. The first
        :data:`WARNINGS_SHOWN` are in the line (a dock has little height), all of them in its tooltip."""
        lines = [str(w) for w in warnings if str(w).strip()] if isinstance(warnings, (list, tuple)) else []
        bullets = [f"• {line}" for line in lines]
        head = "⚠ The drives and the rig profile:" if drives else "⚠ Controller and rig profile disagree:"
        text = "" if not lines else "\n".join([head, *bullets[:WARNINGS_SHOWN]])
        if len(lines) > WARNINGS_SHOWN:
            text += f"\n… and {len(lines) - WARNINGS_SHOWN} more (point here to read them all)"
        if text != self.warning_label.text():
            self.warning_label.setText(text)
            self.warning_label.setVisible(bool(text))
            self.warning_label.setToolTip("\n".join([WARNINGS_TIP, "", *bullets]) if lines else WARNINGS_TIP)

    def _on_scan_state(self, scan_state: Any) -> None:
        """A scan starting ends what an earlier command's failure said ("stopped by STOP", ...):
        problems the rig still has are shown again by its status."""
        if self.state.scan_owns_rig and self.message_label.property("role") == "error" \
                and self.message_label.text() != self._problem_shown:
            self._show_message("")
        self._update_enabled()

    def _show_message(self, text: str, role: str = "error") -> None:
        self.message_label.setText(text)
        if self.message_label.property("role") != role:
            self.message_label.setProperty("role", role)
            self.message_label.style().unpolish(self.message_label)
            self.message_label.style().polish(self.message_label)

    def _update_enabled(self) -> None:
        st = self.last_status
        rig_state = RigState.DISCONNECTED if st is None else st.state
        free = not self.state.scan_owns_rig
        live = self.device is not None and rig_state is not RigState.DISCONNECTED
        can_move = free and live and st is not None and st.homed and rig_state in (RigState.IDLE, RigState.JOGGING)
        self.port_combo.setEnabled(self.device is None)
        self.rig_combo.setEnabled(self.device is None)
        self.options_stack.setEnabled(self.device is None)        # used at Connect: fixed while connected
        self.refresh_button.setEnabled(self.device is None)
        self.connect_button.setEnabled(free and self.borrowed is None)
        self.connect_action.setEnabled(free and self.borrowed is None)
        self.home_button.setEnabled(free and live and self.rig_config.homing)
        self.home_action.setEnabled(free and live and self.rig_config.homing)
        self.origin_button.setEnabled(free and live and rig_state is RigState.IDLE)
        self.origin_action.setEnabled(free and live and rig_state is RigState.IDLE)
        self.recover_button.setEnabled(free)
        self.recover_action.setEnabled(free and self.device is not None)
        drives = st is not None and isinstance(st.extra, dict) and "power_state" in st.extra
        can_keep = free and live and drives and st is not None and not st.homed and rig_state is not RigState.ALARM
        self.keep_button.setVisible(drives and st is not None and not st.homed)
        self.keep_button.setEnabled(can_keep)
        self.keep_action.setEnabled(can_keep)
        for b in self.jog_buttons.values():
            b.setEnabled(can_move or (free and b.isDown() and live))
        self.goto_button.setEnabled(can_move)
        self._show_lock(self.state.motion_lock_reason())

    def _show_lock(self, reason: str) -> None:
        """The lock note and the "why disabled" tooltips, when the scan takes or gives back the rig."""
        if reason == self._lock_shown:
            return
        self._lock_shown = reason
        locked = bool(reason)
        if locked:
            self._hold_timer.stop()
            self._pressed = None
        show_lock_note(self.lock_label, self._base_tips, reason,
                       f"<b>Rig locked by {self.state.scan_label or 'the scan'}</b>: motion controls return when "
                       "it ends or is paused. STOP (Esc) always works.")
