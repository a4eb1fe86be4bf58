"""Every error lfstudio reports carries a stable ``kind`` (lfstudio/errors.py): each error type of the
core states its own, and they are the ones listed here (a renamed kind breaks the code and tests that
tell errors apart by it, so changing one is a decision, made here)."""

from __future__ import annotations

import importlib
import pkgutil
import re

import lfstudio
from lfstudio.errors import LfError

KINDS = {
    "lfstudio.errors.LfError": "error",
    "lfstudio.errors.InputError": "input",
    "lfstudio.errors.DatasetError": "dataset",
    "lfstudio.errors.DatasetNotFound": "dataset-not-found",
    "lfstudio.errors.DeviceError": "device",
    "lfstudio.errors.DeviceTimeout": "device-timeout",
    "lfstudio.errors.DeviceRefused": "device-refused",
    "lfstudio.dataset.images.NotACapture": "not-a-capture",
    "lfstudio.dataset.frames.UnstorableFrame": "unstorable-frame",
    "lfstudio.dataset.storage.StorageError": "error",      # each instance: full, read-only, not writable, failing
    "lfstudio.rig.motion.SoftLimitError": "soft-limit",
    "lfstudio.rig.worker.CallTimedOut": "call-timed-out",
    "lfstudio.rig.worker.DeviceBusy": "device-busy",
    "lfstudio.rig.grbl_protocol.GrblError": "controller-error",
    "lfstudio.rig.grbl_protocol.GrblAlarm": "alarm",
    "lfstudio.rig.grbl_protocol.ConnectionLost": "connection-lost",
    "lfstudio.rig.grbl_protocol.MotionStopped": "motion-stopped",
    "lfstudio.rig.grbl_protocol.PositionError": "position",
    "lfstudio.rig.cia402.DriveNotAnswering": "drive-not-answering",
    "lfstudio.rig.cia402.ExchangeInterrupted": "exchange-interrupted",   # a slow drive's exchange cut by STOP
    "lfstudio.rig.cia402.ObjectAccessRefused": "object-access-refused",
    "lfstudio.rig.cia402.DriveFault": "drive-fault",
    "lfstudio.rig.cia402.MotionStopped": "motion-stopped",
    "lfstudio.rig.cia402.PositionError": "position",
    "lfstudio.rig.cia402.MissingObject": "missing-object",
    "lfstudio.rig.cia402.UnitsMismatch": "units",
    "lfstudio.support.locks.LockBusy": "busy",
    "lfstudio.support.locks.NotALockFile": "not-a-lock-file",
    "lfstudio.scan.faults.ScanFault": "scan-fault",
    "lfstudio.scan.events.ScanRequestRefused": "request-refused",
    "lfstudio.scan.preflight.ScanTooLarge": "scan-too-large",
    "lfstudio.calibration.fit.CalibrationError": "calibration",
    "lfstudio.studio.session.RigNotHomed": "rig-not-homed",
    "lfstudio.studio.session.RigUsedSince": "rig-used-since",
    "lfstudio.studio.session.RigNotWhereLeft": "rig-not-where-left",
    "lfstudio.studio.session.DeviceChangeRefused": "device-change-refused",
}


def _error_types() -> dict[str, type]:
    """Every LfError type defined in the core (lfstudio minus gui), by its dotted name."""
    for info in pkgutil.walk_packages(lfstudio.__path__, "lfstudio."):
        if not info.name.startswith("lfstudio.gui") and info.name != "lfstudio.__main__":
            importlib.import_module(info.name)
    found: dict[str, type] = {}
    todo = [LfError]
    while todo:
        cls = todo.pop()
        if cls.__module__.startswith("lfstudio.") and not cls.__module__.startswith("lfstudio.gui"):
            found[f"{cls.__module__}.{cls.__qualname__}"] = cls
        todo.extend(cls.__subclasses__())
    return found


def test_every_error_type_states_its_kind_and_it_is_the_listed_one():
    types = _error_types()
    assert {name: cls.kind for name, cls in types.items()} == KINDS
    for name, cls in types.items():
        assert re.fullmatch(r"[a-z]+(-[a-z]+)*", cls.kind), name
        if name != "lfstudio.dataset.storage.StorageError":     # its instances say which storage fault
            assert "kind" in vars(cls), f"{name} inherits its kind: give it its own"


def test_a_storage_errors_kind_is_the_fault():
    import errno

    from lfstudio.dataset.storage import storage_error

    assert storage_error(OSError(errno.ENOSPC, "No space left on device"), "/tmp/x", doing="writing").kind == "full"
    assert storage_error(OSError(errno.EROFS, "Read-only file system"), "/tmp/x", doing="writing").kind == "read-only"
