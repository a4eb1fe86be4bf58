"""File names inside a dataset, and THE path guard: nothing lfstudio writes, deletes or reads
under a dataset may lead outside its folder.

:func:`resolve_inside` is the one check (resolve with symlinks, contain, refuse with one line naming
the path); every stage calls it, or a helper here built on it, before it touches a file by a name
that comes from the dataset (manifest entries, ``processing.toml``'s output folder, the folders
``raw/``, ``thumbs/``, ``processed/``, ``cache/`` and files like ``calibration.json`` that may be
symlinks). :func:`check_dataset_entries` runs it on the dataset's own files and folders when a
dataset is opened, so a symlink that leads elsewhere is refused before any stage starts.

:func:`expand_path` is THE reading of a path the operator typed (GUI fields and CLI arguments alike):
``~`` and environment variables expanded, so ``~/datasets/day1`` never becomes a folder named ``~``.
:func:`check_new_dataset_folder` is THE rule for every command that creates a dataset (scan,
import-images, import-hevc, virtual-dataset; CLI and GUI alike), checked before anything is written:
a missing or empty folder is fine; a folder that already holds a dataset is refused unless the
command's own explicit option adds to it or replaces it (``--resume``, ``--overwrite``); a folder
holding other files is always refused, naming it and a new sub-folder (:func:`new_sub_folder`) as the
fix, so a new dataset never mixes with, overwrites or deletes the operator's own files. A folder whose
``dataset.lock`` a running scan holds (this process or another, :mod:`lfstudio.support.locks`) is
never replaced or reused (:func:`check_not_in_use`, also run by the importers at their final rename);
a lock left by a process that is gone is no obstacle and no "file" of the folder.
:func:`dataset_folder_kind` and :func:`new_dataset_folder_problem` are the same reading for a GUI
that asks instead of refusing.
"""

from __future__ import annotations

import os
import re
from pathlib import Path, PurePosixPath
from typing import Any

from lfstudio.errors import DatasetError, InputError, words
from lfstudio.support.locks import DATASET_LOCK_NAME, MANIFEST_LOCK_NAME, LockBusy, holder_of


def view_stem(row: int, column: int) -> str:
    """``r07_c042`` for row 7, column 42 (rows and columns count from 0): the one place a view's
    name is built (:func:`parse_view_stem` reads it back)."""
    if row < 0 or column < 0:
        raise ValueError(f"grid index must be non-negative, got row {row}, column {column}")
    return f"r{row:02d}_c{column:03d}"


def view_label(row: int, column: int) -> str:
    """``r07 c042``: how messages, progress lines and the GUI name a view (the same numbers as its
    file name, :func:`view_stem`, with a space)."""
    return f"r{row:02d} c{column:03d}"


_VIEW_STEM = re.compile(r"^\s*r(\d+)[_\s]*c(\d+)\s*$", re.IGNORECASE)


def parse_view_stem(text: str) -> tuple[int, int]:
    """(row, column) of a view name: ``r07_c042``, also typed as ``r7c42`` or ``R07 C042``;
    ValueError when ``text`` is no view name."""
    m = _VIEW_STEM.match(str(text))
    if not m:
        raise ValueError(f"{text!r} is not a view name like r07_c042")
    return int(m.group(1)), int(m.group(2))


#: the dataset's calibration file (its contents: :mod:`lfstudio.calibration.model`, which reads and writes it)
CALIBRATION_NAME = "calibration.json"
#: the dataset's own files and folders (beside the views' files): none may be a symlink leading outside
DATASET_ENTRIES = ("dataset.json", "journal.jsonl", DATASET_LOCK_NAME, MANIFEST_LOCK_NAME, CALIBRATION_NAME,
                   "processing.toml", "quality.json", "raw", "thumbs", "thumbs/generated", "processed", "cache",
                   "depth")


_VARIABLE = re.compile(r"\$(?:(\w+)|\{([^}]*)\})")


def expand_path(text: str | os.PathLike, field: str = "path", *, absolute: bool = False) -> Path:
    """The path the operator means by ``text``: ``~`` / ``~user`` become the home folder and
    ``$NAME`` / ``${NAME}`` the environment variable's value; spaces around it are dropped.

    An empty text, an unset variable or an unknown ``~user`` is refused (:class:`InputError` naming
    ``field``): left as they are they would become folders literally named ``$NAME`` or ``~user``.
    A relative path stays relative to the working folder unless ``absolute`` (what the GUI shows).
    """
    raw = os.fspath(text).strip() if isinstance(text, (str, os.PathLike)) else ""
    if not raw:
        raise InputError(field, "no path given", "a folder or file, e.g. ~/datasets/day1")
    for match in _VARIABLE.finditer(raw):
        name = match.group(1) or match.group(2)
        if name not in os.environ:
            raise InputError(field, f"{raw!r} uses the environment variable ${name}, which is not set",
                             "set it, or type the path without it")
    expanded = os.path.expanduser(os.path.expandvars(raw))
    if expanded.startswith("~"):
        user = expanded[1:].split("/", 1)[0].split(os.sep, 1)[0]
        raise InputError(field, f"{raw!r}: there is no user {user!r} whose home folder ~{user} could mean",
                         "~/… for your own home folder, or a full path")
    path = Path(expanded)
    check_path_name(path, field)
    return path.absolute() if absolute else path


def is_utf8_name(name: str | os.PathLike) -> bool:
    """True when ``name`` is valid UTF-8 text. A name read from a folder in another character encoding
    (Latin-1 ``d\xe9j\xe0``) holds surrogate escapes in Python: such a name must never reach OpenCV
    (it crashes the process), LibRaw or FFmpeg, nor a message unescaped (:func:`shown_name`)."""
    try:
        os.fspath(name).encode("utf-8")
        return True
    except UnicodeEncodeError:
        return False


def shown_name(name: str | os.PathLike) -> str:
    """``name`` as a message shows it: the bytes that are not UTF-8 as ``\\xNN`` escapes."""
    return os.fspath(name).encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


#: the fix named for a file or folder whose name is not UTF-8
RENAME_UTF8_FIX = "rename it in UTF-8, e.g. " + words("with 'convmv -f latin1 -t utf8 --notest NAME'",
                                                     "in your file manager")


def path_name_problem(path: str | os.PathLike) -> str | None:
    """Why lfstudio cannot work under ``path`` (made absolute), or None: a name that is not valid
    UTF-8 (a folder named in another encoding, e.g. Latin-1 ``d\xe9j\xe0``). Python keeps such bytes
    as surrogate escapes, which OpenCV, LibRaw and FFmpeg cannot take (OpenCV crashes on them)."""
    if is_utf8_name(path):
        return None
    shown = shown_name(path)
    return (f"'{shown}' has a name that is not valid UTF-8 (written in another character encoding), which "
            "the image and video libraries cannot open")


def check_path_name(path: str | os.PathLike, field: str) -> None:
    """:func:`path_name_problem` of ``path`` as an :class:`InputError` naming ``field`` and the fix."""
    problem = path_name_problem(Path(path).absolute())
    if problem:
        raise InputError(field, problem, "a name in UTF-8: rename the folder, e.g. with "
                                         "'convmv -f latin1 -t utf8 --notest NAME'")


#: what a folder offered for a new dataset holds (:func:`dataset_folder_kind`)
FOLDER_MISSING, FOLDER_EMPTY, FOLDER_DATASET, FOLDER_OTHERS, FOLDER_FILE = "missing", "empty", "dataset", "others", "file"


def dataset_folder_kind(folder: str | Path) -> str:
    """What ``folder`` holds, for a new dataset: :data:`FOLDER_MISSING`, :data:`FOLDER_EMPTY`
    (``dataset.lock`` alone is a scan that never started), :data:`FOLDER_DATASET` (``dataset.json``),
    :data:`FOLDER_OTHERS` (other files and no dataset) or :data:`FOLDER_FILE` (not a folder)."""
    folder = Path(folder)
    if not folder.exists() and not folder.is_symlink():
        return FOLDER_MISSING
    if not folder.is_dir():
        return FOLDER_FILE
    if (folder / "dataset.json").exists():
        return FOLDER_DATASET
    return FOLDER_OTHERS if _other_entries(folder) else FOLDER_EMPTY


def _other_entries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name not in (DATASET_LOCK_NAME, MANIFEST_LOCK_NAME))


#: the fix named when a folder for a new dataset is in use (:func:`check_not_in_use`)
IN_USE_FIX = "stop that scan there (or wait for it to finish), or choose another folder"


def check_not_in_use(folder: str | Path, fix: str = IN_USE_FIX) -> None:
    """Refuse ``folder`` while a running scan holds its ``dataset.lock`` (in this process or
    another): :class:`LockBusy` naming the folder, the holder (command, pid, what it is doing, its
    computer when another) and ``fix``. A lock whose process is gone does not count
    (:func:`lfstudio.support.locks.holder_of`)."""
    holder = holder_of(Path(folder) / DATASET_LOCK_NAME)
    if holder is not None:
        raise LockBusy(f"dataset {folder}", holder, fix)


def new_dataset_folder_problem(folder: str | Path) -> str | None:
    """Why a new dataset cannot be created in ``folder``, or None (missing or empty are fine).

    A folder that holds other files but no dataset is refused: a new dataset would mix its views,
    thumbnails and manifest into the operator's own files.
    """
    folder = Path(folder)
    kind = dataset_folder_kind(folder)
    if kind == FOLDER_FILE:
        return f"{folder} is a file, not a folder"
    if kind == FOLDER_DATASET:
        return f"{folder} already holds a dataset"
    if kind == FOLDER_OTHERS:
        others = _other_entries(folder)
        shown = ", ".join(others[:3]) + (f" and {len(others) - 3} more" if len(others) > 3 else "")
        return (f"{folder} is not empty ({shown}) and holds no dataset: a new dataset there would mix its "
                "files with these")
    return None


def new_sub_folder(folder: str | Path, stem: str = "lfstudio-dataset") -> Path:
    """The first of ``folder/stem``, ``folder/stem-2``, … that may receive a new dataset: the fix
    offered for a folder that holds other files."""
    folder = Path(folder)
    for name in (stem, *(f"{stem}-{i}" for i in range(2, 10_000))):
        if new_dataset_folder_problem(folder / name) is None:
            return folder / name
    raise InputError("folder", f"{folder} has no free sub-folder named {stem}-N", "an empty or new folder")


def check_new_dataset_folder(folder: str | Path, field: str, *, add_to_dataset: bool = False,
                             dataset_fix: str = "choose a new folder", stem: str = "lfstudio-dataset",
                             in_use_fix: str = IN_USE_FIX) -> str:
    """THE rule for a folder that is to receive a new dataset; returns its kind
    (:func:`dataset_folder_kind`) or raises :class:`InputError` naming ``field`` and the fix.

    - missing or empty: fine;
    - already a dataset: refused with ``dataset_fix`` (the command's own way to add to it or replace
      it, e.g. "add --resume to continue it, or choose a new folder"), unless ``add_to_dataset``
      (the operator gave that option);
    - other files and no dataset: always refused (also with ``add_to_dataset``: an option to add to or
      replace a dataset never mixes with or deletes other files), naming the folder, a few of its
      files and a new sub-folder (``stem``) as the fix;
    - a file: refused;
    - held by a running scan (its ``dataset.lock``, :func:`check_not_in_use`) where it would be
      accepted (empty, or a dataset with ``add_to_dataset``): refused with :class:`LockBusy` naming
      the holder and ``in_use_fix``.
    """
    kind = dataset_folder_kind(folder)
    if kind == FOLDER_DATASET and add_to_dataset or kind in (FOLDER_MISSING, FOLDER_EMPTY):
        if kind != FOLDER_MISSING:
            check_not_in_use(folder, in_use_fix)
        return kind
    problem = new_dataset_folder_problem(folder)
    assert problem is not None
    if kind == FOLDER_DATASET:
        raise InputError(field, problem, dataset_fix)
    if kind == FOLDER_FILE:
        raise InputError(field, problem, "a folder name for the new dataset")
    raise InputError(field, problem, f"a new sub-folder, e.g. {new_sub_folder(folder, stem)}, or another empty folder")


def relative_name_problem(relative: Any) -> str | None:
    """Why ``relative`` cannot name something inside a folder (empty, absolute, ``..``, a drive), or
    None. For settings that name a place in a dataset before the dataset is known."""
    text = str(relative).replace("\\", "/") if isinstance(relative, (str, os.PathLike)) else None
    if not text:
        return "must be a relative path inside the dataset folder"
    rel = PurePosixPath(text)
    if rel.is_absolute() or ".." in rel.parts or (rel.parts and ":" in rel.parts[0]):
        return "must be a relative path inside the dataset folder (no '..', not absolute)"
    return None


def resolve_inside(root: str | Path, relative: str, *, what: str = "file") -> Path:
    """Return ``root/relative`` resolved, or raise :class:`DatasetError` if it leaves ``root``.

    ``relative`` is a manifest entry (POSIX separators). Absolute paths, ``..`` and symlinks that
    lead outside the dataset folder are refused with one line naming the path.
    """
    root_path = Path(root).resolve()
    problem = relative_name_problem(relative)
    if problem:
        raise DatasetError(f"{what} {relative!r} {problem}; refused")
    rel = PurePosixPath(str(relative).replace("\\", "/"))
    full = (root_path / Path(*rel.parts)).resolve()
    if full != root_path and root_path not in full.parents:
        raise DatasetError(f"{what} {relative!r} points outside the dataset folder {root_path} "
                           f"(it leads to {full}); refused: make it a real file or folder inside the dataset")
    return full


def folder_inside(root: str | Path, relative: str, *, what: str = "folder", create: bool = True) -> Path:
    """The dataset's sub-folder ``relative`` (``raw``, ``processed``, ``cache/features``) resolved and
    checked by :func:`resolve_inside`, created when missing (``create``)."""
    path = resolve_inside(root, relative, what=what)
    if create:
        path.mkdir(parents=True, exist_ok=True)
    return path


def check_dataset_entries(root: str | Path) -> None:
    """Refuse a dataset whose own files or folders lead outside it: every entry of the folder itself
    (whatever a stage writes there, now or later: ``quality/``, ``quality.json``, ``cache/`` ...; no list
    to forget one in) and the nested folders of :data:`DATASET_ENTRIES` (``thumbs/generated``)."""
    try:
        with os.scandir(root) as entries:
            links = [e.name for e in entries if e.is_symlink()]
    except OSError:
        links = []
    for name in sorted(set(links) | {n for n in DATASET_ENTRIES if "/" in n and os.path.islink(os.path.join(root, n))}):
        resolve_inside(root, name, what="folder" if os.path.isdir(os.path.join(root, name)) else "file")


class InsideChecker:
    """:func:`resolve_inside` for many names at once: the dataset folder and each sub-folder are
    resolved once, and listed once for the symlinks in them (the listing says which entries are
    links, no system call per file); a file is resolved on its own only when it is a symlink
    (validating 8241 views takes milliseconds, and time linear in the views)."""

    def __init__(self, root: str | Path):
        self.root = Path(root).resolve()
        self._root_text = str(self.root)
        self._dirs: dict[str, bool] = {}     # sub-folder -> inside the root after resolving
        self._links: dict[str, frozenset[str]] = {}   # sub-folder -> names of the symlinks in it

    def _symlinks(self, parent: str) -> frozenset[str]:
        links = self._links.get(parent)
        if links is None:
            try:
                with os.scandir(os.path.join(self._root_text, parent)) as entries:
                    links = frozenset(e.name for e in entries if e.is_symlink())
            except OSError:
                links = frozenset()
            self._links[parent] = links
        return links

    def _inside(self, path: str) -> bool:
        return path == self._root_text or path.startswith(self._root_text.rstrip(os.sep) + os.sep)

    def check(self, relative: str, *, what: str = "file") -> None:
        text = str(relative).replace("\\", "/")
        parts = text.split("/")
        if not text or text.startswith("/") or ".." in parts or ":" in parts[0]:
            raise DatasetError(f"{what} {relative!r} must be a relative path inside the dataset folder")
        parent = "/".join(p for p in parts[:-1] if p not in ("", "."))
        inside = self._dirs.get(parent)
        if inside is None:
            folder = os.path.realpath(os.path.join(self._root_text, parent)) if parent else self._root_text
            inside = self._dirs[parent] = self._inside(folder)
        full = os.path.join(self._root_text, parent, parts[-1])
        if not inside or (parts[-1] in self._symlinks(parent) and not self._inside(os.path.realpath(full))):
            raise DatasetError(f"{what} {relative!r} points outside the dataset folder {self.root}")
