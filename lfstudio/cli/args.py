"""How the command line reads a view's position on the grid, and the conventions every command
shares (:data:`CONVENTIONS`, said once in ``lfstudio --help``).

- A grid shape is COLUMNSxROWS: ``9x5`` is 9 columns by 5 rows (:func:`grid_option`).
- A position on the grid is COLUMN,ROW counted from 0: ``4,2`` is column 4 of row 2
  (:func:`grid_position`).
- A spacing is HORIZONTALxVERTICAL in millimetres: ``4x6``.
- Devices are ``--port`` (the axis controller: ``sim``, ``instant`` or a serial port) and
  ``--camera`` (``sim``, ``gphoto2``, ``folder:PATH``); profiles and presets are ``--rig-profile``
  and ``--camera-preset``. An old spelling is kept (hidden, :func:`old_spelling`) where it means
  the same as its new name, and refused with a line showing the new form (:func:`refused_spelling`)
  where its meaning changed.

Numbers themselves (ranges, units, pairs like ``4x6``) are read by :mod:`lfstudio.numbers`; the glue that
makes its readers (and paths and brackets) argparse ``type=`` functions is here (:func:`as_option`).
"""

from __future__ import annotations

import argparse
from typing import Any, Callable

from lfstudio.errors import InputError
from lfstudio.numbers import Number, Param, parse_grid, parse_numbers

CONVENTIONS = ("Grids are COLUMNSxROWS (9x5: 9 columns, 5 rows; an array of views: array:3x2); a view's "
               "position is COLUMN,ROW counted from 0 (4,2: column 4, row 2), its name r02_c004; spacings are "
               "HORIZONTALxVERTICAL in mm (4x6). Devices: --port (axis controller), --camera; profiles: "
               "--rig-profile, --camera-preset.")

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


def old_spelling(p: argparse._ActionsContainer, old: str, new: str, **kwargs) -> None:
    """Accept ``old`` as a hidden spelling of ``new`` (the same meaning, so existing scripts keep
    working); ``--help`` shows only ``new``."""
    dest = new.lstrip("-").replace("-", "_")
    p.add_argument(old, dest=dest, help=argparse.SUPPRESS, **kwargs)


class _Refused(argparse.Action):
    def __init__(self, *args: Any, message: str | Callable[[str], str], **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.message = message

    def __call__(self, parser, namespace, values, option_string=None):
        value = values if isinstance(values, str) else ""   # nargs=None: the text given
        text = self.message
        parser.error(text(value) if callable(text) else text.format(value=value))


def refused_spelling(p: argparse._ActionsContainer, old: str, message: str | Callable[[str], str],
                     takes_value: bool = True) -> None:
    """Refuse ``old`` (its meaning changed, so reading it would silently do something else) with
    ``message``, which shows the new form: a text (``{value}`` in it is the value given) or a
    function of the value."""
    p.add_argument(old, action=_Refused, nargs=None if takes_value else 0, help=argparse.SUPPRESS,
                   default=argparse.SUPPRESS, message=message)


# -- argparse glue: a reader of typed text as an option's ``type=`` -------------------------------------
def as_option(option: str, parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """``parse`` as an argparse ``type=``: an InputError becomes argparse's one-line error (exit 2)."""
    def convert(text: str) -> Any:
        try:
            return parse(text)
        except InputError as exc:
            message = str(exc)
            raise argparse.ArgumentTypeError(message[len(option) + 2:] if message.startswith(f"{option}: ")
                                             else message) from None
    convert.__name__ = option.lstrip("-").replace("-", "_")
    return convert


def number_option(number: Number, option: str) -> Callable[[str], Any]:
    """The ``type=`` of an option holding one ``number`` (:meth:`lfstudio.numbers.Number.parse`)."""
    return as_option(option, lambda text: number.parse(option, text))


def numbers_option(option: str, number: Number, count: int = 2, example: str = "4x6",
                   one_for_all: bool = False) -> Callable[[str], tuple]:
    """The ``type=`` of an option of ``count`` numbers (:func:`lfstudio.numbers.parse_numbers`)."""
    return as_option(option, lambda text: parse_numbers(option, text, number, count, example, one_for_all))


def grid_option(option: str) -> Callable[[str], tuple[int, int]]:
    """The ``type=`` of a ``CxR`` grid option (:func:`lfstudio.numbers.parse_grid`)."""
    return as_option(option, lambda text: parse_grid(option, text))


def path_option(option: str) -> Callable[[str], str]:
    """The ``type=`` of a path argument: :func:`lfstudio.dataset.paths.expand_path` on what was typed
    (a quoted ``'~/x'`` or ``'$HOME/x'`` reaches us unexpanded by the shell); a refusal is one line."""
    from lfstudio.dataset.paths import expand_path

    return as_option(option, lambda text: str(expand_path(text, option)))


def described_option(p: Any, param: Param, default: Any, *, said: str | None = None, required: bool = False,
                     reader: Callable[[str], Any] | None = None) -> None:
    """Add the option of a described parameter (:class:`lfstudio.numbers.Param`) to the parser or group
    ``p``: its name, placeholder, choices, reader and help all come from the description, so the command
    line accepts what the loader and the window accept. ``said``: the default as ``--help`` tells it
    (None: ``default`` as typed; empty: not told); ``reader``: a reader of its own for a compound value
    (a grid, a bracket)."""
    option = param.option
    if said is None:
        said = param.to_text(default) if default is not None else ""
    text = f"{param.tip} (default {said})" if said and not required else param.tip
    kwargs: dict[str, Any] = {"help": text.replace("%", "%%")}     # argparse formats help with %
    if required:
        kwargs["required"] = True
    else:
        kwargs["default"] = default
    if param.metavar:
        kwargs["metavar"] = param.metavar
    if param.repeat:
        kwargs["action"] = "append"
    if param.choices:
        kwargs["choices"] = param.choices
    elif reader is not None:
        kwargs["type"] = reader
    elif param.number is not None:
        kwargs["type"] = numbers_option(option, param.number) if param.pair else number_option(param.number, option)
    p.add_argument(option, **kwargs)


def bracket_option(option: str = "--bracket") -> Callable[[str], Any]:
    """The ``type=`` of a ``--bracket`` option (:func:`lfstudio.dataset.bracket.parse_bracket`)."""
    from lfstudio.dataset.bracket import parse_bracket

    return as_option(option, lambda text: parse_bracket(text, option))
