"""File names inside a dataset. Names come from the grid index; nothing may point outside."""

from __future__ import annotations

from pathlib import Path, PurePosixPath

from lfstudio.errors import DatasetError


def view_stem(row: int, column: int) -> str:
    """``r07_c042`` for row 7, column 42 (rows and columns count from 0)."""
    if row < 0 or column < 0:
        raise ValueError(f"grid index must be non-negative, got row {row}, column {column}")
    return f"r{row:02d}_c{column:03d}"


def resolve_inside(root: str | Path, relative: str, *, what: str = "file") -> Path:
    """Return ``root/relative`` resolved, or raise :class:`DatasetError` if it leaves ``root``.

    ``relative`` is a manifest entry (POSIX separators). Absolute paths, ``..`` and symlinks that
    lead outside the dataset folder are refused.
    """
    root_path = Path(root).resolve()
    rel = PurePosixPath(str(relative).replace("\\", "/"))
    if not str(relative) or rel.is_absolute() or ".." in rel.parts or (rel.parts and ":" in rel.parts[0]):
        raise DatasetError(f"{what} {relative!r} must be a relative path inside the dataset folder")
    full = (root_path / Path(*rel.parts)).resolve()
    if full != root_path and root_path not in full.parents:
        raise DatasetError(f"{what} {relative!r} points outside the dataset folder {root_path}")
    return full
