"""Device descriptions -> running drivers, with their OS-level locks (the one place that does this).

The words an operator uses (CLI options, the GUI's choices)::

    rig:     sim | instant | PORT        (/dev/ttyUSB0, /dev/pts/N from `lfstudio sim-rig`, COM3, a pyserial URL)
             dryve:HOST[:PORT],HOST[:PORT]      one CiA 402 drive per axis over Modbus TCP (igus dryve D1
                                                gateway telegrams; port 502 by default; `lfstudio sim-drive`)
             canopen:CHANNEL:NODE,NODE          one CiA 402 drive per axis over CANopen (CHANNEL can0, or
                                                virtual-NAME: python-can's in-process virtual bus)
             sim-dryve | sim-canopen            emulated drives in this process, over Modbus TCP on
                                                127.0.0.1 / over a virtual CAN bus (the simulated studio)
    camera:  sim | instant | gphoto2 | folder:PATH | genicam:ID | NAME:ARGUMENTS (a plugin's kind)

Both are the kinds of :mod:`lfstudio.studio.kinds`, built-in and plugins' alike (the rigs'
words are read, opened and recorded by :mod:`lfstudio.studio.grbl_rigs` and
:mod:`lfstudio.studio.drive_rigs`; a word no kind claims is a serial port). :class:`RigSpec` and
:class:`CameraSpec` hold a kind's name and what its word says; :func:`open_rig`, :class:`RigLink` and
:func:`open_camera` open, describe and record it through its kind, without a branch on its name.

``sim`` starts the GRBL simulator on a pseudo-terminal in this process and drives it with the real
GRBL driver; ``instant`` is a rig/camera that takes no time (tests, benchmarks). A serial port is
locked for this process (:func:`lfstudio.support.locks.port_lock`), and so are a gphoto2 camera and
a hot folder: a second lfstudio process asking for them is refused with the holder's name.

::

    with open_studio("sim", "sim", rig_config, doing="scanning D") as studio:
        studio.rig, studio.camera        # connected drivers (the rig homed when it is simulated here)
        studio.record()                  # what the dataset records about them

The simulated camera renders from the carriage's true position: the in-process simulator's, the
instant rig's, or that of the ``lfstudio sim-rig`` serving the port (see :mod:`lfstudio.studio.simulated`).
"""

from __future__ import annotations

import logging
import weakref
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

from lfstudio.errors import DeviceError, InputError
from lfstudio.optics import REFERENCE
from lfstudio.rig.motion import HasPort, KnowsTruePosition, RigConfig
from lfstudio.studio.kind_types import OpenedRig, close_quietly
from lfstudio.support.locks import Lock, camera_lock, port_lock

log = logging.getLogger(__name__)

SIM = "sim"
INSTANT = "instant"
PLUGIN = "plugin"
#: what each rig profile driver is called in messages: (the kind of rig, what a word of it is)
DRIVERS = {"grbl": ("a GRBL controller", "a GRBL controller"), "cia402": ("CiA 402 drives", "a drive pair")}


def rig_choices() -> str:
    """The words of every rig kind (:mod:`lfstudio.studio.kinds`), for messages."""
    from lfstudio.studio.kinds import rig_choices as choices

    return choices()


@dataclass(frozen=True)
class RigSpec:
    """A rig device word: ``kind``, the name of a registered rig kind (:mod:`lfstudio.studio.kinds`: "grbl"
    for a serial port, "sim", "instant", "dryve", "canopen", "sim-dryve", "sim-canopen", a plugin's
    name), and what its kind reads from the rest of the word: ``port`` (the serial port, the CANopen
    channel, a plugin's arguments) and ``addresses`` (the drives' HOST:PORT, the node ids)."""

    kind: str
    port: str = ""
    addresses: tuple = ()

    @classmethod
    def parse(cls, text: str, option: str = "--port") -> "RigSpec":
        from lfstudio.studio.kinds import rig_word

        kind, argument = rig_word(text, option)
        port, addresses = kind.parse(argument, option) if kind.parse is not None else (argument, ())
        return cls(kind.name, port, tuple(addresses))

    @property
    def info(self) -> Any:
        """Its :class:`lfstudio.studio.kinds.RigKind` (InputError when no installed kind has its name)."""
        from lfstudio.studio.kinds import rig_kind

        kind = rig_kind(self.kind)
        if kind is None:
            raise InputError("--port", f"no rig kind {self.kind!r} is installed", rig_choices())
        return kind

    @property
    def drives(self) -> bool:
        """A pair of CiA 402 drives (its rig profile must be a drive pair's)."""
        return self.info.driver == "cia402"

    @property
    def simulated(self) -> bool:
        return self.info.simulated

    @property
    def text(self) -> str:
        kind = self.info
        if kind.text is not None:
            return kind.text(self.port, self.addresses)
        if kind.catch_all:
            return self.port
        return f"{kind.name}:{self.port}" if (kind.argument or self.port) else kind.name


@dataclass(frozen=True)
class CameraSpec:
    """A camera device word: ``kind`` (a registered camera kind, :mod:`lfstudio.studio.kinds`: "sim",
    "instant", "gphoto2", "folder", "genicam", a plugin's name) and ``argument``, the text after
    ``KIND:`` (the hot folder's path, the GenICam id, a plugin's arguments)."""

    kind: str
    argument: str = ""

    @classmethod
    def parse(cls, text: str, option: str = "--camera") -> "CameraSpec":
        from lfstudio.studio.kinds import camera_choices, camera_kind, split_word

        name, argument = split_word(text)
        if not name:
            raise InputError(option, "no camera given", camera_choices())
        kind = camera_kind(name, option)
        if not kind.argument and argument:
            raise InputError(option, f"{text.strip()!r}: the {kind.name} camera takes nothing after '{kind.name}'",
                             kind.name)
        if kind.normalise is not None:
            argument = kind.normalise(argument, option)
        return cls(kind.name, argument)

    @property
    def folder(self) -> str:
        """The hot folder's path (``folder:PATH``), else ""."""
        return self.argument if self.kind == "folder" else ""

    @property
    def text(self) -> str:
        return f"{self.kind}:{self.argument}" if self.argument else self.kind


def profile_names(driver: str) -> list[str]:
    """The installed rig profiles for ``driver`` ("cia402", "grbl")."""
    from lfstudio.resources import load_presets
    from lfstudio.rig.profile import rig_from_dict

    names = []
    for name, preset in load_presets("rigs").items():
        try:
            if rig_from_dict(name, preset).driver == driver:
                names.append(name)
        except InputError:              # a broken user preset is reported where it is chosen
            continue
    return names


def drive_profile_names() -> list[str]:
    """The installed rig profiles for CiA 402 drives (driver = "cia402")."""
    return profile_names("cia402")


def rig_profile_flag(name: str) -> str:
    """``--rig-profile NAME`` as typed in a shell (quoted when the name has spaces)."""
    import shlex

    return f"--rig-profile {shlex.quote(name)}"


def implied_rig_profile(spec: RigSpec | str, option: str = "--rig-profile") -> str:
    """The rig profile a device word implies when none is given: its kind's (the preset drive pair for
    the drive emulators sim-dryve and sim-canopen, which are started from it), else the reference gantry
    (a GRBL controller, sim, instant, a plugin's rig). A pair of real drives has no default: their feed
    constants, homing method and limits must be the rig's own, so the InputError names exactly what to add."""
    from lfstudio.rig.profile import DEFAULT_DRIVE_RIG, DEFAULT_RIG

    spec = RigSpec.parse(spec) if isinstance(spec, str) else spec
    kind = spec.info
    if kind.profile:
        return kind.profile
    if kind.driver != "cia402":
        return DEFAULT_RIG
    names = drive_profile_names()
    example = names[0] if names else DEFAULT_DRIVE_RIG
    raise InputError(option, f"{spec.text!r} is a pair of CiA 402 drives: name the rig profile that holds their "
                     "feed constants, homing method and limits (lfstudio never guesses them for real drives)",
                     " or ".join(rig_profile_flag(n) for n in names) if names else
                     f"a profile with driver = \"cia402\" in rigs.toml, e.g. {rig_profile_flag(example)}")


class RigLink:
    """An opened rig: ``controller`` (the driver), ``simulator`` (the simulator or emulator started in this
    process, or None), ``port`` (what the driver opened) and its locks. :meth:`close` ends all of them."""

    def __init__(self, spec: RigSpec, config: RigConfig, controller: Any, simulator: Any = None,
                 lock: Any = None):
        self.spec = spec
        self.config = config
        self.controller = controller
        self.simulator = simulator
        self.lock = lock
        port = controller.port if isinstance(controller, HasPort) else ""
        self.port = port or spec.text

    @property
    def simulated(self) -> bool:
        return self.spec.simulated

    def describe(self) -> str:
        kind = self.spec.info
        return kind.describe(self) if kind.describe is not None else f"rig {self.spec.text}"

    def record(self) -> dict[str, Any]:
        """What a dataset records about this rig (see docs/dataset-format.md, ``devices.rig``): what its
        kind records (``kind``, ``port``, ``firmware``), the profile, where a plugin kind came from."""
        from lfstudio.studio.kinds import BUILT_IN

        kind = self.spec.info
        rec: dict[str, Any] = {"kind": kind.name, "profile": self.config.name}
        if kind.record is not None:
            rec.update(kind.record(self))
        else:
            rec["port"] = self.spec.text
        if kind.origin != BUILT_IN:
            rec["origin"] = kind.origin
        return rec

    def close(self, disconnect: bool = True) -> None:
        """Disconnect the driver (``disconnect=False``: its DeviceWorker does that), stop the
        simulator, release the port."""
        if disconnect:
            close_quietly(self.controller, "the rig")
        if self.simulator is not None:
            close_quietly(self.simulator, "the simulated controller")
            self.simulator = None
        if self.lock is not None:
            self.lock.release()


def _profile_fits(spec: RigSpec, config: RigConfig) -> None:
    """InputError (with the window's words) when the rig profile is for another driver than the kind's."""
    kind = spec.info
    if not kind.driver or kind.driver == config.driver:      # a plugin's rig takes any profile
        return
    if config.driver == "cia402":                            # a drive pair's profile, and no drive pair
        words = ", ".join(k.word for k in _rig_kinds().values() if k.driver == config.driver)
        what, word = DRIVERS.get(config.driver, (f"driver {config.driver!r}", f"a {config.driver} rig"))
        error = InputError("--rig-profile", f"rig profile {config.name!r} is for {what}, and {spec.text!r} "
                           f"is not {word}", f"--port {words}")
        error.window_text = (f"The rig profile {config.name!r} is for {what}, and the port {spec.text!r} is "
                             f"not {word}: choose another profile in the Rig list, or the port of {what} "
                             f"({words}) in the Port list")
        raise error
    names = profile_names(kind.driver)
    what = DRIVERS.get(kind.driver, (kind.label,))[0]
    have = DRIVERS.get(config.driver, (f"driver {config.driver!r}",))[0]
    error = InputError("--rig-profile", f"{spec.text!r} is {'a pair of ' if kind.driver == 'cia402' else ''}"
                       f"{what}, and rig profile {config.name!r} is for {have}"
                       + (" (no feed constants or homing methods)" if kind.driver == "cia402" else ""),
                       " or ".join(rig_profile_flag(n) for n in names) if names else
                       f"a profile with driver = \"{kind.driver}\" in rigs.toml")
    error.window_text = (f"The port {spec.text!r} is {what}, and the rig profile {config.name!r} is for {have}: "
                         f"choose its profile in the Rig list"
                         + (f" ({' or '.join(repr(n) for n in names)})" if names else
                            f" (add one with driver = \"{kind.driver}\" to rigs.toml)"))
    raise error


def _rig_kinds() -> dict[str, Any]:
    from lfstudio.studio.kinds import rig_kinds

    return rig_kinds()


#: the device word of each rig driver open_rig made (by id, with a weak reference to tell a reused id)
_OPENED_RIGS: dict[int, tuple[Any, RigSpec]] = {}


def open_rig(spec: RigSpec | str, config: RigConfig, *, doing: str = "", time_scale: float = 1.0, seed: int = 0,
             connect: bool = True, lock: bool = True, **controller_options: Any) -> RigLink:
    """Open the rig ``spec`` names through its kind (:mod:`lfstudio.studio.kinds`): a simulator started when
    the kind runs one, its OS locks taken (raises :class:`lfstudio.support.locks.LockBusy` naming the
    holder), the driver built and, with ``connect``, connected (in this thread; the GUI connects on the
    device's worker instead). ``controller_options``: keyword options of the driver; the kind gets those
    its described options name (``--rig-option``, the Rig panel's form; others are for other kinds)."""
    from lfstudio.rig.motion import MotionController
    from lfstudio.studio.kinds import OpenContext

    spec = RigSpec.parse(spec) if isinstance(spec, str) else spec
    kind = spec.info
    _profile_fits(spec, config)
    argument = spec.port if kind.catch_all else spec.text.partition(":")[2]     # what follows NAME:
    key = kind.lock_key(argument) if (lock and kind.lock_key is not None) else None
    lk = port_lock(key, doing, shown=f"rig {spec.text}").acquire() if key else None
    try:
        options = {k: v for k, v in controller_options.items() if k in kind.option_params()}   # its own only
        opened = kind.open(argument, OpenContext(doing, config=config, time_scale=time_scale, seed=seed,
                                                 connect=connect, lock=lock, options=options))
        if isinstance(opened, OpenedRig):       # a simulator, locks of its own, an emulator's address
            shown = RigSpec(spec.kind, spec.port if opened.port is None else opened.port,
                            spec.addresses if opened.addresses is None else tuple(opened.addresses))
            link = RigLink(shown, config, opened.controller, opened.simulator, _Both(opened.lock, lk))
            lk = None
        else:
            if not isinstance(opened, MotionController):
                missing = [m for m in _members(MotionController) if not hasattr(opened, m)]
                raise DeviceError(f"rig kind {kind.name!r} ({kind.origin}) gave a {type(opened).__name__}, which is "
                                  f"not a motion controller (it lacks {', '.join(missing)}; see "
                                  "lfstudio/rig/motion.py)")
            link = RigLink(spec, config, opened, lock=lk)
            lk = None
            if connect:
                try:
                    opened.connect()
                except BaseException:
                    link.close()            # what a half-done connect opened (its port), then the lock
                    raise
    except BaseException:
        if lk is not None:
            lk.release()
        raise
    _remember(link.controller, link.spec, _OPENED_RIGS)
    return link


def _members(protocol: type) -> list[str]:
    """The attributes and methods a ``typing.Protocol`` asks for (what ``isinstance`` checks), in order."""
    names = list(getattr(protocol, "__annotations__", {}))
    return names + [n for n, v in vars(protocol).items() if callable(v) and not n.startswith("_") and n not in names]


class _Both:
    """Two locks released together (a kind's own and the one of its lock key)."""

    def __init__(self, first: Any, second: Any):
        self.locks = [lk for lk in (first, second) if lk is not None]

    def release(self) -> None:
        for lk in self.locks:
            lk.release()


@dataclass
class CameraLink:
    """An opened camera driver and its lock (None for the simulated and instant cameras)."""

    spec: CameraSpec
    camera: Any
    lock: Lock | None = None

    def record(self) -> dict[str, Any]:
        """What a dataset records about this camera (``devices.camera``): kind, model and serial when
        the driver tells them (``identity()`` or ``status().model``), what the kind records (the hot
        folder), where a plugin kind came from."""
        from lfstudio.rig.camera import HasIdentity, HasStatus, name_of
        from lfstudio.studio.kinds import BUILT_IN, camera_kind

        rec: dict[str, Any] = {"kind": self.spec.kind, "spec": self.spec.text}
        try:
            kind = camera_kind(self.spec.kind)
        except InputError:
            kind = None
        if kind is not None and kind.simulated:      # its settings (image size, ...) are not its identity
            rec["model"] = name_of(self.camera, self.spec.kind)
            return rec
        if kind is not None and kind.record is not None:
            rec.update(kind.record(self.spec.argument))
        if kind is not None and kind.origin != BUILT_IN:
            rec["origin"] = kind.origin
        info: dict[str, Any] = {}
        if isinstance(self.camera, HasIdentity):
            try:
                found = self.camera.identity()
                info = dict(found) if isinstance(found, dict) else {}
            except Exception as exc:  # noqa: BLE001 - a record without the model is still a record
                log.debug("camera identity: %s", exc)
        if not info.get("model"):
            try:
                model = getattr(self.camera.status(), "model", "") if isinstance(self.camera, HasStatus) else ""
            except Exception:  # noqa: BLE001
                model = ""
            if model:
                info["model"] = model
        for key in ("model", "serial", "lens"):
            if info.get(key):
                rec[key] = str(info[key])
        rec.setdefault("model", name_of(self.camera, self.spec.kind))
        return rec

    def close(self, disconnect: bool = True) -> None:
        """Disconnect the driver (``disconnect=False``: its DeviceWorker does that), release the camera."""
        if disconnect:
            close_quietly(self.camera, "the camera")
        if self.lock is not None:
            self.lock.release()


def as_camera(driver: Any, origin: str) -> Any:
    """``driver`` as a :class:`lfstudio.rig.camera.Camera`: an array camera with only ``grab`` wrapped in
    :class:`~lfstudio.rig.camera.FrameGrabber`; DeviceError naming ``origin`` when it is neither."""
    from lfstudio.rig.camera import ArrayCamera, Camera, FrameGrabber

    if isinstance(driver, Camera):
        return driver
    if isinstance(driver, ArrayCamera):
        return FrameGrabber(driver)
    missing = [m for m in ("connect", "disconnect", "settings", "set_setting", "capture", "preview")
               if not callable(getattr(driver, m, None))]
    raise DeviceError(f"{origin} gave a {type(driver).__name__}, which is not a camera (it lacks "
                      f"{', '.join(missing)}; a camera has connect, disconnect, settings, set_setting and capture "
                      "or grab, see lfstudio/rig/camera.py)")


def open_camera(spec: CameraSpec | str, *, position_mm: Callable[[], tuple[float, float]] | None = None,
                doing: str = "", trigger_command: Sequence[str] | None = None, connect: bool = True,
                options: dict[str, Any] | None = None, lock: bool = True) -> CameraLink:
    """Open the camera ``spec`` names through its kind (:mod:`lfstudio.studio.kinds`; connected with
    ``connect``; the GUI connects on the device's worker instead). ``position_mm``: where the
    simulated/instant camera is (required for ``sim``); ``options``: keyword arguments of the driver
    (the kind's connection options; the simulated camera's exposure_s, transfer_s, time_scale, seed,
    studio_kwargs, ...); ``trigger_command``: the hot folder's trigger, an argument list."""
    from lfstudio.studio.kinds import OpenContext, camera_kind

    spec = CameraSpec.parse(spec) if isinstance(spec, str) else spec
    kind = camera_kind(spec.kind)
    lk: Lock | None = None
    key = kind.lock_key(spec.argument) if (lock and kind.lock_key is not None) else None
    if key:
        lk = camera_lock(key, doing, shown=spec.text).acquire()
    try:
        driver = kind.open(spec.argument, OpenContext(doing, position_mm, trigger_command, dict(options or {})))
        cam = as_camera(driver, f"camera kind {kind.name!r} ({kind.origin})")
    except BaseException:
        if lk is not None:
            lk.release()
        raise
    link = CameraLink(spec, cam, lk)
    _remember(cam, spec)
    if connect:
        try:
            cam.connect()
        except BaseException:
            link.close()
            raise
    return link


def link_for_rig(controller: Any, config: RigConfig, simulated: bool = False) -> RigLink:
    """A :class:`RigLink` (without lock) for a driver opened elsewhere: the word :func:`open_rig` opened it
    by, else its kind told by its port (``simulated``: the kind that simulates that one)."""
    from lfstudio.studio.simulated import InstantRig

    ref, opened = _OPENED_RIGS.get(id(controller), (None, None))
    if ref is not None and ref() is controller and opened is not None:
        return RigLink(opened, config, controller)
    if isinstance(controller, InstantRig):
        return RigLink(RigSpec(INSTANT), config, controller)
    port = (controller.port if isinstance(controller, HasPort) else "") or "?"
    spec = RigSpec.parse(port)
    if simulated:
        twin = next((k for k in _rig_kinds().values() if k.simulates == spec.kind), None)
        if twin is not None:
            spec = RigSpec(twin.name, spec.port, spec.addresses)
    return RigLink(spec, config, controller)


#: the device word of each camera driver open_camera made (by id, with a weak reference to tell a reused id)
_OPENED: dict[int, tuple[Any, CameraSpec]] = {}


def _remember(device: Any, spec: Any, table: dict[int, tuple[Any, Any]] | None = None) -> None:
    table = _OPENED if table is None else table
    for key in [k for k, (ref, _) in table.items() if ref() is None]:
        del table[key]
    try:
        table[id(device)] = (weakref.ref(device), spec)
    except TypeError:          # a driver that cannot be weakly referenced: told by its type instead
        pass


def link_for_camera(camera: Any, spec: CameraSpec | None = None) -> CameraLink:
    """A :class:`CameraLink` (without lock) for a camera driver opened elsewhere: ``spec``, else the word
    :func:`open_camera` opened it by, else its kind told by its type (drivers made directly)."""
    from lfstudio.rig.hotfolder import HotFolderCamera
    from lfstudio.studio.simulated import InstantCamera, SimulatedCamera

    if spec is not None:
        return CameraLink(spec, camera)
    ref, opened = _OPENED.get(id(camera), (None, None))
    if ref is not None and ref() is camera and opened is not None:     # opened by open_camera: its own word
        return CameraLink(opened, camera)
    if isinstance(camera, SimulatedCamera):
        return CameraLink(CameraSpec(SIM), camera)
    if isinstance(camera, InstantCamera):
        return CameraLink(CameraSpec(INSTANT), camera)
    if isinstance(camera, HotFolderCamera):
        return CameraLink(CameraSpec("folder", str(camera.folder)), camera)
    return CameraLink(CameraSpec("gphoto2"), camera)


@dataclass
class Studio:
    """A connected rig and camera, ready for a scan (see the module docstring). ``notes``: lines
    for the operator about how the devices were set up."""

    rig_link: RigLink
    camera_link: CameraLink
    notes: list[str] = field(default_factory=list)

    @property
    def rig(self) -> Any:
        return self.rig_link.controller

    @property
    def camera(self) -> Any:
        return self.camera_link.camera

    @property
    def simulator(self) -> Any:
        return self.rig_link.simulator

    @property
    def port(self) -> str:
        return self.rig_link.port

    @property
    def description(self) -> str:
        cam = {"sim": "simulated camera", "instant": "instant camera"}.get(self.camera_link.spec.kind,
                                                                           f"camera {self.camera_link.spec.text}")
        return f"{self.rig_link.describe()}, {cam}"

    def record(self) -> dict[str, Any]:
        """``{"rig": {...}, "camera": {...}}``: the dataset's device record."""
        return {"rig": self.rig_link.record(), "camera": self.camera_link.record()}

    def set_view_region(self, view_region_mm: tuple[float, float, float, float]) -> None:
        """Centre the simulated camera's virtual scene on a grid extent (other cameras: nothing)."""
        from lfstudio.rig.camera import SimulatedScene

        if isinstance(self.camera, SimulatedScene):
            self.camera.set_view_region(tuple(float(v) for v in view_region_mm))

    def close(self) -> None:
        self.camera_link.close()
        self.rig_link.close()

    def __enter__(self) -> "Studio":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _home_telling(controller: Any, say: Callable[[str], None] | None) -> None:
    """``controller.home()``, telling ``say`` when it starts and ends (and the drive pair's lines)."""
    import time

    if say is None:
        controller.home()
        return
    from lfstudio.rig.motion import ReportsProgress

    started = time.monotonic()
    if not isinstance(controller, ReportsProgress):   # a GRBL controller homes its axes in one command
        say("homing the simulated rig (it drives to its limit switches) …")
        controller.home()
    else:
        previous, controller.progress = controller.progress, say
        try:
            controller.home()
        finally:
            controller.progress = previous
    say(f"rig homed ({time.monotonic() - started:.0f} s)")


def open_studio(rig: RigSpec | str, camera: CameraSpec | str, rig_config: RigConfig, *, doing: str = "",
                time_scale: float = 1.0, exposure_s: float = REFERENCE.exposure_s,
                transfer_s: float = REFERENCE.transfer_s, seed: int = 0,
                view_region_mm: tuple[float, float, float, float] | None = None, sim_width_px: int | None = None,
                trigger_command: Sequence[str] | None = None, camera_options: dict[str, Any] | None = None,
                say: Callable[[str], None] | None = None, opened: Callable[[Any], None] | None = None,
                **controller_options: Any) -> Studio:
    """Connect the rig and the camera. A rig simulated in this process is homed (or given its
    origin) at once: the simulated studio starts ready (``say``: told when homing starts, as each
    drive of a drive pair reaches its reference, and when it ends). ``opened``: called with the rig's
    controller as soon as it is connected, before it homes (so that the window's STOP can stop it;
    raising there closes it again). Everything opened is closed again when a step fails. Raises
    InputError / DeviceError / LockBusy with one operator line."""
    rig_spec = RigSpec.parse(rig) if isinstance(rig, str) else rig
    cam_spec = CameraSpec.parse(camera) if isinstance(camera, str) else camera
    link = open_rig(rig_spec, rig_config, doing=doing, time_scale=time_scale, seed=seed, **controller_options)
    notes: list[str] = []
    try:
        if opened is not None:
            opened(link.controller)
        position = None
        if link.simulator is not None:
            if rig_config.homing:
                _home_telling(link.controller, say)
            else:
                link.controller.set_origin()
            position = link.simulator.true_position_mm
        elif isinstance(link.controller, KnowsTruePosition):        # the instant rig
            position = link.controller.true_position_mm
        elif cam_spec.kind in (SIM, INSTANT):
            from lfstudio.studio.simulated import truth_source

            position = truth_source(link.port)
            if position is None and cam_spec.kind == SIM:
                raise InputError("--camera", f"the simulated camera needs the simulated rig, and {link.port} is "
                                 "not a port of 'lfstudio sim-rig' running on this machine",
                                 "--port sim, or the port 'lfstudio sim-rig' printed")
            if position is not None:
                notes.append(f"the simulated camera follows the true position of the simulated controller on "
                             f"{link.port}")
        options: dict[str, Any] = {}
        if cam_spec.kind == SIM:
            from lfstudio.studio.simulated import studio_kwargs_for

            options = dict(exposure_s=exposure_s, transfer_s=transfer_s, time_scale=time_scale, seed=seed,
                           studio_kwargs=studio_kwargs_for(view_region_mm, sim_width_px))
        options.update(camera_options or {})
        cam_link = open_camera(cam_spec, position_mm=position, doing=doing, trigger_command=trigger_command,
                               options=options)
        # the simulated camera's exposure output wired to the emulated drives' touch probe input (#40)
        wire = getattr(link.simulator if link.simulator is not None else position, "exposure_output", None)
        if cam_spec.kind == SIM and callable(wire) and hasattr(cam_link.camera, "exposure_output"):
            cam_link.camera.exposure_output = wire
    except BaseException:
        link.close()
        raise
    return Studio(link, cam_link, notes)
