"""The device kinds lfstudio knows: one registry of cameras (and rigs), built-in and third-party alike.

A **device word** names a kind and what follows its colon: ``gphoto2``, ``folder:PATH``,
``genicam:ID``, ``NAME:ARGUMENTS`` (``--camera`` on the command line, the Camera panel's choice).
Each kind declares, once:

- ``name`` (the word's prefix) and a ``label`` for the window;
- ``argument``: what follows ``NAME:`` ("PATH", "ID"; "" when the kind takes none);
- ``options``: its connection options as a described dataclass (:func:`lfstudio.numbers.described`:
  range, unit, label, tip), from which ``--camera-option NAME=VALUE`` is checked and the window's
  form is built;
- ``open(argument, context)``: the driver (not yet connected);
- ``lock_key(argument)``: the name of its OS lock (a second lfstudio process is refused), or None;
- ``record(argument)``: what the dataset records about it beside kind, model and serial.

The built-in kinds (:func:`_builtin_cameras`) are registered through :func:`register_camera` exactly as
third-party ones. Third-party kinds come from Python entry points, groups ``lfstudio.cameras`` and
``lfstudio.rigs``: ``NAME = "module:factory"``, where ``factory(arguments)`` gets the text after
``NAME:`` and returns a driver implementing :class:`lfstudio.rig.camera.Camera` (or
:class:`~lfstudio.rig.camera.ArrayCamera`), or :class:`lfstudio.rig.motion.MotionController`. An entry
point may also name a :class:`CameraKind` (to declare options, a label, a lock key). A plugin that
fails to load, is not callable, or claims a name another kind has is named in :func:`problems` (and by
``lfstudio doctor``); the others still load.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from dataclasses import dataclass
from typing import Any, Sequence

from lfstudio.errors import DeviceError, InputError
from lfstudio.numbers import FILE_STABLE_S, FILE_WAIT_S, Param, described, params_of
from lfstudio.studio.kind_types import BUILT_IN, CameraKind, OpenContext, OpenedRig, RigKind

__all__ = ["BUILT_IN", "CameraKind", "OpenContext", "OpenedRig", "RigKind"]   # the declarations, for plugins

log = logging.getLogger(__name__)

CAMERA_GROUP = "lfstudio.cameras"
RIG_GROUP = "lfstudio.rigs"


class _Registry:
    def __init__(self) -> None:
        self.cameras: dict[str, CameraKind] = {}
        self.rigs: dict[str, RigKind] = {}
        self.contested: dict[tuple[str, str], list[str]] = {}   # (camera|rig, name) -> the origins claiming it
        self.problems: list[str] = []
        self.plugins_loaded = False
        self.loaded: set[tuple[str, str]] = set()      # (camera|rig, name) registered from entry points
        self.lock = threading.RLock()


_REG = _Registry()


def register_camera(kind: CameraKind) -> None:
    """Add a camera kind; InputError when its name is taken (by a built-in kind or another plugin)."""
    _ensure_builtins()
    _register(_REG.cameras, kind, "camera")


def register_rig(kind: RigKind) -> None:
    """Add a rig kind; InputError when its name is taken (by a built-in kind or another plugin)."""
    _ensure_builtins()
    _register(_REG.rigs, kind, "rig")


def _register(table: dict[str, Any], kind: CameraKind | RigKind, what: str) -> None:
    with _REG.lock:
        _check_name(kind.name, what)
        have = table.get(kind.name.lower())
        if have is not None:
            raise InputError(f"{what} kind", f"{kind.name!r} of {kind.origin} is already the kind of {have.origin}",
                             "a plugin must use a name of its own")
        table[kind.name.lower()] = kind


def _check_name(name: str, what: str) -> None:
    if not name or not all(c.isalnum() or c in "-_." for c in name) or not name[0].isalpha():
        raise InputError(f"{what} kind", f"{name!r} is not a device word name",
                         "letters, digits, - _ . (starting with a letter)")


def unregister(name: str) -> None:
    """Forget a kind (tests)."""
    with _REG.lock:
        _REG.cameras.pop(name.lower(), None)
        _REG.rigs.pop(name.lower(), None)


# -- plugins -----------------------------------------------------------------------------------------
def _entry_points(group: str) -> list[Any]:
    from importlib.metadata import entry_points

    return list(entry_points(group=group))


def _origin(ep: Any) -> str:
    dist = getattr(ep, "dist", None)
    name = f"{dist.name} {dist.version}" if dist is not None else "an installed package"
    return f"plugin {name} ({ep.value})"


def _plugin_kind(ep: Any, group: str) -> CameraKind | RigKind:
    """The kind an entry point names: a CameraKind/RigKind itself, or a factory(arguments)."""
    origin = _origin(ep)
    try:
        obj = ep.load()
    except Exception as exc:   # noqa: BLE001 - a broken plugin is named, the rest still load
        raise DeviceError(f"{origin}: cannot be loaded ({type(exc).__name__}: {exc})") from None
    name = ep.name
    if group == CAMERA_GROUP:
        if isinstance(obj, CameraKind):
            return dataclasses.replace(obj, name=name, origin=origin)
        if not callable(obj):
            raise DeviceError(f"{origin}: {ep.value} is not a factory (not callable) nor a CameraKind")
        return CameraKind(name, lambda argument, _ctx, f=obj: f(argument), label=f"{name} (plugin)",
                          argument="ARGUMENTS", lock_key=lambda argument, n=name: f"{n}-{argument}",
                          origin=origin, help=(getattr(obj, "__doc__", "") or "").strip().split("\n")[0])
    if isinstance(obj, RigKind):
        return dataclasses.replace(obj, name=name, origin=origin)
    if not callable(obj):
        raise DeviceError(f"{origin}: {ep.value} is not a factory (not callable) nor a RigKind")
    return RigKind(name, lambda argument, _ctx, f=obj: f(argument), label=f"{name} (plugin)", argument="ARGUMENTS",
                   lock_key=lambda argument, n=name: f"{n}-{argument}", origin=origin)


def load_plugins(force: bool = False) -> None:
    """Register every installed plugin kind once (``force``: again, e.g. after a pip install)."""
    with _REG.lock:
        if _REG.plugins_loaded and not force:
            return
        _ensure_builtins()
        for what, name in _REG.loaded:                 # a reload forgets what the entry points gave
            (_REG.cameras if what == "camera" else _REG.rigs).pop(name, None)
        _REG.loaded.clear()
        _REG.contested.clear()
        _REG.problems = []
        _REG.plugins_loaded = True
        for group in (CAMERA_GROUP, RIG_GROUP):
            table: dict[str, Any] = _REG.cameras if group == CAMERA_GROUP else _REG.rigs
            what = "camera" if group == CAMERA_GROUP else "rig"
            try:
                eps = _entry_points(group)
            except Exception as exc:   # noqa: BLE001 - broken package metadata
                _REG.problems.append(f"{group}: the installed packages' entry points cannot be read ({exc})")
                continue
            claims: dict[str, list[Any]] = {}
            for ep in eps:
                claims.setdefault(ep.name.lower(), []).append(ep)
            for name, claimants in sorted(claims.items()):
                if name in table:
                    for ep in claimants:
                        _REG.problems.append(f"{what} kind {ep.name!r} of {_origin(ep)} is not loaded: "
                                             f"{ep.name!r} is the {table[name].origin} kind")
                    continue
                if len({ep.value for ep in claimants}) > 1:
                    origins = [_origin(ep) for ep in claimants]
                    _REG.contested[(what, name)] = origins
                    _REG.problems.append(f"{what} kind {claimants[0].name!r} is claimed by {' and '.join(origins)}: "
                                         "neither is loaded; uninstall one of them")
                    continue
                try:
                    kind = _plugin_kind(claimants[0], group)
                    if isinstance(kind, CameraKind):
                        register_camera(kind)
                    else:
                        register_rig(kind)
                    _REG.loaded.add((what, name))
                except (DeviceError, InputError) as exc:
                    _REG.problems.append(str(exc))
        for line in _REG.problems:
            log.warning("%s", line)


def problems() -> list[str]:
    """One line for each plugin that did not load (and why)."""
    load_plugins()
    return list(_REG.problems)


def camera_kinds() -> dict[str, CameraKind]:
    """Every camera kind by name (built-in first, then plugins)."""
    load_plugins()
    return dict(_REG.cameras)


def rig_kinds() -> dict[str, RigKind]:
    load_plugins()
    return dict(_REG.rigs)


def camera_choices() -> str:
    """The words of every camera kind, for messages: ``sim, gphoto2, folder:PATH, ...``."""
    return ", ".join(kind.word for kind in camera_kinds().values())


def camera_kind(name: str, option: str = "--camera") -> CameraKind:
    """The kind called ``name``; InputError listing the known ones (or naming the two plugins that claim it)."""
    kinds = camera_kinds()
    kind = kinds.get(name.lower())
    if kind is not None:
        return kind
    contested = _REG.contested.get(("camera", name.lower()))
    if contested:
        raise InputError(option, f"camera kind {name!r} is claimed by {' and '.join(contested)}",
                         "uninstall one of them (lfstudio doctor lists the kinds)")
    raise InputError(option, f"unknown camera kind {name!r}", "one of " + camera_choices())


def rig_choices() -> str:
    """The words of every rig kind, for messages: ``sim, instant, PORT, dryve:HOST[:PORT],HOST[:PORT], ...``."""
    return ", ".join(kind.word for kind in rig_kinds().values())


def rig_kind(name: str, option: str = "--port") -> RigKind | None:
    """The rig kind called ``name`` (None: no kind has that name); InputError when two plugins claim it."""
    kind = rig_kinds().get(name.strip().lower())
    if kind is not None:
        return kind
    contested = _REG.contested.get(("rig", name.strip().lower()))
    if contested:
        raise InputError(option, f"rig kind {name!r} is claimed by {' and '.join(contested)}",
                         "uninstall one of them (lfstudio doctor lists the kinds)")
    return None


def rig_word(text: str, option: str = "--port") -> tuple[RigKind, str]:
    """The kind a rig's device word names and its argument: ``NAME`` or ``NAME:ARGUMENT`` of a registered
    kind, else the whole word is the argument of the catch-all kind (a serial port). InputError when the
    word is empty, or names no kind and none catches all."""
    word = (text or "").strip()
    if not word:
        raise InputError(option, "no rig given", "one of " + rig_choices())
    head, sep, rest = word.partition(":")
    kind = rig_kind(head, option)
    if kind is not None and not kind.catch_all and (sep or not kind.argument or kind.parse is not None
                                                    or kind.origin == BUILT_IN):
        if not kind.argument and rest.strip():
            raise InputError(option, f"{word!r}: the {kind.name} rig takes nothing after '{kind.name}:'", kind.name)
        return kind, rest.strip()
    if kind is not None and kind.catch_all and sep:      # grbl:/dev/ttyUSB0, as well as /dev/ttyUSB0
        return kind, rest.strip()
    for candidate in rig_kinds().values():
        if candidate.catch_all:
            return candidate, word
    raise InputError(option, f"unknown rig kind {head!r}", "one of " + rig_choices())


def split_word(text: str) -> tuple[str, str]:
    """``NAME:ARGUMENT`` -> (name, argument); a word without a colon is (word, "")."""
    word = (text or "").strip()
    name, _, argument = word.partition(":")
    return name.strip(), argument.strip()


# -- connection options ------------------------------------------------------------------------------
def _value_of(param: Param, text: str) -> Any:
    if param.optional and text.strip().lower() == param.optional.lower():
        return None
    if param.flag:
        low = text.strip().lower()
        if low in ("true", "yes", "on", "1"):
            return True
        if low in ("false", "no", "off", "0"):
            return False
        return text
    if param.number is not None:
        try:
            return int(text) if param.number.integer else float(text)
        except ValueError:
            return text                    # the check names it
    return text


def parse_options(kind: CameraKind | RigKind, items: Sequence[str] | dict[str, Any],
                  option: str = "--camera-option") -> dict[str, Any]:
    """``NAME=VALUE`` texts (or a dict) checked against the kind's described options: the keyword
    arguments for its driver. InputError naming the option and the known names."""
    params = params_of(kind.options) if kind.options is not None else {}
    pairs: list[tuple[str, Any]] = []
    if isinstance(items, dict):
        pairs = list(items.items())
    else:
        for item in items:
            key, sep, value = str(item).partition("=")
            if not sep or not key.strip():
                raise InputError(option, f"cannot read {item!r}", "NAME=VALUE, e.g. timeout_s=3")
            pairs.append((key.strip(), value.strip()))
    out: dict[str, Any] = {}
    for key, value in pairs:
        param = params.get(key)
        if param is None:
            known = ", ".join(params) if params else "none"
            raise InputError(option, f"{kind.name} has no option {key!r}", f"its options: {known}")
        out[key] = param.check(f"{option} {key}", _value_of(param, value) if isinstance(value, str) else value)
    return out


def parse_settings(items: Sequence[str], option: str = "--set") -> dict[str, Any]:
    """``NAME=VALUE`` camera settings (``lfstudio camera --set``, ``lfstudio scan --set``): a number where
    the value reads as one, else the text; the camera checks each against its own description."""
    out: dict[str, Any] = {}
    for item in items:
        name, sep, text = str(item).partition("=")
        if not sep or not name.strip():
            raise InputError(option, f"cannot read {item!r}", "NAME=VALUE, e.g. --set pixel_format=Mono16")
        value: Any = text.strip()
        for kind in (int, float):
            try:
                value = kind(text.strip())
                break
            except ValueError:
                pass
        out[name.strip()] = value
    return out


def options_text(kind: CameraKind | RigKind) -> list[str]:
    """One line per option of ``kind``: ``name (label): valid values, default``."""
    if kind.options is None:
        return []
    lines = []
    for f in dataclasses.fields(kind.options):
        param = params_of(kind.options).get(f.name)
        if param is None:
            continue
        default = param.to_text(f.default) if f.default is not dataclasses.MISSING else "required"
        lines.append(f"{f.name} ({param.label or f.name}): {param.valid()}, default {default}")
    return lines


# -- the built-in cameras ----------------------------------------------------------------------------
def _open_sim(argument: str, ctx: OpenContext) -> Any:
    if ctx.position_mm is None:
        raise InputError("--camera", "the simulated camera renders from the simulated rig's true position",
                         "--port sim, or the port 'lfstudio sim-rig' printed")
    from lfstudio.studio.simulated import simulated_camera

    return simulated_camera(ctx.position_mm, **ctx.options)


def _open_instant(argument: str, ctx: OpenContext) -> Any:
    from lfstudio.studio.simulated import InstantCamera

    return InstantCamera(ctx.position_mm, **ctx.options)


def _open_gphoto2(argument: str, ctx: OpenContext) -> Any:
    try:
        from lfstudio.rig.gphoto import GPhotoCamera
    except ImportError as exc:
        raise DeviceError(f"--camera gphoto2: the driver is not available ({exc})") from None
    return GPhotoCamera(**ctx.options)


def _open_folder(argument: str, ctx: OpenContext) -> Any:
    from lfstudio.rig.hotfolder import HotFolderCamera

    return HotFolderCamera(argument, list(ctx.trigger_command) if ctx.trigger_command else None, **ctx.options)


def _folder_key(argument: str) -> str:
    from pathlib import Path

    return f"folder-{Path(argument).resolve()}"


def _folder_path(argument: str, option: str) -> str:
    from lfstudio.dataset.paths import expand_path

    if not argument:
        raise InputError(option, "folder: names no folder", "folder:PATH, the folder the camera software saves into")
    return str(expand_path(argument, option))


def _open_genicam(argument: str, ctx: OpenContext) -> Any:
    from lfstudio.rig.genicam import GenicamCamera

    return GenicamCamera(argument, **ctx.options)


def _genicam_id(argument: str, option: str) -> str:
    if not argument:
        raise InputError(option, "genicam: names no camera",
                         "genicam:ID, the id arv-tool-0.8 lists (e.g. genicam:Aravis-Fake-GV01 or an IP address)")
    return argument


def _genicam_check() -> tuple[bool, str]:
    from lfstudio.rig.genicam import aravis_version

    return aravis_version()


@dataclass(frozen=True)
class HotFolderOptions:
    timeout_s: float = described(30.0, number=FILE_WAIT_S, label="Wait for the file",
                                 tip="how long a capture waits for the camera software's new file")
    stable_s: float = described(0.5, number=FILE_STABLE_S, label="Unchanged for",
                                tip="how long the new file's size must stay the same before it counts as complete")


def _builtin_cameras() -> list[CameraKind]:
    from lfstudio.rig.genicam import GenicamOptions

    return [
        CameraKind("sim", _open_sim, "Simulated studio camera", simulated=True,
                   help="renders the virtual studio from the simulated rig's true position"),
        CameraKind("gphoto2", _open_gphoto2, "USB camera (gphoto2)", lock_key=lambda _a: "gphoto2",
                   help="A camera tethered over USB through libgphoto2. Connect it by USB, switch it on and set its "
                        "USB mode to <b>PC Remote</b>; pictures go to the camera's memory and are downloaded after "
                        "each shot."),
        CameraKind("folder", _open_folder, "Hot folder (vendor software)", argument="PATH", options=HotFolderOptions,
                   lock_key=_folder_key, record=lambda a: {"folder": a}, normalise=_folder_path,
                   help="the folder the camera's own software saves each picture into"),
        CameraKind("genicam", _open_genicam, "Machine-vision camera (GenICam)", argument="ID",
                   options=GenicamOptions, lock_key=lambda a: f"genicam-{a}", normalise=_genicam_id,
                   check=_genicam_check,
                   help="GigE Vision or USB3 Vision camera through aravis (ID: as arv-tool-0.8 lists it)"),
        CameraKind("instant", _open_instant, "Instant camera (tests)", simulated=True,
                   help="takes no time and writes small files (tests, benchmarks)"),
    ]


_builtins_done = False


def _ensure_builtins() -> None:
    global _builtins_done
    with _REG.lock:
        if _builtins_done:
            return
        _builtins_done = True
        for kind in _builtin_cameras():
            register_camera(kind)
        for rig in _builtin_rigs():
            register_rig(rig)


def _builtin_rigs() -> list[RigKind]:
    """The built-in rig kinds, each declared in its own module beside its driver's set-up."""
    from lfstudio.studio.drive_rigs import DRIVE_KINDS
    from lfstudio.studio.grbl_rigs import GRBL_KINDS

    return [*GRBL_KINDS, *DRIVE_KINDS]
