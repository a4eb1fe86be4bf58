"""Tethered capture over USB with libgphoto2 (python-gphoto2).

One camera session stays open from :meth:`GPhotoCamera.connect` to :meth:`disconnect` (opening one
per shot costs seconds and confuses some bodies). A capture goes to the camera's RAM, is
downloaded, checked for size, renamed to the view's name and deleted from the camera. libgphoto2
error codes become messages an operator can act on (no camera, camera busy, wrong USB mode,
another program holding the camera).

The python-gphoto2 module is passed in (``gp``) so tests can replace it at that boundary; this
layer stays thin: no logic beyond the calls, the size check and the messages.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from lfstudio.dataset.atomic import atomic_write_with
from lfstudio.errors import DeviceError, InputError
from lfstudio.rig.camera import CameraStatus, CaptureResult

log = logging.getLogger(__name__)

#: our setting names -> gphoto2 config widget names tried in order (bodies name them differently)
SETTING_WIDGETS = {
    "iso": ("iso", "isospeed"),
    "shutter_s": ("shutterspeed", "shutterspeed2", "exposuretime"),
    "aperture": ("f-number", "aperture", "fnumber"),
    "format": ("imagequality", "imageformat", "capturetarget_format"),
    "capturetarget": ("capturetarget",),
}

_GP_MESSAGES = {
    -105: "no camera found: connect it by USB, switch it on and set its USB connection mode to "
          "'PC Remote' (not 'Mass Storage' or 'MTP')",
    -52: "no camera found on USB: check the cable and that the camera is switched on",
    -53: "another program holds the camera (a file manager or photo importer such as gvfs, "
         "Image Capture or Lightroom): close it and reconnect",
    -110: "the camera is busy (still writing or transferring the previous picture): wait and retry",
    -6: "the camera does not support remote capture in its current mode: set its USB connection "
        "mode to 'PC Remote' and its mode dial to M",
    -10: "the camera did not answer in time: check the cable, the battery and that the camera is "
         "not asleep",
    -7: "USB input/output error: check the cable (use a short, direct one) and reconnect",
    -113: "the camera reported an error (e.g. could not focus, card full, shutter fault): check its "
          "screen",
}


def gp_message(exc: BaseException, action: str) -> str:
    """An operator's message for a gphoto2 error raised during ``action``."""
    code = getattr(exc, "code", None)
    hint = _GP_MESSAGES.get(code) if isinstance(code, int) else None
    return f"camera: {action} failed: {hint or exc}" + (f" [gphoto2 {code}]" if code is not None else "")


class GPhotoCamera:
    """A :class:`lfstudio.rig.camera.Camera` over python-gphoto2 (see the module docstring)."""

    name = "gphoto2 camera"

    def __init__(self, gp: Any = None, *, delete_from_camera: bool = True,
                 clock: Callable[[], float] = time.monotonic):
        if gp is None:
            try:
                import gphoto2 as gp  # noqa: PLC0415 - optional at import time
            except ImportError as exc:
                raise DeviceError(f"camera: python-gphoto2 is not installed ({exc}); "
                                  "install the 'gphoto2' package") from None
        self.gp = gp
        self.delete_from_camera = delete_from_camera
        self._clock = clock
        self._camera: Any = None
        self._model = ""
        self._busy = False
        self._message = ""
        self.shots = 0
        self._lock = threading.Lock()

    # -- session ------------------------------------------------------------------------------------
    def connect(self) -> None:
        if self._camera is not None:
            return
        camera = self.gp.Camera()
        try:
            camera.init()
        except self.gp.GPhoto2Error as exc:
            self._message = gp_message(exc, "connect")
            raise DeviceError(self._message) from None
        self._camera = camera
        try:
            summary = str(camera.get_summary())
            self._model = next((line.split(":", 1)[1].strip() for line in summary.splitlines()
                                if line.strip().lower().startswith("model:")), "")
        except self.gp.GPhoto2Error:
            self._model = ""
        try:   # captures to the camera's RAM ("Internal RAM"), downloaded each time
            self._set_widget(("capturetarget",), "Internal RAM", required=False)
        except DeviceError:
            pass
        self._message = ""

    def disconnect(self) -> None:
        camera, self._camera = self._camera, None
        if camera is not None:
            try:
                camera.exit()
            except self.gp.GPhoto2Error:
                pass

    def stop(self) -> None:
        """Nothing to abort mid-transfer safely; the capture in progress completes."""

    def _require(self) -> Any:
        if self._camera is None:
            raise DeviceError("camera: not connected; connect the camera first (Camera panel: Connect)")
        return self._camera

    def status(self) -> CameraStatus:
        return CameraStatus(self._camera is not None, self._model, self.shots, self._busy, self._message)

    # -- settings -----------------------------------------------------------------------------------
    def _find_widget(self, config: Any, names: tuple[str, ...]) -> Any:
        for name in names:
            try:
                return config.get_child_by_name(name)
            except self.gp.GPhoto2Error:
                continue
        return None

    def _set_widget(self, names: tuple[str, ...], value: Any, required: bool = True) -> None:
        camera = self._require()
        try:
            config = camera.get_config()
            widget = self._find_widget(config, names)
            if widget is None:
                if required:
                    raise DeviceError(f"camera: this body has no setting {names[0]!r}")
                return
            choices = [str(c) for c in widget.get_choices()] if hasattr(widget, "get_choices") else []
            text = str(value)
            if choices and text not in choices:
                raise InputError(names[0], f"{text!r} is not offered by the camera", ", ".join(choices[:20]))
            widget.set_value(text)
            camera.set_config(config)
        except self.gp.GPhoto2Error as exc:
            raise DeviceError(gp_message(exc, f"setting {names[0]}")) from None

    def settings(self) -> dict[str, Any]:
        camera = self._require()
        out: dict[str, Any] = {}
        try:
            config = camera.get_config()
        except self.gp.GPhoto2Error as exc:
            raise DeviceError(gp_message(exc, "reading the settings")) from None
        for key, names in SETTING_WIDGETS.items():
            widget = self._find_widget(config, names)
            if widget is not None:
                out[key] = widget.get_value()
        return out

    def set_setting(self, name: str, value: Any) -> None:
        if name not in SETTING_WIDGETS:
            raise InputError(name, "unknown camera setting", ", ".join(SETTING_WIDGETS))
        if name == "shutter_s" and isinstance(value, (int, float)):
            value = _shutter_text(float(value))
        self._set_widget(SETTING_WIDGETS[name], value)

    # -- capture ------------------------------------------------------------------------------------
    def capture(self, stem_path: Path, on_exposed: Callable[[], None] | None = None) -> CaptureResult:
        """Capture to the camera's RAM, download to ``stem_path`` + the file's suffix, check its size."""
        gp = self.gp
        camera = self._require()
        stem_path = Path(stem_path)
        with self._lock:
            self._busy = True
            try:
                t0 = self._clock()
                log.debug("gphoto2: capture for %s", stem_path.name)
                try:
                    where = camera.capture(gp.GP_CAPTURE_IMAGE)
                except gp.GPhoto2Error as exc:
                    self._message = gp_message(exc, "capture")
                    log.debug("gphoto2: capture failed: %s", exc)
                    raise DeviceError(self._message) from None
                t_exposed = self._clock()
                if on_exposed is not None:
                    on_exposed()
                suffix = os.path.splitext(where.name)[1].lower() or ".raw"
                dest = stem_path.with_name(stem_path.name + suffix)
                try:
                    expected = int(camera.file_get_info(where.folder, where.name).file.size)
                except (gp.GPhoto2Error, AttributeError, TypeError, ValueError):
                    expected = None

                def download(tmp: Path) -> None:
                    try:
                        camera_file = camera.file_get(where.folder, where.name, gp.GP_FILE_TYPE_NORMAL,
                                                      gp.CameraFile())
                        camera_file.save(str(tmp))
                    except gp.GPhoto2Error as exc:
                        self._message = gp_message(exc, f"download of {where.folder}/{where.name}")
                        raise DeviceError(self._message) from None
                    got = tmp.stat().st_size if tmp.exists() else 0
                    if got == 0 or (expected is not None and got != expected):
                        self._message = (f"camera: download of {where.name} incomplete ({got} of "
                                         f"{expected if expected is not None else '?'} bytes); retry the shot")
                        raise DeviceError(self._message)

                atomic_write_with(dest, download)      # size checked before the file takes its name
                size = dest.stat().st_size
                if self.delete_from_camera:
                    try:
                        camera.file_delete(where.folder, where.name)
                    except gp.GPhoto2Error:
                        pass          # RAM captures may already be gone
                t_done = self._clock()
                log.debug("gphoto2: %s/%s -> %s (%d bytes, exposure %.2f s, transfer %.2f s)", where.folder,
                          where.name, dest.name, size, t_exposed - t0, t_done - t_exposed)
                self.shots += 1
                self._message = ""
                return CaptureResult(files=(dest,), trigger_s=0.0, exposure_s=t_exposed - t0,
                                     transfer_s=t_done - t_exposed,
                                     metadata={"camera_file": f"{where.folder}/{where.name}", "bytes": size,
                                               "model": self._model, "format": suffix[1:].upper()})
            finally:
                self._busy = False

    def preview(self) -> np.ndarray | None:
        """A live-view frame (RGB uint8) or None if the body has no live view over USB."""
        import cv2

        camera = self._require()
        try:
            camera_file = camera.capture_preview(self.gp.CameraFile())
            data = camera_file.get_data_and_size()
        except self.gp.GPhoto2Error as exc:
            if getattr(exc, "code", None) == -6:
                return None
            raise DeviceError(gp_message(exc, "live view")) from None
        img = cv2.imdecode(np.frombuffer(memoryview(data), np.uint8), cv2.IMREAD_COLOR)
        return None if img is None else cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _shutter_text(seconds: float) -> str:
    """gphoto2's usual shutter-speed choice text: '1/250', '0.5' -> '1/2', '2'."""
    if seconds >= 1:
        return f"{seconds:g}"
    return f"1/{round(1 / seconds):d}"
