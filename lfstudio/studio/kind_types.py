"""What a device kind declares (:mod:`lfstudio.studio.kinds` is the registry of them): a camera's
:class:`CameraKind`, a rig's :class:`RigKind`, the :class:`OpenContext` their ``open`` gets, and the
:class:`OpenedRig` a rig kind may return when it starts a simulator or takes locks of its own. Plugins
import them from :mod:`lfstudio.studio.kinds`; the built-in kinds' modules (``grbl_rigs``, ``drive_rigs``)
from here, which imports no other module of lfstudio.studio."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

from lfstudio.numbers import Param, params_of

log = logging.getLogger(__name__)

BUILT_IN = "built-in"


@dataclass(frozen=True)
class OpenContext:
    """What opening a device may need besides its argument: ``doing`` (for lock messages),
    ``position_mm`` (where the simulated camera is), the hot folder's ``trigger_command`` and the
    driver's keyword ``options`` (its checked connection options and the studio's extras). A rig's:
    ``config`` (its rig profile), ``time_scale`` and ``seed`` (a simulator's), ``connect`` (connect
    it before returning: the GUI connects on the device's worker instead), ``lock`` (take its OS
    locks; a built-in kind that returns a RigLink takes them itself)."""

    doing: str = ""
    position_mm: Callable[[], tuple[float, float]] | None = None
    trigger_command: Sequence[str] | None = None
    options: dict[str, Any] = field(default_factory=dict)
    config: Any = None            # a rig's RigConfig (its profile), for a rig kind
    time_scale: float = 1.0
    seed: int = 0
    connect: bool = True
    lock: bool = True


@dataclass(frozen=True)
class CameraKind:
    """One kind of camera (see the module docstring)."""

    name: str
    open: Callable[[str, OpenContext], Any]
    label: str = ""
    argument: str = ""                       # metavar of the text after NAME: ("" = takes none)
    options: Any = None                      # a described dataclass of connection options, or None
    lock_key: Callable[[str], str | None] | None = None
    record: Callable[[str], dict[str, Any]] | None = None
    normalise: Callable[[str, str], str] | None = None   # (argument, option) -> the argument as stored
    simulated: bool = False                  # renders a virtual scene (its settings are not its identity)
    help: str = ""
    origin: str = BUILT_IN
    #: () -> (usable, what it runs on or why not), for lfstudio doctor (None: nothing to check)
    check: Callable[[], tuple[bool, str]] | None = None

    @property
    def word(self) -> str:
        """How the word is written: ``gphoto2``, ``folder:PATH``."""
        return f"{self.name}:{self.argument}" if self.argument else self.name

    def option_params(self) -> dict[str, Param]:
        return params_of(self.options) if self.options is not None else {}


@dataclass(frozen=True)
class RigKind:
    """One kind of rig (motion controller), built-in (GRBL, CiA 402 drives: registered by
    :func:`_builtin_rigs` through :func:`register_rig`) or a plugin's (entry point group ``lfstudio.rigs``).

    ``open(argument, context)`` returns a :class:`lfstudio.rig.motion.MotionController` (not yet
    connected; ``context.config``: the rig profile, ``context.options``: its checked options; lfstudio
    takes its ``lock_key``'s lock and connects it), or an :class:`OpenedRig` when it starts a simulator
    or takes locks of its own (the built-in kinds; then it connects it when ``context.connect``). The rest says how its word is read and written and what it needs:

    - ``parse(argument, option)`` -> ``(port, addresses)`` of its :class:`~lfstudio.studio.devices.RigSpec`
      (InputError naming ``option``); None: ``port`` is the argument as written;
    - ``text(port, addresses)`` -> the word again (None: ``NAME:PORT``, or ``NAME`` without argument);
    - ``catch_all``: a word no other kind claims is this kind's argument (a serial port's path);
    - ``driver``: the rig profile's driver it needs ("grbl", "cia402"; "": any profile);
    - ``profile``: the rig profile it implies when none is given ("": the reference gantry, unless
      ``driver`` is "cia402": real drives' profiles are never guessed);
    - ``simulated``: set up and homed in this process (the simulated studio); ``simulates``: the kind
      whose driver it runs against its emulator (sim-dryve simulates dryve);
    - ``describe(link)``: its line for the operator; ``record(link)``: what the dataset records
      (``devices.rig``; None: ``kind``, ``port`` and ``origin``)."""

    name: str
    open: Callable[[str, OpenContext], Any]
    label: str = ""
    argument: str = ""
    options: Any = None
    lock_key: Callable[[str], str | None] | None = None
    help: str = ""
    origin: str = BUILT_IN
    parse: Callable[[str, str], tuple[str, tuple]] | None = None
    text: Callable[[str, tuple], str] | None = None
    catch_all: bool = False
    driver: str = ""
    profile: str = ""
    simulated: bool = False
    simulates: str = ""
    describe: Callable[[Any], str] | None = None
    record: Callable[[Any], dict[str, Any]] | None = None
    #: () -> (usable, what it runs on or why not), for lfstudio doctor (None: nothing to check)
    check: Callable[[], tuple[bool, str]] | None = None

    @property
    def word(self) -> str:
        if self.catch_all:
            return self.argument
        return f"{self.name}:{self.argument}" if self.argument else self.name

    def option_params(self) -> dict[str, Param]:
        return params_of(self.options) if self.options is not None else {}


@dataclass
class OpenedRig:
    """What a rig kind's ``open`` returns when more than a controller was opened: the ``controller``, the
    ``simulator`` it started (closed with it), the ``lock`` it took (``release()``), and the ``port`` and
    ``addresses`` its RigSpec records when they are other than the word's (an emulator's own address)."""

    controller: Any
    simulator: Any = None
    lock: Any = None
    port: str | None = None
    addresses: tuple | None = None


def close_quietly(obj: Any, what: str) -> None:
    """Disconnect/close a device without hiding the problem that made us close it."""
    if obj is None:
        return
    try:
        (obj.disconnect if hasattr(obj, "disconnect") else obj.close)()
    except Exception as exc:  # noqa: BLE001
        log.debug("closing %s: %s", what, exc)
