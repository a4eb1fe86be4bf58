"""One scan session: dataset lock -> dataset (new or resumed) -> devices -> homing -> scan engine.

The CLI (``lfstudio scan``) and the GUI's Scan panel both run a scan through :class:`ScanSession`::

    session = ScanSession(ScanRequest(folder, resume=True, home=True), doing="lfstudio scan")
    try:
        engine = session.open(plan_for)       # plan_for(existing_dataset_or_None, rig_config) -> (plan, scene)
        engine.start(); engine.wait()
    finally:
        session.close()                       # devices, then the dataset lock

What :meth:`ScanSession.open` guarantees, in this order:

1. **A new dataset gets a folder of its own**: a folder holding other files (and no dataset) is
   refused before anything is written into it (:func:`lfstudio.dataset.paths.check_new_dataset_folder`).
   **One process per dataset**: ``DATASET/dataset.lock`` is held from before the first file is
   read until :meth:`close` (:mod:`lfstudio.support.locks`); a second scan or resume of the same
   folder is refused naming the holder, and touches no file of it.
2. **A resume uses the dataset's own devices** (``dataset.json`` → ``devices``): without device
   options they are opened again; other devices (the simulator included) are refused unless the
   request says ``allow_device_change``, and then the change is recorded (``device_changes`` and
   each view's ``devices``). A dataset without a device record resumes with a warning on the devices
   the request names (the command line must name them: never the simulated studio by default).
3. **Homing policy** (:func:`prepare_rig`): ``home`` homes before the first view (``$H``; a rig
   without limit switches is refused: park it and use ``origin_here``); without it a rig in ALARM or
   not homed is refused with one line naming ``--home`` and ``lfstudio rig --port P home``. A resume
   on the dataset's own rig that did not home checks that the rig stands where the last run left it,
   and that no other dataset's scan used the rig since (:func:`note_scan_on_rig` records each scan
   per port beside the port's lock; else :class:`RigUsedSince`: the GUI asks, the CLI names ``--home``).
4. The engine gets a plan of the views still to capture (``recapture`` cells again). A resume on its
   own devices of a dataset whose every view is finished connects nothing (no homing for nothing):
   :meth:`ScanSession.open` returns None, with :attr:`ScanSession.dataset` and ``plan`` set.
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

from lfstudio.dataset import Dataset
from lfstudio.dataset.bracket import Bracket
from lfstudio.dataset.store import free_bytes
from lfstudio.dataset.manifest import MANIFEST_NAME, ViewRecord, is_finished, now_iso
from lfstudio.dataset.paths import check_new_dataset_folder, view_label
from lfstudio.errors import DeviceError, InputError, LfError, words
from lfstudio.numbers import EXPOSURE_S, RETRIES, TIME_SCALE, TRANSFER_S
from lfstudio.optics import REFERENCE
from lfstudio.planning.scene_plan import ScenePlan
from lfstudio.rig.camera import Camera, HasCardSpace, HasIdentity, name_of
from lfstudio.rig.motion import ChecksTargets, RigConfig, RigState, SoftLimitError
from lfstudio.rig.worker import RunsOnWorker, caller_of, driver_of
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.studio.devices import (SIM, CameraSpec, RigSpec, Studio, implied_rig_profile, open_studio,
                                     rig_profile_flag)
from lfstudio.support.locks import MANIFEST_LOCK_NAME, Lock, dataset_lock

log = logging.getLogger(__name__)

#: the scan's dataset folder and bracket, as the command line and the Scan panel name them
OUT_FIELD = words("--out", "Folder")
BRACKET_OPTION = words("--bracket", "Bracket")
RIG_PROFILE_FIELD = words("--rig-profile", "Rig")

#: how far (mm) a resumed rig may stand from the path where the last run stopped
RESUME_TOLERANCE_MM = 0.5
ALLOW_CHANGE_OPTION = "--allow-device-change"

PlanFor = Callable[[Dataset | None, RigConfig], tuple[ScanPlan, Any]]


# -- the dataset of a scan -------------------------------------------------------------------------
def dataset_views(plan: ScanPlan) -> list[ViewRecord]:
    """One pending manifest entry per grid cell of ``plan`` (row-major), with its commanded position."""
    full = plan.with_subset(None)
    return [{"row": r, "column": c, "commanded_mm": list(full.position_mm(r, c)), "reported_mm": None,
             "captured_at": None, "exposure_s": None, "file": None, "sha256": None, "status": "pending"}
            for r in range(plan.rows) for c in range(plan.columns)]


def create_scan_dataset(root: str | Path, plan: ScanPlan, *, rig: dict, camera: dict, lens: dict,
                        scene_plan: dict | None = None, devices: dict | None = None) -> Dataset:
    """A new dataset folder for ``plan`` with every view pending (``devices``: the device record)."""
    extra: dict[str, Any] = {"devices": devices} if devices else {}
    return Dataset.create(root, camera=camera, lens=lens, grid=plan.grid_dict(), rig=rig, plan=scene_plan or {},
                          views=dataset_views(plan), **extra)


def check_resume_matches(dataset: Dataset, plan: ScanPlan) -> list[str]:
    """Differences between an existing dataset's grid and ``plan`` that make resuming into it wrong."""
    g = dataset.grid
    problems = []
    if (g.columns, g.rows) != (plan.columns, plan.rows):
        problems.append(f"grid: the dataset is {g.columns} x {g.rows}, "
                        f"the scan asks for {plan.columns} x {plan.rows}")
    spacing = g.spacing_mm
    if spacing and any(abs(float(a) - b) > 1e-6 for a, b in zip(spacing, plan.spacing_mm)):
        problems.append(f"spacing_mm: the dataset has {spacing[0]:g} x {spacing[1]:g} mm, "
                        f"the scan asks for {plan.spacing_mm[0]:g} x {plan.spacing_mm[1]:g} mm")
    return problems


def resume_plan(dataset: Dataset, *, order: str | None = None, settle_s: float | None = None) -> ScanPlan:
    """The plan of an existing dataset (its grid), with another capture order or settle time if given."""
    base = ScanPlan.from_grid(dataset.grid)
    return ScanPlan(base.columns, base.rows, base.spacing_mm, base.origin_mm, order or base.order,
                    base.settle_s if settle_s is None else settle_s)


def describe_camera(camera: Any, scene: Any = None) -> tuple[dict, dict]:
    """The manifest's camera and lens entries: from the scene plan, else from the simulated studio,
    else the driver's name; with what a real camera reports of itself (model, serial, lens)."""
    identity = camera.identity() if isinstance(camera, HasIdentity) else {}
    if isinstance(scene, ScenePlan):
        return {**identity, **scene.camera_dict()}, scene.lens_dict()
    from lfstudio.studio.simulated import describe_simulated_camera

    described = describe_simulated_camera(camera)
    if described is not None:
        return described
    return ({"name": identity.get("model") or name_of(camera, "camera"), **identity},
            {"name": identity.get("lens") or "unknown"})


# -- device records --------------------------------------------------------------------------------
def recorded_devices(dataset: Dataset) -> dict[str, Any] | None:
    """The devices that captured ``dataset``: its ``devices`` record, else what datasets made before
    it existed kept (``rig.port``, ``camera.driver``), else None."""
    devices = dataset.manifest.get("devices")
    if isinstance(devices, dict) and isinstance(devices.get("rig"), dict) and isinstance(devices.get("camera"), dict):
        return devices
    port = dataset.manifest.get("rig", {}).get("port")
    driver = dataset.camera.get("driver")
    if port and driver:
        rig_kind = port if port in ("sim", "instant") else "grbl"
        rig = {"kind": rig_kind, "profile": dataset.manifest.get("rig", {}).get("name", "")}
        if rig_kind == "grbl":
            rig["port"] = port
        try:
            cam = CameraSpec.parse(driver)
        except InputError:
            return None
        return {"rig": rig, "camera": {"kind": cam.kind, "spec": cam.text}}
    return None


def rig_spec_of(record: dict[str, Any]) -> str:
    """The ``--port`` word that opens a recorded rig again ("" when the record does not say: the
    device parser then refuses it as "no rig given", naming ``--port``)."""
    kind = record.get("kind", SIM)
    if kind in ("grbl", "dryve", "canopen") or record.get("origin"):     # origin: a plugin kind's NAME:ARGS
        port = record.get("port")
        return str(port) if port else ""
    return str(kind) if kind else ""


def device_differences(recorded: dict[str, Any], current: dict[str, Any]) -> list[str]:
    """What makes ``current`` other devices than ``recorded`` (an empty list: the same devices).

    A rig is the same when its kind, profile and firmware agree (the port name may change between
    sessions: USB ports are renumbered); a camera when its kind, model, serial and hot folder agree.
    Fields one side does not know are not compared."""
    out = []
    for dev, keys in (("rig", ("kind", "profile", "firmware")), ("camera", ("kind", "model", "serial", "folder"))):
        a, b = recorded.get(dev, {}), current.get(dev, {})
        for key in keys:
            if key in ("kind",) or (a.get(key) and b.get(key)):
                if a.get(key) != b.get(key):
                    out.append(f"{dev} {key}: the dataset was captured with {a.get(key)!r}, this scan has "
                               f"{b.get(key)!r}")
    return out


def describe_devices(record: dict[str, Any]) -> str:
    rig, cam = record.get("rig", {}), record.get("camera", {})
    rig_text = {"sim": "the simulated rig", "instant": "the instant rig",
                "sim-dryve": "the emulated dryve D1 drives", "sim-canopen": "the emulated CANopen drives"}.get(
        rig.get("kind"), f"the rig on {rig.get('port', rig.get('kind', '?'))}" + (f" ({rig['firmware']})" if rig.get("firmware") else ""))
    cam_text = {"sim": "the simulated camera", "instant": "the instant camera"}.get(
        cam.get("kind"), f"camera {cam.get('spec', cam.get('kind', '?'))}" +
        (f" ({cam['model']})" if cam.get("model") else ""))
    return f"{rig_text} and {cam_text}"


# -- homing policy ---------------------------------------------------------------------------------
def _last_position(dataset: Dataset, plan: ScanPlan, ahead: int = 3) -> tuple[tuple[float, float], str, list]:
    """Where the last run left the rig: the reported position of the last captured view, its name,
    and the commanded positions of the next ``ahead`` views in plan order (the run may have been on
    its way there: the rig moves on while a view is still transferring)."""
    done = [v for v in dataset.done_views() if v.get("reported_mm") and v.get("captured_at")]
    last = max(done, key=lambda v: v.get("captured_at") or "")
    order = [(v.row, v.column) for v in plan.with_subset(None).views()]
    finished = {(v["row"], v["column"]) for v in dataset.views if is_finished(v)}
    following: list[tuple[int, int]] = []
    if (last["row"], last["column"]) in order:
        i = order.index((last["row"], last["column"]))
        following = [cell for cell in order[i + 1:] if cell not in finished][:ahead]
    reported = last.get("reported_mm")
    assert reported, "every view in done has a reported position"     # filtered above
    return ((float(reported[0]), float(reported[1])), view_label(last["row"], last["column"]),
            [plan.position_mm(*cell) for cell in following])


def _distance_to_path(p: tuple[float, float], path: list[tuple[float, float]]) -> float:
    """Distance (mm) from ``p`` to the polyline through ``path``."""
    best = math.dist(p, path[0])
    for a, b in zip(path, path[1:]):
        dx, dy = b[0] - a[0], b[1] - a[1]
        length2 = dx * dx + dy * dy
        t = 0.0 if length2 == 0 else max(0.0, min(1.0, ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / length2))
        best = min(best, math.dist(p, (a[0] + t * dx, a[1] + t * dy)))
    return best


class RigNotHomed(DeviceError):
    """The rig is not homed (or locked in ALARM) and can home: homing first would let the scan go on
    (the GUI offers it; the CLI's line names ``--home``)."""

    kind = "rig-not-homed"


class RigUsedSince(DeviceError):
    """A resume whose rig stands where this dataset's last view was taken, but another dataset's scan
    used the rig since: standing at the same numbers is then a coincidence (the other scan may have
    ended there, after the rig was homed again or given another origin), not this dataset's own
    position. ``other``: that scan's record (:func:`last_scan_on_rig`); the GUI asks the operator, the
    CLI's line says how to resume from a known reference (``--home``)."""

    kind = "rig-used-since"

    def __init__(self, message: str, other: dict[str, Any], last_view: str):
        super().__init__(message)
        self.other, self.last_view = other, last_view


def _dataset_identity(dataset: Dataset) -> dict[str, Any]:
    return {"dataset": str(Path(dataset.root).resolve()), "created": dataset.manifest.get("created")}


def note_scan_on_rig(port: str, dataset: Dataset) -> None:
    """Record that ``dataset``'s scan now uses the rig on ``port`` (read back by :func:`last_scan_on_rig`)."""
    from lfstudio.dataset.atomic import atomic_write_json
    from lfstudio.support.locks import rig_record_path

    if not port:
        return
    try:
        atomic_write_json(rig_record_path(port), {**_dataset_identity(dataset), "at": now_iso()})
    except OSError as exc:        # the record only sharpens a later resume check; the scan goes on
        log.warning("could not note the scan on the rig %s: %s", port, exc)


def last_scan_on_rig(port: str) -> dict[str, Any] | None:
    """Which dataset's scan last used the rig on ``port`` (``dataset``: its folder, ``created``, ``at``),
    or None when no scan was recorded for it (or the record is unreadable)."""
    import json

    from lfstudio.support.locks import rig_record_path

    try:
        record = json.loads(rig_record_path(port).read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) and isinstance(record.get("dataset"), str) else None


class RigNotWhereLeft(DeviceError):
    """A resume on the dataset's own rig, which stands elsewhere than where the last run left it (it
    was moved, or lost its position). ``position_mm``: where it reports; ``last_mm`` and ``last_view``:
    the last captured view's position and name (the GUI offers to move the rig there)."""

    kind = "rig-not-where-left"

    def __init__(self, message: str, position_mm: tuple[float, float], last_mm: tuple[float, float],
                 last_view: str):
        super().__init__(message)
        self.position_mm, self.last_mm, self.last_view = position_mm, last_mm, last_view


def rig_command(port: str, config: RigConfig, commands: str) -> str:
    """``lfstudio rig`` as the operator types it for this rig: the port, and the rig profile unless the
    port word implies it (a drive pair's profile always: its feed constants are not guessed)."""
    import shlex

    from lfstudio.studio.devices import implied_rig_profile

    try:
        implied = implied_rig_profile(port)
    except InputError:
        implied = None
    profile = "" if implied == config.name else f" {rig_profile_flag(config.name)}"
    return f"lfstudio rig --port {shlex.quote(port)}{profile} {commands}"


def cli_homing_hint(port: str, config: RigConfig) -> str:
    """How to home from the command line (the end of a "not homed" line)."""
    if config.driver == "cia402":        # each lfstudio process establishes its own reference on drives
        return ("add --home to this command" if config.homing else
                "park the carriage at the left/top end of its travel and add --origin-here to this command") + \
            (", or --keep-drive-reference to accept the position the drives report (they were homed before and "
             "kept it, e.g. after a crash)")
    if config.homing:
        return f"add --home to this command, or first run '{rig_command(port, config, 'home')}'"
    return ("park the carriage at the left/top end of its travel and add --origin-here to this command "
            "(a rig without limit switches cannot home)")


def prepare_rig(rig: Any, config: RigConfig, port: str, *, home: bool = False, origin_here: bool = False,
                resume_from: tuple[Dataset, ScanPlan] | None = None, how_to_home: str | None = None,
                tolerance_mm: float = RESUME_TOLERANCE_MM, say: Callable[[str], None] | None = None,
                trust_position: bool = False, keep_reference: bool = False) -> list[str]:
    """Apply the homing policy to a connected rig (see the module docstring); returns lines for the
    operator. ``rig``: the driver, or its :class:`~lfstudio.rig.worker.DeviceWorker`. ``how_to_home``:
    the end of a "not homed" line (default: the CLI's). ``trust_position``: the operator confirmed that
    the rig kept this dataset's reference although another scan used it since (:class:`RigUsedSince`).
    ``keep_reference``: the operator accepts the CiA 402 drives' own reference without homing (logged;
    the drives are never taken as homed otherwise). Raises InputError/DeviceError with one line."""
    if isinstance(rig, RunsOnWorker):                            # a DeviceWorker: call through its queue
        rig = _WorkerCalls(rig)
    fix = how_to_home or cli_homing_hint(port, config)
    notes: list[str] = []
    if home and origin_here:
        raise InputError("--home/--origin-here", "give one of them",
                         "--home for a rig with limit switches, --origin-here for one without")
    if keep_reference and (home or origin_here):
        raise InputError("--keep-drive-reference", "homing or setting the origin makes a new reference",
                         "give --keep-drive-reference without --home/--origin-here")
    if keep_reference:
        if config.driver != "cia402":
            raise InputError("--keep-drive-reference", f"rig profile {config.name!r} is a GRBL controller, whose "
                             "reference lfstudio keeps by itself", "leave it out, or --home")
        rig.accept_reference()
        notes.append("the drives' own reference is kept (not homed on this connection: the operator accepted it)")
    if home:
        if not config.homing:
            raise InputError("--home", f"rig profile {config.name!r} has no limit switches, so it cannot home",
                             "park the carriage at the left/top end of its travel and use --origin-here")
        if say is not None:
            say("homing the rig (it drives to its limit switches; Ctrl+C stops it) …")
        rig.home()
        notes.append("rig homed")
        return notes
    if origin_here:
        if config.homing:
            raise InputError("--origin-here", f"rig profile {config.name!r} homes with its limit switches",
                             "--home")
        if rig.status().state is RigState.ALARM:
            rig.unlock()
        rig.set_origin()
        notes.append("origin (0, 0) set at the carriage's current position")
        return notes
    status = rig.status()
    if status.state is RigState.ALARM and isinstance(status.extra, dict) and "power_state" in status.extra:
        reset = ("Reset fault in the Rig panel, then start again" if how_to_home is not None   # the window's words
                 else rig_command(port, config, "reset"))
        raise DeviceError(f"the rig on {port} has a drive in fault, nothing was moved: {status.message} ({reset})")
    if status.state is RigState.ALARM:
        reason = status.message if status.message.startswith("ALARM") else \
            "locked since it was powered up or reset" if config.homing else "locked"
        raise (RigNotHomed if config.homing else DeviceError)(f"the rig on {port} is in ALARM ({reason}): {fix}")
    if status.state is RigState.DISCONNECTED:
        raise DeviceError(f"the rig on {port} is not connected: {status.message}")
    if not status.homed:
        raise (RigNotHomed if config.homing else DeviceError)(
            f"the rig on {port} is not homed (its position is unknown): {fix}")
    if resume_from is not None and status.position_mm is not None:
        dataset, plan = resume_from
        if any(v.get("reported_mm") and v.get("captured_at") for v in dataset.done_views()):
            last, name, ahead = _last_position(dataset, plan)
            back = ("--keep-drive-reference " if config.driver == "cia402" and how_to_home is None else "") + \
                f"move {last[0]:g} {last[1]:g}"
            off = _distance_to_path(status.position_mm, [last, *ahead])
            if off > tolerance_mm:
                x, y = status.position_mm
                raise RigNotWhereLeft(
                    f"the rig reports ({x:.3f}, {y:.3f}) mm, but the dataset's last view {name} was captured at "
                    f"({last[0]:.3f}, {last[1]:.3f}) mm ({off:.2f} mm away, tolerance {tolerance_mm:g} mm): it was "
                    f"moved or lost its position. To resume from a known position: {fix}, then move it back to "
                    f"({last[0]:.3f}, {last[1]:.3f}) mm ({rig_command(port, config, back)})",
                    (x, y), last, name)
            other = last_scan_on_rig(port)
            if other is not None and other.get("dataset") != _dataset_identity(dataset)["dataset"] \
                    and not trust_position:
                if how_to_home is not None:
                    again = how_to_home
                elif config.homing:
                    again = "add --home to this command (the rig homes, then the scan continues with the next view)"
                else:
                    again = ("park the carriage where this dataset's origin was set and add --origin-here to this "
                             "command")
                raise RigUsedSince(
                    f"the rig on {port} stands where this dataset's last view {name} was taken, but the last scan "
                    f"on it was {other['dataset']} ({other.get('at', 'time unknown')}): it may have been homed "
                    f"again or given another origin since, so standing at the same numbers proves nothing. To "
                    f"resume from a known reference: {again}", other, name)
            notes.append(f"rig at ({status.position_mm[0]:.3f}, {status.position_mm[1]:.3f}) mm, where the last "
                         f"run left it (last view {name}): continuing")
    return notes


def check_plan_on_controller(rig: Any, plan: ScanPlan) -> None:
    """Refuse a plan that reaches beyond what the connected controller itself allows (GRBL's travel
    ``$130``/``$131`` with its soft limits on), once it is connected and before the first move: each view
    would otherwise be refused, retried and the scan stopped with advice about the cable. The corners
    of the grid are checked by the driver's own ``check_target`` (nothing is sent)."""
    driver = driver_of(rig)
    if not isinstance(driver, ChecksTargets):
        return
    check = driver.check_target
    x0, x1, y0, y1 = plan.extent_mm()
    for x, y in ((x0, y0), (x1, y1), (x0, y1), (x1, y0)):
        try:
            check(x, y)
        except SoftLimitError as exc:
            raise InputError("--grid/--spacing-mm/--offset-mm",
                             f"the grid reaches ({x:g}, {y:g}) mm, out of the controller's reach: {exc}",
                             "a grid inside that range (fewer views, a smaller spacing or another offset), "
                             "or the controller's travel set to the rig's ($130/$131)") from None


class _WorkerCalls:
    """``worker.call(name, ...)`` spelled ``rig.name(...)`` (homing may take minutes)."""

    def __init__(self, worker: Any):
        self._worker = worker

    def __getattr__(self, name: str) -> Callable[..., Any]:
        return lambda *args: self._worker.call(name, *args, timeout_s=600)


# -- the session -----------------------------------------------------------------------------------
class DeviceChangeRefused(LfError):
    """A resume with other devices than the dataset's own, without the operator's explicit consent."""

    kind = "device-change-refused"

    def __init__(self, root: Path, recorded: dict, current: dict, differences: list[str], how_to_allow: str):
        self.recorded, self.current, self.differences = recorded, current, differences
        before, now = describe_devices(recorded), describe_devices(current)
        detail = f" ({'; '.join(differences)})" if before == now else ""
        super().__init__(f"{root} was captured with {before}; this resume has {now}{detail}. {how_to_allow}")


@dataclass
class SharedDevices:
    """Devices opened elsewhere (the GUI's Rig and Camera panels, its simulated studio): drivers or
    their DeviceWorkers, the device record (:meth:`lfstudio.studio.devices.Studio.record`), the rig's
    port, and how the operator homes it there."""

    rig: Any
    camera: Any
    record: dict[str, Any]
    port: str = ""
    how_to_home: str = "home it in the Rig panel (Rig → Home), then start again"


@dataclass
class ScanRequest:
    """What to scan with. ``rig``/``camera``: device words (:mod:`lfstudio.studio.devices`); None
    means ``sim`` for a new dataset and the dataset's own devices for a resume. ``rig_config``: None
    means the dataset's rig profile (resume) or the default profile."""

    folder: Path
    resume: bool = False
    rig: str | None = None
    camera: str | None = None
    rig_config: RigConfig | None = None
    home: bool = False
    origin_here: bool = False
    allow_device_change: bool = False
    recapture: Sequence[tuple[int, int]] | None = None
    retries: int = 2
    time_scale: float = 1.0
    exposure_s: float = REFERENCE.exposure_s
    transfer_s: float = REFERENCE.transfer_s
    seed: int = 0
    sim_width_px: int | None = None
    trigger_command: Sequence[str] | None = None
    camera_options: dict[str, Any] = field(default_factory=dict)
    #: the rig kind's connection options (lfstudio scan --rig-option; the window: the Rig panel's form)
    rig_options: dict[str, Any] = field(default_factory=dict)
    #: camera settings made before the first view (lfstudio scan --set; the window: the Camera panel)
    camera_settings: dict[str, Any] = field(default_factory=dict)
    engine_options: dict[str, Any] = field(default_factory=dict)
    trust_rig_position: bool = False
    keep_drive_reference: bool = False
    #: fly scanning (lfstudio.scan.fly): rows at constant speed, a triggered frame per view
    fly: bool = False
    #: --keep-on-card (lfstudio.scan.card): pictures stay on the camera's card, downloaded at row changes
    keep_on_card: bool = False
    fly_speed_mm_s: float | None = None
    blur_limit_px: float = 0.5
    #: who fires the camera in a fly scan: "hardware" (the controller's output at the positions),
    #: "software" (this computer, timed from the position reports), "auto" (hardware where both can)
    fly_trigger: str = "auto"


class ScanSession:
    """See the module docstring. ``doing``: how the holder of the locks describes itself
    (``"lfstudio scan"``, ``"the lfstudio window"``). ``notes``: lines for the operator."""

    def __init__(self, request: ScanRequest, *, doing: str = "scanning", devices: SharedDevices | None = None,
                 log_line: Callable[[str], None] | None = None):
        self.request = request
        self.shared = devices
        self.folder = Path(request.folder)
        self.doing = doing
        self.notes: list[str] = []
        self._log_line = log_line
        self.lock: Lock | None = None
        self.studio: Studio | None = None    # the devices this session opened (None with shared devices)
        self.dataset: Dataset | None = None
        self.plan: ScanPlan | None = None
        self.engine: Any = None
        self.rig_config: RigConfig | None = None
        self._created_folder = False

    def note(self, text: str) -> None:
        self.notes.append(text)
        log.info("scan session: %s", text)
        if self._log_line is not None:
            self._log_line(text)

    # -- steps -------------------------------------------------------------------------------------
    def lock_dataset(self) -> Lock:
        """Take the dataset folder's lock (creating the folder for a new scan); check the folder."""
        req = self.request
        manifest = self.folder / MANIFEST_NAME
        if req.resume and not manifest.is_file():
            raise InputError(OUT_FIELD, f"{self.folder} holds no dataset to resume", "the folder of an interrupted scan")
        lock = dataset_lock(self.folder, f"{self.doing} {self.folder}")
        check_new_dataset_folder(self.folder, OUT_FIELD, add_to_dataset=req.resume, stem="lfstudio-scan",
                                 dataset_fix="add --resume to continue it, or choose a new folder",
                                 in_use_fix=lock.hint)
        if not self.folder.exists():
            self.folder.mkdir(parents=True)
            self._created_folder = True
        self.lock = lock.acquire()
        if self.lock.taken_over is not None:
            self.note(f"took over the lock of {self.folder} left by {self.lock.taken_over.describe()}, "
                      "which is no longer running")
        if not req.resume and manifest.exists():      # created by another process in the meantime
            raise InputError(OUT_FIELD, f"{self.folder} already holds a dataset",
                             "add --resume to continue it, or choose a new folder")
        return self.lock

    def _device_words(self, existing: Dataset | None) -> tuple[str, str, dict | None]:
        """The rig and camera words to open, and the record to compare them with (resume)."""
        req = self.request
        if existing is None:
            return req.rig or SIM, req.camera or SIM, None
        record = recorded_devices(existing)
        if self.shared is not None:
            if record is None:
                self.note(f"warning: {existing.manifest_path} does not record which devices captured it (made by "
                          "an older lfstudio); resuming with the connected devices, recorded from now on")
            return "", "", record
        if record is None:
            if req.rig is None or req.camera is None:     # never the simulated studio in a real scan's place
                raise InputError("--port/--camera", f"{existing.manifest_path} does not record which devices "
                                 "captured it (made by an older lfstudio)",
                                 "name them: --port PORT --camera CAMERA (sim for the simulated studio)")
            rig, cam = req.rig, req.camera
            self.note(f"warning: {existing.manifest_path} does not record which devices captured it (made by an "
                      f"older lfstudio); resuming with --port {rig} --camera {cam}, recorded from now on")
            return rig, cam, None
        rig = req.rig or rig_spec_of(record["rig"])
        cam = req.camera or record["camera"].get("spec") or record["camera"].get("kind", SIM)
        if req.rig is None or req.camera is None:
            self.note(f"resuming with the dataset's own devices: {describe_devices(record)}")
        return rig, cam, record

    def open(self, plan_for: PlanFor) -> Any:
        """Run steps 1-4 of the module docstring; returns the (not started) :class:`ScanEngine`.
        On any error everything taken so far is released again."""
        try:
            return self._open(plan_for)
        except BaseException as exc:
            if isinstance(exc, KeyboardInterrupt) and self.studio is not None:
                try:                      # Ctrl-C while homing or checking: no motion left running
                    self.studio.rig.stop()
                except Exception as stop_exc:  # noqa: BLE001
                    log.warning("stopping the rig after Ctrl-C: %s", stop_exc)
            self.close()
            raise

    def _open(self, plan_for: PlanFor) -> Any:
        from lfstudio.rig.profile import DEFAULT_RIG, load_rig
        from lfstudio.scan.engine import ScanEngine

        req = self.request
        for option, number, value in (("--time-scale", TIME_SCALE, req.time_scale), ("--retries", RETRIES, req.retries),
                                      ("--exposure-s", EXPOSURE_S, req.exposure_s),
                                      ("--transfer-s", TRANSFER_S, req.transfer_s)):
            number.check(option, value)        # before any folder, lock or device
        for given, parse in ((req.rig, RigSpec.parse), (req.camera, CameraSpec.parse)):
            if given is not None:
                parse(given)              # a typo is reported before any folder is made
        self.lock_dataset()
        existing = Dataset.open(self.folder) if req.resume else None
        if existing is not None:
            existing.journal_lock = self.lock     # the scan owns the journal; other stages merge beside it
        rig_words, cam_words, record = self._device_words(existing)
        config = req.rig_config
        if config is None:
            profile = (record or {}).get("rig", {}).get("profile") if record else None
            if not profile and existing is not None:
                profile = existing.manifest.get("rig", {}).get("name")
            if not profile and rig_words:
                profile = implied_rig_profile(rig_words)     # real drives without --rig-profile: refused by name
            try:
                config = load_rig(profile or DEFAULT_RIG)
            except InputError as exc:       # never another rig's limits, speeds and homing in its place
                if not profile:
                    raise
                from lfstudio.resources import load_presets

                installed = load_presets("rigs")
                why = "is not installed" if profile not in installed else f"cannot be read: {exc}"
                raise InputError(RIG_PROFILE_FIELD, f"the dataset's rig profile {profile!r} {why}; its limits, "
                                 "speeds and homing are not guessed", f"install it again (rigs.toml), or name this "
                                 f"rig's profile: {' or '.join(rig_profile_flag(n) for n in installed)}") from None
        self.rig_config = config
        plan, scene = plan_for(existing, config)
        if existing is not None:
            problems = check_resume_matches(existing, plan)
            if problems:
                raise InputError(OUT_FIELD, f"{self.folder} holds another scan: " + "; ".join(problems),
                                 "choose a new folder, or set the grid to the dataset's")
            plan = replace(resume_plan(existing, order=plan.order, settle_s=plan.settle_s), bracket=plan.bracket)
            recorded = existing.manifest.get("bracket")
            if plan.bracket is not None and recorded and Bracket.from_manifest(recorded) != plan.bracket:
                have = Bracket.from_manifest(recorded)
                raise InputError(BRACKET_OPTION, f"{plan.bracket.describe()} ({plan.bracket.frames} frames) differs from "
                                 f"the {have.describe()} ({have.frames} frames) the dataset's views were captured with",
                                 words("leave --bracket out with --resume, or scan into a new --out folder",
                                       "empty the Bracket field, or choose a new Folder"))
            single = [v for v in existing.done_views() if not v.get("frames")]
            if plan.bracket is not None and not recorded and single:     # said before the devices connect
                raise InputError(BRACKET_OPTION, f"this dataset has {len(single)} view(s) captured with one picture "
                                 "each; every view of a dataset has the same frames",
                                 words("leave --bracket out with --resume, or scan into a new --out folder",
                                       "empty the Bracket field, or choose a new Folder"))
        if existing is not None and self.shared is None and not req.recapture:
            finished = {(v["row"], v["column"]) for v in existing.views if is_finished(v)}
            if all(v.cell in finished for v in plan.views()):      # files still on a card are not finished
                self.dataset, self.plan = existing, plan
                return None
        if self.shared is None:
            rig_spec, cam_spec = RigSpec.parse(rig_words), CameraSpec.parse(cam_words)
            if record is not None and req.rig is None and rig_spec.kind == "grbl" and \
                    rig_spec.port.startswith("/") and not os.path.exists(rig_spec.port):
                raise DeviceError(f"the dataset was captured with the rig on {rig_spec.port}, which is not there now: "
                                  "connect the rig, or give the port it has now with --port PORT")
            self.note(f"connecting the rig ({rig_spec.text}) and the camera ({cam_spec.text})"   # homing takes a while: say so
                      + (" (the simulated rig homes first)" if rig_spec.simulated
                         and config.homing else ""))
            studio = self.studio = open_studio(
                rig_spec, cam_spec, config, doing=f"{self.doing} {self.folder}", time_scale=req.time_scale,
                exposure_s=req.exposure_s, transfer_s=req.transfer_s, seed=req.seed,
                view_region_mm=plan.extent_mm(), sim_width_px=req.sim_width_px,
                trigger_command=req.trigger_command, camera_options=req.camera_options, say=self.note,
                **req.rig_options)
            for line in studio.notes:
                self.note(line)
            for name, value in req.camera_settings.items():      # --set: before the first view
                try:
                    studio.camera.set_setting(name, value)
                except InputError as exc:                        # the camera's own check, named by the option
                    raise InputError(f"--set {name}", str(exc).split(": ", 1)[-1]) from None
                self.note(f"camera setting {name} = {value}")
            rig, camera, current, port = studio.rig, studio.camera, studio.record(), studio.port
            if req.camera_settings:                  # --set: recorded with the camera (not part of its identity)
                current["camera"]["set"] = dict(req.camera_settings)
            fresh = studio.simulator is not None or rig_spec.kind == "instant"   # set up just now, homed
            how_to_home = None
            rig_text, cam_text = rig_spec.text, cam_spec.text
        else:
            rig, camera, current, port = self.shared.rig, self.shared.camera, self.shared.record, self.shared.port
            fresh = current.get("rig", {}).get("kind") == "instant"
            how_to_home = self.shared.how_to_home
            rig_text, cam_text = rig_spec_of(current["rig"]), current["camera"].get("spec", "")
        same_rig = False
        if record is not None and existing is not None:        # a record comes with the dataset (_device_words)
            self._check_devices(existing, record, current)
            same_rig = not any(d.startswith("rig ") for d in device_differences(record, current))
        if not fresh:
            # where the last run left the rig means something only for the same rig, and only to continue
            # its path: a re-capture trusts a homed rig as a new scan does (it drives to each view)
            for line in prepare_rig(rig, config, port, home=req.home, origin_here=req.origin_here,
                                    resume_from=(existing, plan) if existing is not None and same_rig
                                    and not req.recapture else None,
                                    how_to_home=how_to_home, say=self.note,
                                    trust_position=req.trust_rig_position,
                                    keep_reference=req.keep_drive_reference):
                self.note(line)
        elif req.home or req.origin_here:
            self.note("the simulated rig was homed when it started")
        check_plan_on_controller(rig, plan)
        fly = self._decide_fly(rig, camera, plan, scene, config) if req.fly else None
        if req.keep_on_card:
            from lfstudio.scan.card import card_problem

            problem = card_problem(camera)
            card_words = words("--keep-on-card", "Keep pictures on the camera's card")
            if problem is not None:
                raise InputError(card_words, problem, "a gphoto2 camera, or leave it out")
            if req.fly:
                raise InputError(card_words, "a fly scan takes its frames from a camera with triggers, not from "
                                 "a card", "one of the two")
        if existing is None and plan.bracket is not None:       # refused before the dataset is made
            self._check_bracket(plan.bracket, camera)
        self._check_space(plan.with_subset(req.recapture) if req.recapture else plan, camera, scene, existing)
        if existing is None:
            camera_info, lens = describe_camera(driver_of(camera), scene)
            camera_info.setdefault("driver", cam_text)
            rig_info = {"name": config.name, "label": config.label, "port": rig_text}
            dataset = create_scan_dataset(self.folder, plan, rig=rig_info, camera=camera_info, lens=lens,
                                          scene_plan=scene.to_dict() if isinstance(scene, ScenePlan) else None,
                                          devices=current)
        else:
            dataset = existing
            if record is None:
                dataset.manifest["devices"] = current
                dataset.save()
        dataset.journal_lock = self.lock
        self.dataset = dataset
        note_scan_on_rig(port, dataset)           # the next resume of another dataset on this rig knows
        if req.recapture:
            plan = plan.with_subset(req.recapture)
        self.plan = plan
        if fly is not None:
            from lfstudio.scan.fly import FlyScanEngine

            dataset.manifest["acquisition"] = {"mode": "fly", "positions": "recorded", **fly}
            dataset.save()
            self.note(f"fly scan: rows at {fly['speed_mm_s']:.3g} mm/s ({fly['binding']} binds), blur "
                      f"{fly['blur_px']:.2f} px at the near distance; the rows and row changes take about "
                      f"{fly['time_s']:.0f} s")
            self.engine = FlyScanEngine(dataset, plan, rig, camera, retries=req.retries, time_scale=req.time_scale,
                                        recapture=bool(req.recapture), speed_mm_s=fly["speed_mm_s"],
                                        trigger=fly["trigger"], **req.engine_options)
            return self.engine
        engine_class: Any = ScanEngine
        if req.keep_on_card:
            from lfstudio.scan.card import CardBufferEngine

            engine_class = CardBufferEngine
        self.engine = engine_class(dataset, plan, rig, camera, retries=req.retries,
                                   time_scale=req.time_scale, recapture=bool(req.recapture), **req.engine_options)
        return self.engine

    def _decide_fly(self, rig: Any, camera: Any, plan: ScanPlan, scene: Any, config: RigConfig) -> dict[str, Any]:
        """The row speed of a fly scan (lfstudio.planning.fly) from the devices as they are: the camera's
        exposure and frame rate, the controller's measured position-report rate, the rig's axes; refused
        (InputError naming --fly) with the numbers when the devices or the limits do not allow one."""
        import time as _time

        from lfstudio.planning.fly import FlyInputs, plan_fly
        from lfstudio.scan.fly import fly_problem

        req = self.request
        from lfstudio.errors import words

        fly_words = words("--fly", "Continuous motion")
        problem = fly_problem(rig, camera)
        if problem is not None:
            raise InputError(fly_words, problem, "a camera with triggers and a controller that reports its position")
        if plan.bracket is not None:
            raise InputError(fly_words, "an exposure bracket needs the carriage to stand still", "one picture per view")
        if req.time_scale <= 0:
            raise InputError(words("--time-scale", "Simulation time scale"), "a fly scan needs simulated time to pass", "> 0 for a fly scan")
        driver, rig_driver = driver_of(camera), driver_of(rig)
        settings = driver.settings() if isinstance(driver, Camera) else {}
        exposure = settings.get("shutter_s", settings.get("exposure_s"))
        if not isinstance(exposure, (int, float)) or exposure <= 0:
            raise InputError(fly_words, "the camera does not tell its exposure time", "a camera reporting shutter_s")
        fps = settings.get("frame_rate_fps")
        camera_info, lens = describe_camera(driver, scene)
        if scene is not None:
            near_mm, focal, pitch = scene.near_m * 1000.0, float(scene.focal_length_mm), scene.pixel_pitch_used_um
        else:
            from lfstudio.studio.simulated import SimulatedCamera

            studio = driver.studio if isinstance(driver, SimulatedCamera) else None      # the virtual studio's
            near_mm = float(studio.near_m if studio is not None else REFERENCE.near_m) * 1000.0
            focal = float(lens.get("focal_length_mm") or REFERENCE.focal_length_mm)
            pitch = float(camera_info.get("pixel_pitch_um") or REFERENCE.pixel_pitch_um)
        t0 = _time.monotonic()
        for _ in range(5):                     # how fast the controller answers where it is
            rig_driver.report()
        per_report_s = (_time.monotonic() - t0) / 5 / req.time_scale      # in simulated time on a simulator
        h, v = config.horizontal, config.vertical
        inputs = FlyInputs(columns=plan.columns, rows=plan.rows, spacing_mm=plan.spacing_mm,
                           exposure_s=float(exposure), near_mm=near_mm, focal_length_mm=focal, pixel_pitch_um=pitch,
                           blur_limit_px=req.blur_limit_px,
                           frame_rate_fps=float(fps) if isinstance(fps, (int, float)) and fps > 0 else None,
                           report_rate_hz=1.0 / max(per_report_s, 1e-6),
                           max_speed_mm_s=(h.max_speed_mm_s, v.max_speed_mm_s),
                           acceleration_mm_s2=(h.acceleration_mm_s2, v.acceleration_mm_s2),
                           travel_mm=h.soft_max_mm - h.soft_min_mm, settle_s=plan.settle_s,
                           speed_mm_s=req.fly_speed_mm_s)
        result = plan_fly(inputs)
        if not result.possible:
            raise InputError(fly_words, result.refusal)
        trigger, why_not = self._fly_trigger(rig_driver, driver, plan, result.speed_mm_s)
        if req.fly_trigger == "hardware" and trigger != "hardware":
            raise InputError(words("--trigger", "Trigger"), f"no hardware trigger: {why_not}",
                             words("--trigger software", "Software or Automatic in the Scan panel's Trigger list")
                             + ", or fix that")
        if req.fly_trigger == "software":
            trigger = "software"
        elif trigger != "hardware":
            self.note(f"fly scan: software trigger ({why_not})")
        return {"speed_mm_s": result.speed_mm_s, "trigger": trigger, "binding": result.binding, "blur_px": result.blur_px,
                "blur_limit_px": req.blur_limit_px, "time_s": result.time_s,
                "limits_mm_s": {k: round(val, 4) for k, val in result.limits_mm_s.items()},
                "report_rate_hz": round(1.0 / max(per_report_s, 1e-6), 1)}

    @staticmethod
    def _fly_trigger(rig: Any, camera: Any, plan: ScanPlan, speed_mm_s: float) -> tuple[str, str]:
        """("hardware", "") when the controller can drive the camera's trigger line at each view of
        this plan at this speed, else ("software", why not, with the numbers)."""
        from lfstudio.rig.camera import LineTriggered
        from lfstudio.rig.motion import PulsesAtPositions

        if not isinstance(camera, LineTriggered):
            return "software", (f"the camera ({name_of(camera, type(camera).__name__)}) takes no triggers "
                                "from a hardware line lfstudio drives")
        problem = camera.line_trigger_problem()
        if problem is not None:
            return "software", problem
        if not isinstance(rig, PulsesAtPositions):
            return "software", (f"the axis controller ({type(rig).__name__}) has no output lfstudio can switch "
                                "at positions during a move")
        problem = rig.pulse_problem(float(plan.spacing_mm[0]), float(speed_mm_s))
        if problem is not None:
            return "software", problem
        return "hardware", ""

    def _check_bracket(self, bracket: Bracket, camera: Any) -> None:
        """The bracket's shutter times among the camera's choices: else InputError naming --bracket
        before the dataset is made (the disk is checked for every scan: :meth:`_check_space`)."""
        from lfstudio.scan.engine import bracket_on_camera

        times, _ = bracket_on_camera(bracket, driver_of(camera), caller_of(camera))
        self.note(f"exposure bracket {bracket.describe()}: " + ", ".join(f"{t:.6g} s" for t in times)
                  + " at every view")

    def _check_space(self, plan: ScanPlan, camera: Any, scene: Any, existing: Dataset | None) -> None:
        """Every view still to capture fits the disk of the dataset folder and, for a camera that keeps
        its pictures on its card, the card (:mod:`lfstudio.scan.preflight`): else
        :class:`~lfstudio.scan.preflight.ScanTooLarge` naming the need, the free space, the folder and
        the fix, before the dataset is made. A camera whose frame size nothing tells (a gphoto2
        camera, a hot folder) is checked by the engine right after the first view's frames arrive."""
        from lfstudio.scan.store import stored_view_bytes
        from lfstudio.scan.preflight import MIN_FREE_BYTES, card_shortfall, disk_shortfall, view_size

        finished = {(v["row"], v["column"]) for v in existing.views if is_finished(v)} if existing is not None else set()
        views = sum(1 for v in plan.views() if self.request.recapture or v.cell not in finished)
        frames = plan.bracket.frames if plan.bracket is not None else 1
        driver = driver_of(camera)
        info, _ = describe_camera(driver)
        per_image = None
        if isinstance(scene, ScenePlan) and info.get("sensor_px") is None:
            try:
                per_image = scene.derive(check_travel=False).bytes_per_image
            except (LfError, ValueError, ArithmeticError) as exc:     # the plan was checked before: a note only
                log.info("the plan's image size not known: %s", exc)
        size = view_size(frames, stored_view_bytes=stored_view_bytes(existing) if existing is not None else 0,
                         sensor_px=info.get("sensor_px"), plan_bytes_per_image=per_image)
        if size is None:
            self.note("the camera's picture size is not known before its first picture: the free space for the "
                      "whole scan is checked right after the first view")
        else:
            manifest = existing.manifest_path.stat().st_size if existing is not None and \
                existing.manifest_path.exists() else 0
            short = disk_shortfall(self.folder, views, size, free_bytes(self.folder),
                                   min_free_bytes=self.request.engine_options.get("min_free_bytes", MIN_FREE_BYTES),
                                   manifest_bytes=manifest)
            if short is not None:
                raise short
        if isinstance(driver, HasCardSpace):
            try:
                card = caller_of(camera)("card_space")
            except (DeviceError, OSError) as exc:        # where the driver cannot read it: a note
                self.note(f"the camera's card space could not be read ({exc})")
                card = None
            short = card_shortfall(card, views, frames, size.frame_bytes if size is not None else None)
            if short is not None:
                raise short

    def _check_devices(self, dataset: Dataset, record: dict, current: dict) -> None:
        differences = device_differences(record, current)
        if not differences:
            if record.get("rig", {}).get("port") != current.get("rig", {}).get("port") and \
                    current["rig"].get("kind") == "grbl":
                self.note(f"the rig's port changed from {record['rig'].get('port')} to {current['rig'].get('port')} "
                          "(same profile and firmware)")
            dataset.capture_devices = None
            return
        if not self.request.allow_device_change:
            how = ("To resume with its own devices, connect them in the Rig and Camera panels." if self.shared is not None else
                   "Resume without --port/--camera to use the dataset's own devices, or add "
                   f"{ALLOW_CHANGE_OPTION} to continue with these (the change is recorded in the dataset)")
            raise DeviceChangeRefused(dataset.root, record, current, differences, how)
        change = {"at": now_iso(), "devices": current, "differences": differences}
        dataset.manifest.setdefault("device_changes", []).append(change)
        dataset.save()
        dataset.capture_devices = current
        self.note(f"device change recorded in {dataset.manifest_path}: " + "; ".join(differences))

    def close(self) -> None:
        """Close the devices, then release the dataset lock (idempotent)."""
        studio, self.studio = self.studio, None
        if studio is not None:
            studio.close()
        dataset = self.dataset
        if dataset is not None:
            dataset.close()
        lock, self.lock = self.lock, None
        if lock is None:
            return
        if self._created_folder and self.dataset is None and \
                {p.name for p in self.folder.iterdir()} <= {lock.path.name, MANIFEST_LOCK_NAME}:
            (self.folder / MANIFEST_LOCK_NAME).unlink(missing_ok=True)
            lock.remove()                 # a new scan that never started leaves no folder behind
            try:
                self.folder.rmdir()
            except OSError:
                pass
        else:
            lock.release()
