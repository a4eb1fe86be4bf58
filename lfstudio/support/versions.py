"""Versions of lfstudio and every component it loads (``lfstudio doctor``, Help → About).

Each component is imported by name, so a missing optional one (gphoto2 on Windows) is reported,
not fatal. The GUI uses the same list; the core never imports Qt itself, it only asks for a version.
"""

from __future__ import annotations

import importlib
import platform
import sys
from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class Component:
    name: str              # what an operator reads ("LibRaw", "FFmpeg")
    module: str            # the Python module that provides it
    version: Callable      # module -> version text
    required: bool = True  # False: the app works without it (reduced features)
    purpose: str = ""


def _attr(name: str) -> Callable:
    """module -> ``str(module.NAME)`` (dotted names followed; a callable is called)."""
    def get(mod):
        value = mod
        for part in name.split("."):
            value = getattr(value, part)
        return str(value() if callable(value) else value)
    return get


def _ffmpeg(av) -> str:
    from av import library_versions

    ffmpeg = getattr(av, "ffmpeg_version_info", None)
    if ffmpeg:
        return f"{ffmpeg} (PyAV {av.__version__})"
    major, minor, micro = library_versions["libavformat"]
    return f"libavformat {major}.{minor}.{micro} (PyAV {av.__version__})"


def _libraw(rawpy) -> str:
    return f"{'.'.join(map(str, rawpy.libraw_version))} (rawpy {rawpy.__version__})"


def _gphoto2(gp) -> str:
    libs = gp.gp_library_version(gp.GP_VERSION_SHORT)
    abilities = gp.CameraAbilitiesList()
    abilities.load()                  # the camera drivers (camlibs): none loaded means a broken install
    return f"{libs[0] if libs else '?'} (python-gphoto2 {gp.__version__}; {len(abilities)} camera models)"


def _lensfun(lensfunpy) -> str:
    db = lensfunpy.Database()
    return f"{lensfunpy.__version__} ({len(db.cameras)} cameras, {len(db.lenses)} lenses in the database)"


def _qt(qtcore) -> str:
    import PySide6

    return f"Qt {qtcore.qVersion()} (PySide6 {PySide6.__version__})"


COMPONENTS: tuple[Component, ...] = (
    Component("Qt", "PySide6.QtCore", _qt, purpose="application window"),
    Component("numpy", "numpy", _attr("__version__")),
    Component("OpenCV", "cv2", _attr("__version__"), purpose="calibration, processing"),
    Component("LibRaw", "rawpy", _libraw, purpose="RAW/DNG decoding"),
    Component("FFmpeg", "av", _ffmpeg, purpose="HEVC/FFV1 video export"),
    Component("lensfun", "lensfunpy", _lensfun, purpose="lens distortion database"),
    Component("pyqtgraph", "pyqtgraph", _attr("__version__"), purpose="plots"),
    Component("SciPy", "scipy", _attr("__version__")),
    Component("tifffile", "tifffile", _attr("__version__")),
    Component("pyserial", "serial", _attr("__version__"), purpose="rig controller"),
    Component("dask", "dask", _attr("__version__"), required=False, purpose="processing on a cluster"),
    Component("libgphoto2", "gphoto2", _gphoto2, required=False, purpose="USB camera control"),
)


@dataclass(frozen=True)
class ComponentStatus:
    name: str
    ok: bool
    version: str          # or the import error
    required: bool
    purpose: str


def check_component(c: Component) -> ComponentStatus:
    try:
        mod = importlib.import_module(c.module)
        return ComponentStatus(c.name, True, c.version(mod), c.required, c.purpose)
    except Exception as exc:  # noqa: BLE001 - any failure to load is what we report
        return ComponentStatus(c.name, False, f"not available: {type(exc).__name__}: {exc}", c.required, c.purpose)


def versions(components: tuple[Component, ...] = COMPONENTS) -> list[tuple[str, str]]:
    """``[(name, version text)]``: lfstudio, Python, the platform, then every component."""
    from lfstudio import __version__

    frozen = " (bundle)" if getattr(sys, "frozen", False) else ""
    rows = [("lfstudio", __version__ + frozen),
            ("Python", f"{platform.python_version()} ({sys.executable})"),
            ("Platform", platform.platform())]
    rows += [(s.name, s.version) for s in map(check_component, components)]
    return rows


def report_text() -> str:
    """Plain-text versions block (the crash dialog's "Copy details", bug reports)."""
    rows = versions()
    width = max(len(name) for name, _ in rows)
    return "\n".join(f"{name:<{width}}  {text}" for name, text in rows)
