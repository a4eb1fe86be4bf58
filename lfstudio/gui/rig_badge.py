"""The rig's state in the window's STOP toolbar, visible with every panel layout (the Rig panel may be
a tab behind the Planner, closed or floating on another screen).

One word an operator acts on — **disconnected**, **not homed**, **homing**, **homed**, **reference
kept from the drive** (CiA 402 drives whose own reference the operator kept without homing),
**moving**, **hold**, **alarm**, **fault** — coloured like the Rig panel's state, with the position and the
controller's message in the tooltip. Homing is announced in the status bar when it starts and when it
ends, wherever it was asked for (Rig → Home, the Rig panel, a scan that homes first). Clicking the
badge shows the Rig panel.
"""

from __future__ import annotations

from typing import Any

from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import QToolButton, QWidget

from lfstudio.rig.motion import RigState, RigStatus
from lfstudio.rig.worker import DeviceFault

#: word → background colour (the Rig panel's colours: green fine, blue moving, orange attention, red stop)
KEPT = "reference kept from the drive"
BADGE_COLOURS = {"disconnected": "#6b7280", "not homed": "#b35900", "homing": "#1565c0", "homed": "#2e7d32",
                 KEPT: "#00695c", "moving": "#1565c0", "hold": "#b35900", "alarm": "#b00020", "fault": "#b00020"}


MOVES = ("move_to", "jog")     # device calls that move the rig (shown as "moving" while they run)


def badge_word(status: Any, homing: bool = False, moving: bool = False) -> str:
    """The badge's word for a rig snapshot (None: no rig connected). ``homing``: a home command is
    running (the controller may report Idle between its phases); ``moving``: a move command is."""
    if isinstance(status, DeviceFault):
        return "fault"
    if not isinstance(status, RigStatus) or status.state is RigState.DISCONNECTED:
        return "disconnected"
    if homing:                             # a home command runs (from an alarm lock too)
        return "homing"
    if status.state is RigState.ALARM:
        extra = status.extra if isinstance(status.extra, dict) else {}
        if not status.homed and extra.get("locked") and extra.get("alarm_code") is None:
            return "not homed"             # a controller with homing boots locked until homed: no fault
        return "alarm"
    if status.state is RigState.HOMING:
        return "homing"
    if status.state in (RigState.MOVING, RigState.JOGGING) or (moving and status.state is not RigState.HOLD):
        return "moving"
    if status.state is RigState.HOLD:
        return "hold"
    if status.homed and isinstance(status.extra, dict) and status.extra.get("reference") == "kept":
        return KEPT
    return "homed" if status.homed else "not homed"


class RigBadge(QToolButton):
    """``Rig: <word>`` for ``state.devices["rig"]``; follows the device as it is connected or removed.
    ``wordChanged(word)`` when the word changes."""

    wordChanged = Signal(str)

    def __init__(self, state, show_rig_panel=None, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.setObjectName("rigBadge")
        self.setAutoRaise(True)
        self.setFocusPolicy(Qt.FocusPolicy.NoFocus)
        self._device: Any = None
        self._status: Any = None
        self._homing = False
        self._moves = 0                  # move calls running
        self.word = ""
        if show_rig_panel is not None:
            self.clicked.connect(show_rig_panel)
        state.devicesChanged.connect(self._devices_changed)
        self._show()
        self._devices_changed("rig")

    def _devices_changed(self, name: str) -> None:
        if name != "rig":
            return
        device = self.state.devices.get("rig")
        if device is self._device:
            return
        if self._device is not None:
            for signal, slot in ((self._device.statusChanged, self._on_status),
                                 (self._device.callStarted, self._call_started),
                                 (self._device.callFinished, self._call_finished),
                                 (self._device.callFailed, self._call_failed)):
                try:
                    signal.disconnect(slot)
                except (RuntimeError, TypeError):
                    pass
        self._device, self._homing, self._moves = device, False, 0
        self._status = None if device is None else device.latest
        if device is not None:
            device.statusChanged.connect(self._on_status)
            device.callStarted.connect(self._call_started)
            device.callFinished.connect(self._call_finished)
            device.callFailed.connect(self._call_failed)
        self._show()

    def _on_status(self, status: Any) -> None:
        self._status = status
        self._show()

    def _call_started(self, name: str) -> None:
        if name in MOVES:
            self._moves += 1
            self._show()
        if name == "home":
            self._homing = True
            self.state.show_status("Rig: homing … (STOP: Esc)", 0)
            self._show()

    def _call_finished(self, name: str, _result: Any) -> None:
        if name in MOVES:
            self._moves = max(0, self._moves - 1)
            self._show()
        if name == "home":
            self._homing = False
            self.state.show_status("Rig homed", 8000)
            self._show()

    def _call_failed(self, name: str, message: str) -> None:
        if name in MOVES:
            self._moves = max(0, self._moves - 1)
            self._show()
        if name == "home":
            self._homing = False
            self.state.show_status(f"Rig: homing failed: {message.splitlines()[0] if message else ''}", 15000)
            self._show()

    def _show(self) -> None:
        word = badge_word(self._status if self._device is not None else None, self._homing, self._moves > 0)
        changed, self.word = word != self.word, word
        self.setText(f"Rig: {word}")
        self.setStyleSheet(f"QToolButton {{ color: white; background: {BADGE_COLOURS[word]}; border-radius: 4px;"
                           " padding: 2px 8px; font-weight: 600; }")
        tip = [f"The rig is {word}."]
        status = self._status
        if isinstance(status, RigStatus) and status.position_mm is not None and self._device is not None:
            tip.append(f"Position {status.position_mm[0]:.3f}, {status.position_mm[1]:.3f} mm.")
        message = getattr(status, "message", "") if self._device is not None else ""
        if message:
            tip.append(message)
        drives = isinstance(status, RigStatus) and isinstance(status.extra, dict) and "power_state" in status.extra
        if word == "not homed":
            tip.append("Home it (Rig → Home, Ctrl+H) before jogging or scanning" +
                       (", or keep the drives' own reference (Rig → Keep the drives' reference) if they were "
                        "homed before and kept it." if drives else "."))
        elif word == KEPT:
            tip.append("The operator kept the drives' own reference: lfstudio did not home them on this "
                       "connection. Home the rig when in doubt.")
        elif word == "disconnected":
            tip.append("Connect it with Rig → Connect rig.")
        tip.append("Click to show the Rig panel.")
        self.setToolTip("\n".join(tip))
        if changed:
            self.wordChanged.emit(word)
