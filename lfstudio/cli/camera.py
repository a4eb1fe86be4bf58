"""``lfstudio camera``: connect a camera, show its settings, take a test shot."""

from __future__ import annotations

import argparse
import json

from lfstudio.cli.args import number_option, path_option
from lfstudio.errors import InputError
from lfstudio.numbers import WIDTH_PX, Number, parse_numbers

HELP = ("take a test shot with a camera (sim, gphoto2, folder:PATH, genicam:ID, a plugin's KIND:ARGS) and print its "
        "files and timings")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("stem", type=path_option("stem"), help="where to store the shot, without suffix (e.g. /tmp/test -> /tmp/test.dng)")
    p.add_argument("--camera", default="sim", metavar="sim|gphoto2|folder:PATH|genicam:ID|KIND:ARGS",
                   help="simulated studio camera, USB camera via gphoto2, a hot folder, a GenICam camera through "
                        "aravis, or an installed plugin's kind (lfstudio doctor lists them; default: sim)")
    p.add_argument("--camera-option", action="append", default=[], metavar="NAME=VALUE",
                   help="a connection option of the camera's kind, e.g. --camera-option timeout_s=3")
    p.add_argument("--trigger", nargs=argparse.REMAINDER, default=None,
                   help="hot folder: the trigger command and its arguments (must come last)")
    p.add_argument("--position-mm", default="0,0", metavar="X,Y", help="simulated camera: position on the rig")
    p.add_argument("--width", type=number_option(WIDTH_PX, "--width"), default=2000, metavar="PX",
                   help="simulated camera: image width")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="camera setting before the shot, e.g. --set iso=200 --set shutter_s=0.25")


def _open(args: argparse.Namespace):
    """The connected camera ``--camera`` names (the same names as ``lfstudio scan --camera``), as a
    :class:`lfstudio.studio.devices.CameraLink` (a gphoto2 camera or hot folder is locked for this process)."""
    from lfstudio.studio.devices import CameraSpec, open_camera
    from lfstudio.studio.kinds import camera_kind, parse_options

    spec = CameraSpec.parse(args.camera)
    position = None
    options = parse_options(camera_kind(spec.kind), args.camera_option)
    if spec.kind == "sim":
        from lfstudio.studio.simulated import studio_kwargs_for

        x, y = parse_numbers("--position-mm", args.position_mm, Number("mm", -1e6, 1e6), 2, "X,Y in mm")
        if not 16 <= args.width <= 12000:
            raise InputError("--width", f"{args.width} px is out of range", "16 .. 12000")
        position = lambda: (x, y)  # noqa: E731
        options.update({"studio_kwargs": studio_kwargs_for(width_px=args.width), "time_scale": 0.0})
    return open_camera(spec, position_mm=position, doing="test shot", trigger_command=args.trigger or None,
                       options=options)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from lfstudio.rig.camera import stored
    from lfstudio.studio.kinds import parse_settings

    link = _open(args)
    camera = link.camera
    try:
        for name, value in parse_settings(args.set).items():
            camera.set_setting(name, value)
        result = stored(camera.capture(Path(args.stem)))     # an array camera's frame written to the stem
        out = {"files": [str(f) for f in result.files], "trigger_s": round(result.trigger_s, 3),
               "exposure_s": round(result.exposure_s, 3), "transfer_s": round(result.transfer_s, 3),
               "settings": camera.settings()}
        truth = result.metadata.get("ground_truth")
        if truth:
            out["true_position_mm"] = truth["true_position_mm"]
        print(json.dumps(out, indent=1))
    finally:
        link.close()
    return 0
