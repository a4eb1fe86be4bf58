"""How the command line reads a view's position on the grid, and the conventions every command
shares (:data:`CONVENTIONS`, said once in ``lfstudio --help``).

- A grid shape is COLUMNSxROWS: ``9x5`` is 9 columns by 5 rows (:func:`lfstudio.numbers.grid_option`).
- A position on the grid is COLUMN,ROW counted from 0: ``4,2`` is column 4 of row 2
  (:func:`grid_position`).
- A spacing is HORIZONTALxVERTICAL in millimetres: ``4x6``.

Numbers themselves (ranges, units, pairs like ``4x6``) are read by :mod:`lfstudio.numbers`.
"""

from __future__ import annotations

from lfstudio.errors import InputError
from lfstudio.numbers import Number, parse_numbers

CONVENTIONS = ("Grids are COLUMNSxROWS (9x5: 9 columns, 5 rows); a view's position is COLUMN,ROW counted "
               "from 0 (4,2: column 4, row 2); spacings are HORIZONTALxVERTICAL in mm (4x6).")

_INDEX = Number("", 0, integer=True)


def grid_position(text: str, option: str, example: str = "4,2") -> tuple[int, int]:
    """``"4,2"`` -> (column, row), whole numbers from 0."""
    if "," not in str(text):
        raise InputError(option, f"cannot read {text!r}", f"COLUMN,ROW counted from 0, like {example}")
    column, row = parse_numbers(option, text, _INDEX, 2, example)
    return column, row


def number_pair(text: str, option: str, example: str) -> tuple[float, float]:
    """Two finite numbers written ``AxB`` or ``A,B`` (e.g. a horizontal and a vertical sigma)."""
    a, b = parse_numbers(option, text, Number(), 2, example)
    return a, b
