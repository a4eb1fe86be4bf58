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
             (the camera kinds of :mod:`lfstudio.studio.kinds`)

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
from lfstudio.rig.motion import RigConfig
from lfstudio.support.locks import Lock, camera_lock, drive_lock, port_lock

log = logging.getLogger(__name__)

SIM = "sim"
INSTANT = "instant"
RIG_CHOICES = ("sim, instant, a serial port such as /dev/ttyUSB0, dryve:HOST[:PORT],HOST[:PORT], "
               "canopen:CHANNEL:NODE,NODE, sim-dryve, sim-canopen or an installed plugin's NAME:ARGS")
DRIVE_KINDS = ("dryve", "canopen", "sim-dryve", "sim-canopen")
PLUGIN = "plugin"


@dataclass(frozen=True)
class RigSpec:
    """``kind``: "sim" (simulator in this process), "instant", "serial" (``port``), "plugin" (``port``: the
    kind's name, ``addresses``: its arguments; a rig kind from the entry points group lfstudio.rigs), or a CiA 402
    drive pair: "dryve" (``addresses``: two ``HOST:PORT``), "canopen" (``port``: the channel,
    ``addresses``: the two node ids), "sim-dryve" / "sim-canopen" (emulated here)."""

    kind: str
    port: str = ""
    addresses: tuple = ()

    @classmethod
    def parse(cls, text: str, option: str = "--port") -> "RigSpec":
        word = (text or "").strip()
        if not word:
            raise InputError(option, "no rig given", RIG_CHOICES)
        if word.lower() in (SIM, INSTANT, "sim-dryve", "sim-canopen"):
            return cls(word.lower())
        head, _, rest = word.partition(":")
        if head.lower() == "dryve":
            from lfstudio.rig.dryve import parse_address

            parts = [p for p in rest.split(",")]
            if len(parts) != 2 or not all(p.strip() for p in parts):
                raise InputError(option, f"{word!r}: a dryve rig names two drives, the horizontal one first",
                                 "dryve:HOST[:PORT],HOST[:PORT], e.g. dryve:192.168.1.10,192.168.1.11")
            addresses = tuple("%s:%d" % parse_address(p, option) for p in parts)
            if addresses[0] == addresses[1]:
                raise InputError(option, f"{word!r}: both axes name the same drive {addresses[0]}",
                                 "one drive per axis, each its own address")
            return cls("dryve", "", addresses)
        if head.lower() == "canopen":
            channel, _, nodes = rest.rpartition(":")
            parts = nodes.split(",")
            if not channel or len(parts) != 2:
                raise InputError(option, f"{word!r}: a CANopen rig names its bus and two node ids",
                                 "canopen:CHANNEL:NODE,NODE, e.g. canopen:can0:1,2")
            ids = []
            for p in parts:
                try:
                    n = int(p)
                except ValueError:
                    n = 0
                if not 1 <= n <= 127:
                    raise InputError(option, f"{word!r}: node id {p!r} is not 1 … 127", "canopen:can0:1,2")
                ids.append(n)
            if ids[0] == ids[1]:
                raise InputError(option, f"{word!r}: both axes name node {ids[0]}", "one node per axis")
            return cls("canopen", channel, tuple(ids))
        from lfstudio.studio.kinds import rig_kind

        plugin = rig_kind(head, option) if ":" in word else None     # a plugin's NAME:ARGS (studio/kinds.py)
        if plugin is not None:
            return cls(PLUGIN, plugin.name, (rest.strip(),))
        return cls("serial", word)

    @property
    def drives(self) -> bool:
        return self.kind in DRIVE_KINDS

    @property
    def text(self) -> str:
        if self.kind == "dryve":
            return "dryve:" + ",".join(self.addresses)
        if self.kind == "canopen":
            return f"canopen:{self.port}:{self.addresses[0]},{self.addresses[1]}"
        if self.kind == PLUGIN:
            return f"{self.port}:{self.addresses[0]}"
        return self.port if self.kind == "serial" else self.kind


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


def drive_profile_names() -> list[str]:
    """The installed rig profiles for CiA 402 drives (driver = "cia402")."""
    from lfstudio.resources import load_presets
    from lfstudio.rig.profile import rig_from_dict

    names = []
    for name, preset in load_presets("rigs").items():
        try:
            if rig_from_dict(name, preset).driver == "cia402":
                names.append(name)
        except InputError:              # a broken user preset is reported where it is chosen
            continue
    return names


def rig_profile_flag(name: str) -> str:
    """``--rig-profile NAME`` as typed in a shell (quoted when the name has spaces)."""
    import shlex

    return f"--rig-profile {shlex.quote(name)}"


def implied_rig_profile(spec: RigSpec | str, option: str = "--rig-profile") -> str:
    """The rig profile a device word implies when none is given: the reference gantry for a GRBL
    controller (a serial port, sim, instant), the preset drive pair for the drive emulators (sim-dryve,
    sim-canopen, which are started from it). A pair of real drives has no default: their feed constants,
    homing method and limits must be the rig's own, so the InputError names exactly what to add."""
    from lfstudio.rig.profile import DEFAULT_DRIVE_RIG, DEFAULT_RIG

    spec = RigSpec.parse(spec) if isinstance(spec, str) else spec
    if spec.kind in ("sim-dryve", "sim-canopen"):
        return DEFAULT_DRIVE_RIG
    if not spec.drives:
        return DEFAULT_RIG
    names = drive_profile_names()
    example = names[0] if names else DEFAULT_DRIVE_RIG
    raise InputError(option, f"{spec.text!r} is a pair of CiA 402 drives: name the rig profile that holds their "
                     "feed constants, homing method and limits (lfstudio never guesses them for real drives)",
                     " or ".join(rig_profile_flag(n) for n in names) if names else
                     f"a profile with driver = \"cia402\" in rigs.toml, e.g. {rig_profile_flag(example)}")


def close_quietly(obj: Any, what: str) -> None:
    """Disconnect/close a device without hiding the problem that made us close it."""
    if obj is None:
        return
    try:
        (obj.disconnect if hasattr(obj, "disconnect") else obj.close)()
    except Exception as exc:  # noqa: BLE001
        log.debug("closing %s: %s", what, exc)


class RigLink:
    """An opened rig: ``controller`` (the driver), ``simulator`` (the in-process GRBL simulator or
    None), ``port`` (what the driver opened) and the port's lock. :meth:`close` ends all of them."""

    def __init__(self, spec: RigSpec, config: RigConfig, controller: Any, simulator: Any = None,
                 lock: Any = None):
        self.spec = spec
        self.config = config
        self.controller = controller
        self.simulator = simulator
        self.lock = lock
        self.port = getattr(controller, "port", "") or spec.text

    @property
    def simulated(self) -> bool:
        return self.spec.kind in (SIM, "sim-dryve", "sim-canopen")

    def describe(self) -> str:
        if self.spec.kind == SIM:
            return f"simulated rig on {self.port}"
        if self.spec.kind == INSTANT:
            return "instant rig"
        if self.spec.kind in ("sim-dryve", "sim-canopen"):
            return f"emulated CiA 402 drives ({self.port})"
        if self.spec.drives:
            return f"CiA 402 drives {self.port}"
        if self.spec.kind == PLUGIN:
            return f"rig {self.spec.text}"
        return f"rig on {self.port}"

    def record(self) -> dict[str, Any]:
        """What a dataset records about this rig (see docs/dataset-format.md, ``devices.rig``)."""
        kind = {SIM: "sim", INSTANT: "instant"}.get(self.spec.kind, "grbl")
        if self.spec.drives:
            kind = self.spec.kind
        if self.spec.kind == PLUGIN:
            from lfstudio.studio.kinds import rig_kinds

            plugin = rig_kinds().get(self.spec.port)
            return {"kind": self.spec.port, "profile": self.config.name, "port": self.spec.text,
                    "origin": plugin.origin if plugin is not None else "plugin"}
        rec: dict[str, Any] = {"kind": kind, "profile": self.config.name}
        if self.spec.kind == "serial":
            rec["port"] = self.spec.port
        elif self.spec.kind in ("dryve", "canopen"):
            rec["port"] = self.spec.text
        version = str(getattr(self.controller, "version", "") or "").rstrip(":")
        if version and not self.spec.drives:
            rec["firmware"] = f"GRBL {version}"
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


def open_rig(spec: RigSpec | str, config: RigConfig, *, doing: str = "", time_scale: float = 1.0, seed: int = 0,
             connect: bool = True, lock: bool = True, **controller_options: Any) -> RigLink:
    """Open the rig ``spec`` names: start the simulator for ``sim``, take the port's lock (raises
    :class:`lfstudio.support.locks.LockBusy` naming the holder), build the driver and, with
    ``connect``, connect it (in this thread; the GUI connects on the device's worker instead)."""
    spec = RigSpec.parse(spec) if isinstance(spec, str) else spec
    if spec.kind == PLUGIN:
        return _open_plugin_rig(spec, config, doing=doing, connect=connect, lock=lock)
    if spec.drives or config.driver == "cia402":
        return _open_drives(spec, config, doing=doing, time_scale=time_scale, seed=seed, connect=connect,
                            lock=lock, **controller_options)
    if spec.kind == INSTANT:
        from lfstudio.studio.simulated import InstantRig

        rig = InstantRig(config)
        if connect:
            rig.connect()
        return RigLink(spec, config, rig)
    from lfstudio.rig.grbl import GrblController

    simulator = None
    port_lk: Lock | None = None
    try:
        if spec.kind == SIM:
            from lfstudio.studio.simulated import start_simulator

            simulator = start_simulator(config, time_scale=time_scale, seed=seed)
            if simulator.port is None:                    # start() opens it, or raises
                raise DeviceError("the simulated rig did not open its serial port")
            port = simulator.port
        else:
            port = spec.port
        if lock:
            port_lk = port_lock(port, doing).acquire()
        controller = GrblController(port, config, **controller_options)
        link = RigLink(spec, config, controller, simulator, port_lk)
        if connect:
            controller.connect()
    except BaseException:
        if port_lk is not None:
            port_lk.release()
        if simulator is not None:
            close_quietly(simulator, "the GRBL simulator")
        raise
    return link


def _open_plugin_rig(spec: RigSpec, config: RigConfig, *, doing: str, connect: bool, lock: bool) -> RigLink:
    """A rig kind from a plugin (entry points group lfstudio.rigs): its factory's controller, locked by
    the kind's lock key, connected with ``connect``."""
    from lfstudio.rig.motion import MotionController
    from lfstudio.studio.kinds import OpenContext, rig_kind

    kind = rig_kind(spec.port)
    assert kind is not None, "RigSpec.parse found it"
    argument = spec.addresses[0] if spec.addresses else ""
    key = kind.lock_key(argument) if (lock and kind.lock_key is not None) else None
    lk = port_lock(key, doing).acquire() if key else None
    try:
        controller = kind.open(argument, OpenContext(doing, config=config))
        if not isinstance(controller, MotionController):
            missing = [m for m in ("connect", "home", "move_to", "stop", "status") if not callable(getattr(controller, m, None))]
            raise DeviceError(f"rig kind {kind.name!r} ({kind.origin}) gave a {type(controller).__name__}, which is "
                              f"not a motion controller (it lacks {', '.join(missing) or 'part of lfstudio/rig/motion.py'})")
        link = RigLink(spec, config, controller, lock=lk)
        if connect:
            controller.connect()
    except BaseException:
        if lk is not None:
            lk.release()
        raise
    return link


class _Locks:
    """The locks of a rig's drives (one per address), released together."""

    def __init__(self, locks: list[Lock]):
        self.locks = locks

    def release(self) -> None:
        for lk in self.locks:
            lk.release()


#: the drive options of ``lfstudio rig`` etc. that the CiA 402 driver takes
_DRIVE_OPTIONS = ("timeout_s", "poll_hz", "tolerance_mm", "stall_s", "accept_reference", "known_objects")


def _open_drives(spec: RigSpec, config: RigConfig, *, doing: str, time_scale: float, seed: int, connect: bool,
                 lock: bool, **controller_options: Any) -> RigLink:
    """A CiA 402 drive pair: the emulators for ``sim-dryve``/``sim-canopen``, one lock per drive
    address, the links and the driver (connected with ``connect``)."""
    if not spec.drives:
        error = InputError("--rig-profile", f"rig profile {config.name!r} is for CiA 402 drives, and {spec.text!r} "
                           "is not a drive pair", "--port dryve:HOST,HOST, canopen:CHANNEL:NODE,NODE or sim-dryve")
        error.window_text = (f"The rig profile {config.name!r} is for CiA 402 drives, and the port {spec.text!r} is "
                             "not a drive pair: choose a GRBL profile in the Rig list, or the drives' port "
                             "(Simulated drives, dryve:HOST,HOST or canopen:CHANNEL:NODE,NODE) in the Port list")
        raise error
    if config.driver != "cia402":
        names = drive_profile_names()
        error = InputError("--rig-profile", f"{spec.text!r} is a pair of CiA 402 drives, and rig profile "
                           f"{config.name!r} is for a GRBL controller (no feed constants or homing methods)",
                           " or ".join(rig_profile_flag(n) for n in names) if names else
                           "a profile with driver = \"cia402\" in rigs.toml")
        error.window_text = (f"The port {spec.text!r} is a pair of CiA 402 drives, and the rig profile {config.name!r} "
                             "is for a GRBL controller: choose the drives' profile in the Rig list"
                             + (f" ({' or '.join(repr(n) for n in names)})" if names else
                                " (add one with driver = \"cia402\" to rigs.toml)"))
        raise error
    from lfstudio.rig.cia402 import Cia402Controller

    simulator: Any = None
    locks: list[Lock] = []
    options = {k: v for k, v in controller_options.items() if k in _DRIVE_OPTIONS}
    try:
        if spec.kind == "sim-dryve":
            from lfstudio.studio.simulated import start_drive_emulator

            simulator = start_drive_emulator(config, "modbus", time_scale=time_scale, seed=seed)
            spec = RigSpec.parse(simulator.word)
        elif spec.kind == "sim-canopen":
            from lfstudio.studio.simulated import start_drive_emulator

            simulator = start_drive_emulator(config, "canopen", time_scale=time_scale, seed=seed)
            spec = RigSpec.parse(simulator.word)
        # an EDS/DCF named by the profile: the drive's objects are the file's (python-canopen parses it)
        dictionaries: list[Any] = [None, None]
        known: list[set | None] = [None, None]
        for i, axis in enumerate((config.horizontal, config.vertical)):
            if axis.eds_file:
                from lfstudio.rig.cia402 import load_object_dictionary

                node = int(spec.addresses[i]) if spec.kind == "canopen" else 1
                dictionaries[i], known[i] = load_object_dictionary(
                    axis.eds_file, node, f"rig {config.name!r} {axis.name}.eds_file (drive {'xy'[i]})")
        if known != [None, None]:
            options["known_objects"] = (known[0], known[1])
        if spec.kind == "dryve":
            from lfstudio.rig.dryve import DryveLink, parse_address

            x, y = spec.addresses
            links = (DryveLink(*parse_address(x), timeout_s=options.get("timeout_s", 1.0)),
                     DryveLink(*parse_address(y), timeout_s=options.get("timeout_s", 1.0)))
        else:
            from lfstudio.rig.canopen_link import CanopenLink

            x, y = spec.addresses
            links = (CanopenLink(spec.port, x, timeout_s=options.get("timeout_s", 1.0), object_dictionary=dictionaries[0]),
                     CanopenLink(spec.port, y, timeout_s=options.get("timeout_s", 1.0), object_dictionary=dictionaries[1]))
        if lock:
            for link in links:
                locks.append(drive_lock(link.address, doing).acquire())
        controller = Cia402Controller(links, config, port=spec.text, **options)
        kind_spec = RigSpec(spec.kind if simulator is None else ("sim-dryve" if spec.kind == "dryve" else "sim-canopen"),
                            spec.port, spec.addresses)
        rig_link = RigLink(kind_spec, config, controller, simulator, _Locks(locks))
        if connect:
            controller.connect()
    except BaseException:
        for lk in locks:
            lk.release()
        if simulator is not None:
            close_quietly(simulator, "the emulated drives")
        raise
    return rig_link


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
        from lfstudio.rig.camera import HasIdentity, HasStatus
        from lfstudio.studio.kinds import BUILT_IN, camera_kind

        rec: dict[str, Any] = {"kind": self.spec.kind, "spec": self.spec.text}
        try:
            kind = camera_kind(self.spec.kind)
        except InputError:
            kind = None
        if kind is not None and kind.simulated:      # its settings (image size, ...) are not its identity
            rec["model"] = getattr(self.camera, "name", self.spec.kind)
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
        rec.setdefault("model", getattr(self.camera, "name", self.spec.kind))
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
        lk = camera_lock(key, doing).acquire()
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
    """A :class:`RigLink` (without lock) for a driver opened elsewhere, its kind told by its type."""
    from lfstudio.studio.simulated import InstantRig

    if isinstance(controller, InstantRig):
        return RigLink(RigSpec(INSTANT), config, controller)
    port = getattr(controller, "port", "") or "?"
    if config.driver == "cia402":
        spec = RigSpec.parse(port)
        if simulated:
            spec = RigSpec("sim-dryve" if spec.kind == "dryve" else "sim-canopen", spec.port, spec.addresses)
        return RigLink(spec, config, controller)
    return RigLink(RigSpec(SIM) if simulated else RigSpec("serial", port), config, controller)


#: the device word of each camera driver open_camera made (by id, with a weak reference to tell a reused id)
_OPENED: dict[int, tuple[Any, CameraSpec]] = {}


def _remember(camera: Any, spec: CameraSpec) -> None:
    for key in [k for k, (ref, _) in _OPENED.items() if ref() is None]:
        del _OPENED[key]
    try:
        _OPENED[id(camera)] = (weakref.ref(camera), spec)
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
                say: Callable[[str], None] | None = None, **controller_options: Any) -> Studio:
    """Connect the rig and the camera. A rig simulated in this process is homed (or given its
    origin) at once: the simulated studio starts ready (``say``: told when homing starts, as each
    drive of a drive pair reaches its reference, and when it ends). Everything opened is closed again
    when a step fails. Raises InputError / DeviceError / LockBusy with one operator line."""
    rig_spec = RigSpec.parse(rig) if isinstance(rig, str) else rig
    cam_spec = CameraSpec.parse(camera) if isinstance(camera, str) else camera
    link = open_rig(rig_spec, rig_config, doing=doing, time_scale=time_scale, seed=seed, **controller_options)
    notes: list[str] = []
    try:
        position = None
        if link.simulator is not None:
            if rig_config.homing:
                _home_telling(link.controller, say)
            else:
                link.controller.set_origin()
            position = link.simulator.true_position_mm
        elif rig_spec.kind == INSTANT:
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
