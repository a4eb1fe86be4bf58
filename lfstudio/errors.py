"""Errors an operator reads. Every message names the field or file and says how to fix it; every error
carries a stable ``kind`` (:attr:`LfError.kind`) for code and tests."""

from __future__ import annotations


import re

#: the marks around a part of a message each front end says in its own words (:func:`words`)
_OPEN, _SPLIT, _CLOSE = "\x1f", "\x1e", "\x1d"
_WORDS = re.compile(f"{_OPEN}([^{_OPEN}{_SPLIT}{_CLOSE}]*){_SPLIT}([^{_OPEN}{_SPLIT}{_CLOSE}]*){_CLOSE}")


def words(cli: str, window: str) -> str:
    """A part of an operator's message that the command line and the window say in their own words:
    an option (``--no-rectify``) and the control that does the same (untick *Rectification* in the
    Process dialog), a command and a menu. Put it into the message as it is built; ``str()`` of an
    :class:`LfError` and :func:`for_cli` show the command line's words, :func:`window_message` and
    :func:`for_window` the window's. The marks are control characters no one types."""
    return f"{_OPEN}{cli}{_SPLIT}{window}{_CLOSE}"


def for_cli(text: str) -> str:
    """``text`` with each :func:`words` part in the command line's words."""
    return _WORDS.sub(lambda m: m.group(1), text) if _OPEN in text else text


def for_window(text: str) -> str:
    """``text`` with each :func:`words` part in the window's words."""
    return _WORDS.sub(lambda m: m.group(2), text) if _OPEN in text else text


class LfError(Exception):
    """Base class for every error lfstudio reports to a person (CLI exit message, GUI dialog).

    ``window_text``: the message in the window's words where they differ from the command line's
    (the message names an option or command; the window names its own panels and fields instead);
    :func:`window_message` picks it.

    ``kind``: a stable word for what went wrong (``input``, ``dataset``, ``device-timeout``,
    ``soft-limit``, ``busy``, a storage error's ``full``...), for code and tests to tell errors apart
    without matching their sentences, which are written for the operator and may be reworded. Each
    error type states its own; an instance may be more precise (a storage error's
    :class:`lfstudio.dataset.storage.StorageError`). ``tests/test_errors.py`` lists them."""

    window_text: str | None = None
    kind: str = "error"

    def __str__(self) -> str:
        return for_cli(super().__str__())


def window_message(exc: BaseException) -> str:
    """What the window shows for ``exc``: its words for the window when it has them (``window_text``,
    or the window's side of each :func:`words` part), else its message."""
    explicit = getattr(exc, "window_text", None)
    if explicit:
        return for_window(explicit)
    if isinstance(exc, LfError):
        return for_window(Exception.__str__(exc))
    return str(exc)


class InputError(LfError, ValueError):
    """A value given by the user is out of range or inconsistent.

    ``field`` is the name the user knows (a CLI option or a GUI label), ``valid`` the accepted range.
    """

    kind = "input"

    def __init__(self, field: str, message: str, valid: str | None = None):
        self.field = field
        self.valid = valid
        text = f"{field}: {message}"
        if valid:
            text += f" (valid: {valid})"
        super().__init__(text)


class DatasetError(LfError):
    """A dataset folder or one of its files is missing, corrupt or inconsistent.

    ``problems`` lists every problem found as ``"file: field: what is wrong"`` strings (one problem is
    told on the message's line, several on a line each).
    """

    kind = "dataset"

    def __init__(self, message: str, problems: list[str] | None = None):
        self.problems = list(problems or [])
        text = message
        if len(self.problems) == 1:         # one problem: one line
            text += f": {self.problems[0]}"
        elif self.problems:
            text += "\n" + "\n".join(f"  - {p}" for p in self.problems)
        super().__init__(text)


class DatasetNotFound(DatasetError):
    """The path given as a dataset is not a folder or holds no ``dataset.json``: a mistake in what
    was typed (the command line exits 2, as for any bad input), not a damaged dataset."""

    kind = "dataset-not-found"


class DeviceError(LfError):
    """A device (axis controller, camera) failed, timed out or refused a command."""

    kind = "device"


class DeviceRefused(DeviceError):
    """A device cannot do what was asked, for a reason its message names with the fix (a setting out of
    the camera's range, a file whose name the image libraries cannot open): trying again does not
    help and the cable is not the cause, so a scan pauses at once with the message's own advice."""

    kind = "device-refused"


class DeviceTimeout(DeviceError):
    """A device did not answer in time (a silent camera, a controller that stopped talking): waiting
    for it again does not help, so a scan stops at once instead of retrying."""

    kind = "device-timeout"
