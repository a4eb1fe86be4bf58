"""What pauses a scan: :class:`ScanFault` (a device's or the disk's fault with the operator's fix) and
what clears each kind by itself (auto-resume). Shared by the engine thread (``scan/engine.py``) and
the store stage (``scan/store.py``)."""

from __future__ import annotations

from lfstudio.errors import DeviceTimeout, LfError
from lfstudio.rig.grbl_protocol import ConnectionLost
from lfstudio.rig.worker import CallTimedOut

#: what the operator does about a device's fault
FIX = {"rig": "Check the axis controller's cable, power and alarms, reconnect it, then Resume.",
       "camera": "Check the camera's cable, power, battery and card, reconnect it, then Resume.",
       "disk": "Free disk space or choose another folder, then Resume."}
#: what clears each kind of fault that can clear without a person (ScanFault.clears)
CLEARS_DISK = "there is free disk space again"
CLEARS_CAMERA = "the camera answers again"
CLEARS_RIG = "the axis controller answers again"


def clears_by_itself(device: str, exc: BaseException | None = None) -> str:
    """What ends a ``device`` fault caused by ``exc`` without a person ("" when it needs one).

    A camera that fails or stops answering may be back after a reconnect (a cable, a power save). A
    rig only when its connection was lost or it stopped answering: an alarm (a limit switch, a soft
    limit, a reset that needs homing), a move stopped by STOP, a position error or a refused command
    always wait for a person."""
    if device == "camera":
        return CLEARS_CAMERA
    if device == "rig" and (exc is None or isinstance(exc, (ConnectionLost, DeviceTimeout, CallTimedOut))):
        return CLEARS_RIG
    return ""


class ScanFault(LfError):
    """A fault the operator must fix (device, disk); the scan pauses with this message.

    ``clears``: what, happening without a person, ends the fault ("" when it needs a person: STOP,
    an alarm that needs homing, a limit switch, a position error, a device held by another scan);
    with ``auto_resume`` the engine resumes by itself when it sees that (see ``ScanEngine._cleared``)."""

    kind = "scan-fault"

    def __init__(self, message: str, device: str = "", clears: str = "", need_bytes: int = 0):
        super().__init__(message)
        self.device = device
        self.clears = clears
        self.need_bytes = need_bytes  # a disk fault: the free space that clears it (0: the next view's)
        self.reconnected = False     # the auto-resume probe reconnected the device already
        self.stop_pressed = False    # the operator's STOP: they know, no alarm box (the rig may still be homed)
        self.resumable = True        # False: this dataset cannot continue as it is (its message says what to do)


def error_text(exc: BaseException) -> str:
    """An exception's message for the operator (its type's name when it has none)."""
    text = str(exc).strip()
    return text if text else type(exc).__name__


def fault_text(device: str, message: str, attempts: int) -> str:
    """The fault of a view that failed ``attempts`` times on ``device`` with ``message``, and its fix."""
    what = "Rig" if device == "rig" else "Camera" if device == "camera" else "Disk"
    return f"{what} failed {attempts} time(s): {message}. {FIX.get(device, 'Then Resume.')}"


def refused_text(device: str, where: str, message: str) -> str:
    """The fault of a device that refused what the scan asked of it (a setting out of its range, a file
    it cannot use; :class:`lfstudio.errors.DeviceRefused` or a value error) during ``where``: the cause
    and its own fix, never cable advice, and no retry (it would be refused again)."""
    what = "Rig" if device == "rig" else "Camera"
    return f"{what} refused ({where}): {message.rstrip('.')}. Fix that, then Resume."
