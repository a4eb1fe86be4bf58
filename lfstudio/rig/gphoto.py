"""Tethered capture over USB with libgphoto2 (python-gphoto2 2.5 or newer).

Contract:

- One camera session stays open from :meth:`GPhotoCamera.connect` to :meth:`disconnect` (opening
  one per shot costs seconds and confuses some bodies). Where the body has a ``capturetarget``
  setting, captures go to its RAM ("Internal RAM").
- :meth:`capture` triggers the shot (``camera.capture``), calls ``on_exposed`` when the camera
  has the picture, collects the files the shot added (in RAW + JPEG mode ``capture`` names one
  file and the other arrives as a ``GP_EVENT_FILE_ADDED``), downloads each one to the view's
  stem + the file's suffix (RAW first, the JPEG as a sidecar), checks each size against the
  camera's file info, writes it atomically and deletes it on the camera.
- python-gphoto2 call style (2.5+): ``camera.file_get(folder, name, type)`` and
  ``camera.capture_preview()`` take no CameraFile and return one (passing one returns None).
- Settings have our names (:data:`SETTINGS`: ``shutter_s``, ``aperture``, ``iso``, ...) mapped
  onto the body's config widgets. A value is matched by value against the choices the camera
  offers (0.01 finds "1/100" or "0.0100s", 8 finds "f/8" or "8"); a value it does not offer is
  refused with the list of its choices. :meth:`describe_settings` gives the offered settings as
  :class:`~lfstudio.rig.camera.CameraSetting` data for a GUI.
- Each capture reports the exposure settings the camera gives after the shot (``shutter_s`` is
  the shutter time, not the call time) and the camera's identity (model, serial, lens) in
  ``CaptureResult.record``; :meth:`identity` gives the same for the dataset's camera record.
- Every libgphoto2 error becomes a message an operator can act on (:func:`gp_message`).

The python-gphoto2 module is passed in (``gp``) so tests can wrap it at that boundary. The test
suite runs this driver against libgphoto2's own virtual PTP camera (``VCAMERADIR``), see
``tests/rig/test_gphoto_vusb.py``.
"""

from __future__ import annotations

import logging
import math
import os
from types import SimpleNamespace
import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from lfstudio.dataset import images
from lfstudio.dataset.atomic import atomic_write_with
from lfstudio.errors import DeviceError, InputError
from lfstudio.rig.camera import CameraSetting, CameraStatus, CaptureResult

log = logging.getLogger(__name__)
# Log records keep their arguments: a libgphoto2 error logged as itself would keep its traceback, and
# with it the gp.Camera of the failed call, alive as long as a handler holds the record. So errors are
# logged as text (libgphoto2's virtual camera showed it: its store lives until no gp.Camera is left).

# -- reading the camera's texts ---------------------------------------------------------------------
def _ratio_or_number(text: str) -> float | None:
    m = re.fullmatch(r"([0-9]*\.?[0-9]+)/([0-9]*\.?[0-9]+)", text)
    if m:
        den = float(m.group(2))
        return float(m.group(1)) / den if den else None
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def parse_shutter_s(text: Any) -> float | None:
    """Seconds from a shutter-speed text: "1/100", "0.0100s", "2", '2.5"', "1/4000 s"; None for
    "Bulb", "Auto", "Time" and other words."""
    t = str(text).strip().lower().replace(" ", "")
    for unit in ("sec", "s", '"', "''"):
        if t.endswith(unit):
            t = t[: -len(unit)]
            break
    value = _ratio_or_number(t)
    return value if value is not None and value > 0 else None


def parse_f_number(text: Any) -> float | None:
    """The f-number from "f/8", "F8", "8", "f/5.6"; None for "implicit auto" and other words."""
    t = str(text).strip().lower().replace(" ", "")
    t = t[2:] if t.startswith("f/") else t[1:] if t.startswith("f") else t
    value = _ratio_or_number(t)
    return value if value is not None and value > 0 else None


def parse_iso(text: Any) -> int | None:
    """ISO from "100", "ISO 100", "100.0"; None for "Auto" and other words."""
    t = str(text).strip().lower().replace(" ", "")
    t = t[3:] if t.startswith("iso") else t
    value = _ratio_or_number(t)
    return int(round(value)) if value is not None and value > 0 and abs(value - round(value)) < 1e-6 else None


def parse_ev(text: Any) -> float | None:
    """Exposure compensation in EV from "+0.3", "-1", "0", "+1/3"."""
    t = str(text).strip().lower().replace(" ", "").removesuffix("ev")
    sign = -1.0 if t.startswith("-") else 1.0
    value = _ratio_or_number(t.lstrip("+-"))
    return None if value is None else sign * value


def _text(value: Any) -> str:
    return str(value).strip()


@dataclass(frozen=True)
class SettingSpec:
    """How one of our settings maps onto a body's config widgets and how its values compare."""

    widgets: tuple[str, ...]                       # gphoto2 widget names tried in order (bodies differ)
    type: str                                      # "float", "int", "str"
    unit: str = ""
    parse: Callable[[Any], Any] | None = None      # camera text -> our value (None: it has none)
    ratio_tol: float = 0.0                         # accepted value/choice ratio - 1 (positive values)
    abs_tol: float = 0.0                           # accepted |value - choice|


#: our setting names -> the widgets that hold them and how to read their values
SETTINGS: dict[str, SettingSpec] = {
    "shutter_s": SettingSpec(("shutterspeed", "shutterspeed2", "exposuretime"), "float", "s", parse_shutter_s,
                             ratio_tol=0.03),
    "aperture": SettingSpec(("f-number", "aperture", "fnumber"), "float", "", parse_f_number, ratio_tol=0.03),
    "iso": SettingSpec(("iso", "isospeed"), "int", "", parse_iso),
    "exposure_compensation_ev": SettingSpec(("exposurecompensation", "exposurebiascompensation"), "float", "EV",
                                            parse_ev, abs_tol=0.05),
    "format": SettingSpec(("imagequality", "imageformat"), "str"),
    "image_size": SettingSpec(("imagesize",), "str"),
    "capturetarget": SettingSpec(("capturetarget",), "str"),
}

#: the settings a capture reports into the view's record
EXPOSURE_SETTINGS = ("shutter_s", "aperture", "iso", "exposure_compensation_ev", "format", "image_size")

#: identity fields -> widgets (status section) that hold them
_IDENTITY_WIDGETS = {
    "manufacturer": ("manufacturer",),
    "device_model": ("cameramodel", "model"),
    "serial": ("serialnumber", "eosserialnumber"),
    "firmware": ("deviceversion", "firmwareversion"),
    "lens": ("lensname", "lens", "lensmodel"),
}


def _norm(text: str) -> str:
    return re.sub(r"\s+", "", text).lower()


def value_of(spec: SettingSpec, text: Any) -> Any:
    """Our value for one of the camera's texts (its text when it has no number, e.g. "Auto")."""
    if spec.parse is None:
        return _text(text)
    value = spec.parse(text)
    return _text(text) if value is None else value


def match_choice(name: str, spec: SettingSpec, wanted: Any, choices: Sequence[str], camera: str = "the camera") -> str:
    """The camera's choice text for ``wanted``: its own text (any case or spacing), else the choice
    whose value is nearest to ``wanted``'s within the setting's tolerance. :class:`InputError`
    listing every choice when none fits."""
    text = _text(wanted)
    for choice in choices:
        if _norm(choice) == _norm(text):
            return choice
    if spec.parse is not None:
        if isinstance(wanted, (int, float)) and not isinstance(wanted, bool):
            target = float(wanted)
        else:
            target = spec.parse(text)
        best, best_err = None, math.inf
        if target is not None:
            for choice in choices:
                value = spec.parse(choice)
                if value is None:
                    continue
                if spec.ratio_tol and target > 0 and value > 0:
                    err = abs(math.log(value / target))
                    ok = err <= math.log1p(spec.ratio_tol)
                else:
                    err = abs(value - target)
                    ok = err <= spec.abs_tol + 1e-9
                if ok and err < best_err:
                    best, best_err = choice, err
        if best is not None:
            return best
    else:
        inside = [c for c in choices if _norm(text) and _norm(text) in _norm(c)]
        if len(inside) == 1:
            return inside[0]
    unit = f" {spec.unit}" if spec.unit and isinstance(wanted, (int, float)) else ""
    raise InputError(name, f"{text}{unit} is not offered by {camera}",
                     ", ".join(choices) if choices else "the camera offers no choices")


# -- errors -----------------------------------------------------------------------------------------
_USB_CABLE = "check the cable (a short, direct one, no hub) and reconnect the camera"

#: libgphoto2 result codes (gphoto2-port-result.h, gphoto2-result.h) -> what the operator does
_GP_MESSAGES = {
    -1: "the camera reported an unspecified error: check its screen (a setting it refuses, no card, "
        "no lens); switch it off and on if it repeats",
    -2: "libgphoto2 refused the request (a value or an operation this camera does not accept)",
    -3: "the card or the camera's buffer is full: free space on the card (download or delete "
        "pictures) or wait until the camera has finished writing, then retry",
    -4: "libgphoto2 could not load its camera or port drivers: reinstall python-gphoto2 "
        "(pip install --force-reinstall gphoto2)",
    -5: "the camera's USB port is no longer known (unplugged or renumbered): reconnect the camera",
    -6: "the camera does not support this in its current mode: set its USB connection mode to "
        "'PC Remote' and its mode dial to M",
    -7: f"USB input/output error: {_USB_CABLE}",
    -8: "a libgphoto2 limit was exceeded (too many files on the card or a name too long): free the card",
    -10: "the camera did not answer in time: check the cable, the battery and that the camera is not asleep",
    -20: "this libgphoto2 has no support for that port: install python-gphoto2 from PyPI (its wheel "
         "includes USB support)",
    -21: "this libgphoto2 has no USB support: install python-gphoto2 from PyPI (its wheel includes it)",
    -31: "USB could not be initialised: check that this user may use USB devices (plugdev group, "
         "udev rules of the libgphoto2 package)",
    -34: f"reading from the camera over USB failed: {_USB_CABLE}",
    -35: f"writing to the camera over USB failed: {_USB_CABLE}",
    -37: f"the USB settings could not be changed: {_USB_CABLE}",
    -51: "the USB connection stalled: unplug the camera, plug it in again and reconnect",
    -52: "no camera found on USB: check the cable and that the camera is switched on",
    -53: "the camera is busy with another program (a file manager or photo importer such as gvfs, "
         "Image Capture or Lightroom, or another lfstudio): close it and reconnect",
    -60: "another program has locked the camera's USB device: close it and reconnect",
    -102: f"the data from the camera arrived corrupted: {_USB_CABLE}, then retry",
    -103: "a file of that name already exists on the camera",
    -105: "no camera found: connect it by USB, switch it on and set its USB connection mode to "
          "'PC Remote' (not 'Mass Storage' or 'MTP')",
    -107: "the picture's folder is no longer on the camera (deleted, or the camera restarted): retry the shot",
    -108: "the picture is no longer on the camera (deleted, or the camera restarted): retry the shot",
    -110: "the camera is busy (still writing or transferring the previous picture): wait and retry",
    -112: "cancelled",
    -113: "the camera could not take the picture (could not focus, shutter fault, card missing or "
          "locked): check its screen; set the lens to manual focus",
    -114: "the operating system refused the USB request: check that this user may use USB devices "
          "(plugdev group) and reconnect the camera",
    -115: "the camera's card is full: free space on the card (download or delete pictures), then retry",
}


@dataclass(frozen=True)
class _Code:
    """A libgphoto2 result code where no GPhoto2Error carries it."""

    code: int


def gp_message(exc: BaseException | _Code, action: str, waited_s: float | None = None, camera_said: str = "") -> str:
    """An operator's message for a gphoto2 error raised during ``action``. ``waited_s``: how long
    the call waited (named when the camera did not answer); ``camera_said``: libgphoto2's own
    description of the failure (its context's error text), quoted."""
    code = getattr(exc, "code", None)
    hint = _GP_MESSAGES.get(code) if isinstance(code, int) else None
    if code == -10 and waited_s is not None:
        hint = (f"the camera did not answer within {max(waited_s, 0.0):.0f} s: check the cable, the battery "
                "and that the camera is not asleep")
    if code == -1 and camera_said:
        hint = (f"the camera reported '{camera_said}': check its screen; switch it off and on if it repeats")
        camera_said = ""
    if hint is None:
        what = getattr(exc, "string", None) or str(exc) or type(exc).__name__
        hint = (f"libgphoto2 reported '{what}': switch the camera off and on, reconnect it and retry"
                if code is not None else what)
    said = f" (libgphoto2: '{camera_said}')" if camera_said else ""
    return f"camera: {action} failed: {hint}{said}" + (f" [gphoto2 {code}]" if code is not None else "")


class GPhotoCamera:
    """A :class:`lfstudio.rig.camera.Camera` over python-gphoto2 (see the module docstring)."""

    name = "gphoto2 camera"

    def __init__(self, gp: Any = None, *, delete_from_camera: bool = True, capture_target: str = "Internal RAM",
                 clock: Callable[[], float] = time.monotonic, events_s: float = 3.0):
        if gp is None:
            try:
                import gphoto2 as gp  # noqa: PLC0415 - optional at import time
            except ImportError as exc:
                raise DeviceError(f"camera: python-gphoto2 is not installed ({exc}); "
                                  "install the 'gphoto2' package") from None
        self.gp = gp
        self.delete_from_camera = delete_from_camera
        #: where the body puts a shot ("Internal RAM": downloaded and gone; "Memory card": on its card too)
        self.capture_target = capture_target
        self.events_s = float(events_s)        # how long a capture collects the files it added at most
        self._clock = clock
        self._camera: Any = None
        self._identity: dict[str, str] = {}
        self._widgets: dict[str, str] = {}     # our setting name -> the widget name this body uses
        self._busy = False
        self._message = ""
        self._store_full = False                # the last capture failed on a full card or buffer
        self.shots = 0
        self._lock = threading.Lock()
        # libgphoto2 tells the reason of a failure (e.g. "PTP Store Full") only to a context's error
        # callback; each call gets this context and a failure's message quotes what it said
        self._camera_said: list[str] = []
        self._ctx: tuple = ()
        self._ctx_callbacks: list = []
        try:
            context = gp.Context()
            self._ctx_callbacks.append(context.set_error_func(self._on_camera_error, None))
            self._ctx = (context,)
        except (AttributeError, TypeError) as exc:
            log.debug("gphoto2: no error context: %s", str(exc))

    def _on_camera_error(self, _context: Any, text: Any, _data: Any) -> None:
        said = text.decode("utf-8", "replace") if isinstance(text, bytes) else str(text)
        self._camera_said.append(" ".join(said.split()))

    def _said(self) -> str:
        """What libgphoto2 said about the last failure ('' if nothing); clears it."""
        said, self._camera_said[:] = "; ".join(dict.fromkeys(self._camera_said)), []
        return said

    # -- session ------------------------------------------------------------------------------------
    def connect(self) -> None:
        if self._camera is not None:
            return
        gp = self.gp
        camera = gp.Camera()
        self._camera_said.clear()
        t0 = self._clock()
        try:
            camera.init(*self._ctx)
        except gp.GPhoto2Error as exc:
            raise self._failed(exc, "connect", t0) from None
        self._camera = camera
        self._store_full = False
        try:
            config = camera.get_config(*self._ctx)
        except gp.GPhoto2Error as exc:
            self._camera = None
            self._exit(camera)
            raise self._failed(exc, "reading the camera's settings") from None
        self._widgets = {name: found.get_name() for name, spec in SETTINGS.items()
                         if (found := self._find_widget(config, spec.widgets)) is not None}
        self._identity = self._read_identity(camera, config)
        if "capturetarget" in self._widgets:   # captures go to the camera's RAM, downloaded each time
            try:
                self.set_setting("capturetarget", self.capture_target)
            except (DeviceError, InputError) as exc:
                log.info("gphoto2: capture target left as it is: %s", str(exc))
        self._message = ""
        log.info("gphoto2: connected to %s", self._identity.get("model") or "a camera")

    def _read_identity(self, camera: Any, config: Any) -> dict[str, str]:
        ident = {"driver": "gphoto2", "model": ""}
        try:
            ident["model"] = str(camera.get_abilities().model)
        except (self.gp.GPhoto2Error, AttributeError):
            pass
        for key, names in _IDENTITY_WIDGETS.items():
            widget = self._find_widget(config, names)
            if widget is not None:
                try:
                    ident[key] = _text(widget.get_value())
                except self.gp.GPhoto2Error:
                    pass
        if not ident["model"]:
            ident["model"] = ident.get("device_model", "")
        return ident

    def _exit(self, camera: Any) -> None:
        try:
            camera.exit(*self._ctx)
        except Exception as exc:   # noqa: BLE001 - a camera that is gone cannot be closed
            log.debug("gphoto2: exit: %s", str(exc))

    def disconnect(self) -> None:
        camera, self._camera = self._camera, None
        if camera is not None:
            self._exit(camera)

    def stop(self) -> None:
        """Nothing to abort mid-transfer safely; the capture in progress completes."""

    def _require(self) -> Any:
        if self._camera is None:
            raise DeviceError("camera: not connected; connect the camera first (Camera panel: Connect)")
        return self._camera

    def status(self) -> CameraStatus:
        return CameraStatus(self._camera is not None, self._identity.get("model", ""), self.shots, self._busy,
                            self._message)

    def identity(self) -> dict[str, str]:
        """The camera as it reports itself: driver, model (libgphoto2's name), device_model,
        manufacturer, serial, firmware, lens (the keys the camera has; empty before the first connect)."""
        return dict(self._identity)

    def card_space(self) -> dict[str, Any]:
        """What the camera's card holds for a scan, as the camera reports it (``get_storageinfo``):
        ``keeps`` ("none": shots go to the camera's RAM; "one": each is on the card until its
        download deletes it; "all": they stay on the card), ``free_bytes`` and ``free_images`` over
        its writable stores (None where the camera does not report them), ``label``."""
        gp = self.gp
        camera = self._require()
        target = ""
        if "capturetarget" in self._widgets:
            try:
                target = _text(self._config("reading the capture target").get_child_by_name(
                    self._widgets["capturetarget"]).get_value())
            except (gp.GPhoto2Error, DeviceError) as exc:
                log.info("gphoto2: capture target not read: %s", str(exc))
        in_ram = "ram" in _norm(target) and "card" not in _norm(target)     # libgphoto2: "Internal RAM"
        keeps = "none" if in_ram else "all" if not self.delete_from_camera else "one"
        free_kb = free_images = None
        labels = []
        self._camera_said.clear()
        try:
            stores = camera.get_storageinfo(*self._ctx)
        except gp.GPhoto2Error as exc:
            raise self._failed(exc, "reading the card's free space") from None
        for info in stores:
            fields = int(getattr(info, "fields", 0))
            if fields & gp.GP_STORAGEINFO_STORAGETYPE and int(info.type) in (gp.GP_STORAGEINFO_ST_FIXED_ROM,
                                                                            gp.GP_STORAGEINFO_ST_REMOVABLE_ROM):
                continue                        # a ROM takes no pictures
            if fields & gp.GP_STORAGEINFO_FREESPACEKBYTES:
                free_kb = (free_kb or 0) + int(info.freekbytes)
            if fields & gp.GP_STORAGEINFO_FREESPACEIMAGES and int(info.freeimages) >= 0:
                free_images = (free_images or 0) + int(info.freeimages)
            label = (getattr(info, "label", "") if fields & gp.GP_STORAGEINFO_LABEL else "") or \
                getattr(info, "basedir", "")
            if label:
                labels.append(f"the camera's card {label!r}")
        return {"keeps": keeps, "target": target, "label": ", ".join(labels) or "the camera's card",
                "free_bytes": None if free_kb is None else free_kb * 1024, "free_images": free_images}

    # -- settings -----------------------------------------------------------------------------------
    def _find_widget(self, config: Any, names: Sequence[str]) -> Any:
        for name in names:
            try:
                return config.get_child_by_name(name)
            except self.gp.GPhoto2Error:
                continue
        return None

    def _config(self, action: str) -> Any:
        try:
            camera = self._require()
            self._camera_said.clear()
            return camera.get_config(*self._ctx)
        except self.gp.GPhoto2Error as exc:
            raise self._failed(exc, action) from None

    def _choices(self, widget: Any) -> tuple[str, ...]:
        if widget.get_type() in (self.gp.GP_WIDGET_RADIO, self.gp.GP_WIDGET_MENU):
            return tuple(_text(c) for c in widget.get_choices())
        return ()

    def describe_settings(self) -> list[CameraSetting]:
        """The settings this camera offers (of :data:`SETTINGS`), with their choices, as data."""
        config = self._config("reading the settings")
        out = []
        for name, spec in SETTINGS.items():
            widget = self._find_widget(config, spec.widgets)
            if widget is None:
                continue
            choices = self._choices(widget)
            rng = None
            if widget.get_type() == self.gp.GP_WIDGET_RANGE:
                low, high, step = (float(v) for v in widget.get_range())     # libgphoto2: min, max, increment
                rng = (low, high, step)
            out.append(CameraSetting(name=name, label=_text(widget.get_label()), type=spec.type,
                                     value=value_of(spec, widget.get_value()), choices=choices,
                                     values=tuple(value_of(spec, c) for c in choices), range=rng,
                                     read_only=bool(widget.get_readonly()), unit=spec.unit))
        return out

    def settings(self) -> dict[str, Any]:
        """Current values of the settings this camera has (numbers where the camera's text is one)."""
        config = self._config("reading the settings")
        out: dict[str, Any] = {}
        for name, spec in SETTINGS.items():
            widget = self._find_widget(config, spec.widgets)
            if widget is not None:
                out[name] = value_of(spec, widget.get_value())
        return out

    def set_setting(self, name: str, value: Any) -> None:
        """Set one of :data:`SETTINGS` to ``value``, matched against the choices the camera offers."""
        spec = SETTINGS.get(name)
        if spec is None:
            raise InputError(name, "unknown camera setting", ", ".join(SETTINGS))
        camera = self._require()
        config = self._config("reading the settings")
        widget = self._find_widget(config, spec.widgets)
        model = self._identity.get("model") or "this camera"
        if widget is None:
            offered = [n for n, s in SETTINGS.items() if self._find_widget(config, s.widgets) is not None]
            raise InputError(name, f"{model} has no such setting", ", ".join(offered) or "none")
        current = _text(widget.get_value())
        if widget.get_readonly():
            raise InputError(name, f"{model} does not let it be changed remotely (it is {current})")
        kind = widget.get_type()
        gp = self.gp
        if kind in (gp.GP_WIDGET_RADIO, gp.GP_WIDGET_MENU):
            new: Any = match_choice(name, spec, value, self._choices(widget), model)
        elif kind == gp.GP_WIDGET_RANGE:
            lo, hi, _step = (float(v) for v in widget.get_range())
            parsed = value if isinstance(value, (int, float)) else (spec.parse or _ratio_or_number)(_text(value))
            if parsed is None or not lo <= float(parsed) <= hi:
                raise InputError(name, f"{value} is out of the camera's range", f"{lo:g} .. {hi:g}")
            new = float(parsed)
        elif kind == gp.GP_WIDGET_TOGGLE:
            new = 1 if str(value).strip().lower() in ("1", "true", "on", "yes") else 0
        else:
            new = _text(value)
        if str(new) == current:
            return
        try:
            widget.set_value(new)
            self._camera_said.clear()
            camera.set_config(config, *self._ctx)
        except gp.GPhoto2Error as exc:
            raise self._failed(exc, f"setting {name} to {new}") from None
        log.info("gphoto2: %s = %s", name, new)

    def _reported_settings(self) -> dict[str, Any]:
        """The exposure settings the camera reports now (read one widget at a time)."""
        camera = self._require()
        out: dict[str, Any] = {}
        for name in EXPOSURE_SETTINGS:
            widget_name = self._widgets.get(name)
            if widget_name is None:
                continue
            try:
                widget = camera.get_single_config(widget_name, *self._ctx)
            except self.gp.GPhoto2Error as exc:
                log.debug("gphoto2: reading %s: %s", widget_name, str(exc))
                continue
            out[name] = value_of(SETTINGS[name], widget.get_value())
        return out

    # -- capture ------------------------------------------------------------------------------------
    def _failed(self, exc: BaseException | _Code, action: str, since: float | None = None) -> DeviceError:
        self._message = gp_message(exc, action, None if since is None else self._clock() - since, self._said())
        log.debug("gphoto2: %s failed: %s", action, str(exc))
        return DeviceError(self._message)

    def _files_added(self, camera: Any, first: Any) -> list[Any]:
        """The other files this shot added (RAW + JPEG: the second one), from the camera's events."""
        gp = self.gp
        seen = {(first.folder, first.name)}
        added = []
        wait_ms = 10
        deadline = self._clock() + self.events_s
        while self._clock() < deadline:
            try:
                kind, data = camera.wait_for_event(wait_ms, *self._ctx)
            except gp.GPhoto2Error as exc:
                log.debug("gphoto2: waiting for events: %s", str(exc))
                break
            if kind == gp.GP_EVENT_TIMEOUT:
                break
            if kind == gp.GP_EVENT_FILE_ADDED and (data.folder, data.name) not in seen:
                seen.add((data.folder, data.name))
                added.append(data)
                wait_ms = 100     # a pair's second file follows within a moment
        return added

    def _download(self, camera: Any, where: Any, dest: Path) -> int:
        """Download ``where`` to ``dest`` atomically, its size checked; the number of bytes."""
        gp = self.gp
        try:
            expected = int(camera.file_get_info(where.folder, where.name, *self._ctx).file.size)
        except (gp.GPhoto2Error, AttributeError, TypeError, ValueError):
            expected = None

        def write(tmp: Path) -> None:
            t0 = self._clock()
            self._camera_said.clear()
            try:   # (no context argument here: python-gphoto2 2.x would take it for the old CameraFile one)
                camera_file = camera.file_get(where.folder, where.name, gp.GP_FILE_TYPE_NORMAL)
                camera_file.save(str(tmp))
            except gp.GPhoto2Error as exc:
                raise self._failed(exc, f"download of {where.folder}/{where.name}", t0) from None
            got = tmp.stat().st_size if tmp.exists() else 0
            if got == 0 or (expected is not None and got != expected):
                self._message = (f"camera: download of {where.name} incomplete ({got} of "
                                 f"{expected if expected is not None else '?'} bytes): {_USB_CABLE}, "
                                 "then retry the shot")
                raise DeviceError(self._message)

        atomic_write_with(dest, write)      # size checked before the file takes its name
        return dest.stat().st_size

    def capture(self, stem_path: Path, on_exposed: Callable[[], None] | None = None) -> CaptureResult:
        """Take a picture; download its file(s) to ``stem_path`` + each file's suffix (see the module
        docstring); the main file (RAW when there is one) comes first in ``files``."""
        with self._lock:
            self._busy = True
            try:
                t0 = self._clock()
                shot, t_exposed = self._shoot(stem_path, on_exposed, t0)
                return self._fetch(shot, Path(stem_path), t0, t_exposed)
            finally:
                self._busy = False

    # -- the card as the buffer (lfstudio.rig.camera.CardBuffered) ------------------------------------
    def keep_on_card(self) -> str:
        """Pictures stay on the camera's card until :meth:`download_from_card` fetches them: the capture
        target is set to the card where the body has one; returns where they go. Raises DeviceError
        when the body can only keep them in its RAM."""
        if "capturetarget" in self._widgets:
            config = self._config("reading the capture target")
            widget = config.get_child_by_name(self._widgets["capturetarget"])
            card = [c for c in self._choices(widget) if "card" in _norm(c)]
            if not card:
                raise DeviceError(f"camera: {self._identity.get('model') or 'the camera'} cannot keep its pictures "
                                  f"on a card (capture targets: {', '.join(self._choices(widget))})")
            self.set_setting("capturetarget", card[0])
            self.capture_target = card[0]
            return card[0]
        return "its storage"       # a body without the setting (libgphoto2's virtual camera): its store

    def capture_to_card(self, stem_path: Path, on_exposed: Callable[[], None] | None = None) -> list[str]:
        """Take a picture and leave its file(s) on the card; their paths on the camera."""
        with self._lock:
            self._busy = True
            try:
                shot, _ = self._shoot(stem_path, on_exposed, self._clock())
                self.shots += 1
                return [f"{w.folder}/{w.name}" for w in shot]
            finally:
                self._busy = False

    def download_from_card(self, camera_files: list[str], stem_path: Path) -> CaptureResult:
        """Download the files :meth:`capture_to_card` left on the card (size checked), then delete them there."""
        with self._lock:
            self._busy = True
            try:
                shot: list[Any] = []
                for text in camera_files:
                    folder, _, name = str(text).rpartition("/")
                    shot.append(SimpleNamespace(folder=folder or "/", name=name))   # as a CameraFilePath
                t0 = self._clock()
                self.shots -= 1                       # _fetch counts the shot; capture_to_card did
                return self._fetch(shot, Path(stem_path), t0, t0)
            finally:
                self._busy = False

    def _shoot(self, stem_path: Path, on_exposed: Callable[[], None] | None, t0: float) -> tuple[list[Any], float]:
        """The capture: the files it added on the camera, and when it was exposed."""
        gp = self.gp
        camera = self._require()
        log.debug("gphoto2: capture for %s", Path(stem_path).name)
        self._camera_said.clear()
        try:
            first = camera.capture(gp.GP_CAPTURE_IMAGE, *self._ctx)
        except gp.GPhoto2Error as exc:
            code = getattr(exc, "code", None)
            if code == -1 and self._store_full and not self._camera_said:
                # a full store answers the next captures with a bare PTP "Store Full" (-1 here)
                exc = _Code(-3)
            self._store_full = code == -3 or (code == -1 and self._store_full)
            raise self._failed(exc, "capture", t0) from None
        self._store_full = False
        t_exposed = self._clock()
        if on_exposed is not None:
            on_exposed()
        return [first, *self._files_added(camera, first)], t_exposed

    def _fetch(self, shot: list[Any], stem_path: Path, t0: float, t_exposed: float) -> CaptureResult:
        """Download ``shot``'s files to ``stem_path`` + suffix, delete them on the camera (when asked)."""
        gp = self.gp
        camera = self._require()
        files: list[Path] = []
        sizes: list[int] = []
        for where in shot:
            suffix = os.path.splitext(where.name)[1].lower() or ".raw"
            dest = stem_path.with_name(stem_path.name + suffix)
            if dest in files:       # two files of one type: keep both
                dest = stem_path.with_name(f"{stem_path.name}_{len(files)}{suffix}")
            sizes.append(self._download(camera, where, dest))
            files.append(dest)
        # the capture's main file first (a RAW: LibRaw reads it), its sidecars (JPEG ...) after
        order = sorted(range(len(files)), key=lambda i: not images.is_raw(files[i]))
        shot, files, sizes = [shot[i] for i in order], [files[i] for i in order], [sizes[i] for i in order]
        if self.delete_from_camera:
            for where in shot:
                try:
                    camera.file_delete(where.folder, where.name, *self._ctx)
                except gp.GPhoto2Error as exc:
                    log.debug("gphoto2: deleting %s/%s: %s", where.folder, where.name, str(exc))  # RAM: gone
        reported = self._reported_settings()
        t_done = self._clock()
        shutter_s = reported.get("shutter_s")
        shutter_s = float(shutter_s) if isinstance(shutter_s, (int, float)) else None
        call_s = t_exposed - t0
        log.debug("gphoto2: %s -> %s (%s bytes, capture call %.2f s, transfer %.2f s)",
                  ", ".join(f"{w.folder}/{w.name}" for w in shot), ", ".join(f.name for f in files),
                  "+".join(map(str, sizes)), call_s, t_done - t_exposed)
        self.shots += 1
        self._message = ""
        ident = {k: self._identity[k] for k in ("model", "serial", "lens") if self._identity.get(k)}
        metadata = {"camera_files": [f"{w.folder}/{w.name}" for w in shot], "bytes": sizes,
                    "model": self._identity.get("model", ""), "capture_call_s": call_s,
                    "format": files[0].suffix[1:].upper(), "settings": reported}
        if shutter_s is not None:
            metadata["shutter_s"] = shutter_s        # the scan records it as the view's exposure_s
        return CaptureResult(files=tuple(files), trigger_s=max(0.0, call_s - (shutter_s or 0.0)),
                             exposure_s=shutter_s or 0.0, transfer_s=t_done - t_exposed,
                             metadata=metadata,
                             record={"camera": ident, "camera_settings": reported})

    def preview(self) -> np.ndarray | None:
        """A live-view frame (RGB uint8) or None if the body has no live view over USB."""
        camera = self._require()
        self._camera_said.clear()
        try:
            camera_file = camera.capture_preview()     # (no context: see the download)
            data = camera_file.get_data_and_size()
        except self.gp.GPhoto2Error as exc:
            if getattr(exc, "code", None) == -6:
                return None
            raise DeviceError(gp_message(exc, "live view", camera_said=self._said())) from None
        return images.decode_frame(data)
