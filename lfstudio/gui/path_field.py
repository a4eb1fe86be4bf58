"""Folders and files typed into the GUI: read by :func:`lfstudio.dataset.paths.expand_path`, the same
reading as the command line's (``~`` and ``$VARIABLES`` expanded), and shown as the absolute path
they mean as soon as the operator leaves the field, so what will be written where is in sight.

:func:`offer_sub_folder` is the one question asked when a folder chosen for a new dataset holds other
files (the rule: :func:`lfstudio.dataset.paths.check_new_dataset_folder`): use a new sub-folder of it,
or choose another folder; nothing is written into the chosen folder either way.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from PySide6.QtWidgets import QLineEdit, QMessageBox, QWidget

from lfstudio.dataset.paths import expand_path, new_dataset_folder_problem, new_sub_folder
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


def offer_sub_folder(parent: QWidget, folder: Path, *, stem: str, verb: str, where: str,
                     accepted: Callable[[Path], None]) -> QMessageBox:
    """Ask (non-modal: the event loop keeps running) whether the new dataset goes into a new
    sub-folder of ``folder``, which holds other files; ``accepted(sub_folder)`` runs on Yes, Cancel
    does nothing. ``verb`` names the action on the button ("Scan" → "Scan into lfstudio-scan"),
    ``where`` the field to change instead. The box (object name ``folderNotEmptyBox``) is returned."""
    sub = new_sub_folder(folder, stem)
    problem = new_dataset_folder_problem(folder)
    box = QMessageBox(QMessageBox.Icon.Warning, "Folder is not empty",
                      f"{problem}.\n\n{verb} into the new folder {sub} instead, or choose an empty folder "
                      f"({where}).", QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.Cancel, parent)
    box.setObjectName("folderNotEmptyBox")
    box.button(QMessageBox.StandardButton.Yes).setText(f"{verb} into {sub.name}")
    box.setDefaultButton(QMessageBox.StandardButton.Cancel)

    def answered(button) -> None:
        if box.standardButton(button) == QMessageBox.StandardButton.Yes:
            accepted(sub)
    box.buttonClicked.connect(answered)
    box.open()
    return box
