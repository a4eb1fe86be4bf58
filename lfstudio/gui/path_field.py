"""Folders and files typed into the GUI: read by :func:`lfstudio.dataset.paths.expand_path`, the same
reading as the command line's (``~`` and ``$VARIABLES`` expanded), and shown as the absolute path
they mean as soon as the operator leaves the field, so what will be written where is in sight.
"""

from __future__ import annotations

from pathlib import Path

from PySide6.QtWidgets import QLineEdit

from lfstudio.dataset.paths import expand_path
from lfstudio.errors import InputError


def field_path(edit: QLineEdit, field: str) -> Path:
    """The absolute path typed in ``edit`` (shown in it from now on); :class:`InputError` naming
    ``field`` when it is empty or uses an unset variable."""
    path = expand_path(edit.text(), field, absolute=True)
    if edit.text() != str(path):
        edit.setText(str(path))
    return path


def expand_on_edit(edit: QLineEdit, field: str) -> None:
    """Show the absolute path in ``edit`` whenever its editing ends (Enter, Tab, a click elsewhere).
    Text that names no path yet (empty, an unset variable) is left as typed: the action that uses
    it says what is wrong."""
    def expand() -> None:
        try:
            field_path(edit, field)
        except InputError:
            pass
    edit.editingFinished.connect(expand)
