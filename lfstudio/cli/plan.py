"""``lfstudio plan``: depth of field, aperture, minimum distance, disparity, parallax, images, time and disk."""

from __future__ import annotations

import argparse
import json
import math
import sys

from lfstudio.cli.args import old_spelling
from lfstudio.errors import InputError
from lfstudio.dataset.paths import path_option

HELP = "plan a scene: aperture, depth of field, disparity, parallax, capture time and disk space"


def _pair(text: str, conv=float) -> tuple:
    parts = text.lower().replace("×", "x").split("x")
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2:
        raise ValueError(text)
    return conv(parts[0]), conv(parts[1])


def add_arguments(p: argparse.ArgumentParser) -> None:
    def one_line_error(message: str) -> None:   # a bad value: one line naming the option, exit 2
        p.exit(2, f"lfstudio plan: error: {message}\n")

    p.error = one_line_error
    g = p.add_argument_group("camera and lens")
    g.add_argument("--plan", metavar="FILE", type=path_option("--plan"), help="start from this plan file (.toml or .json) instead of the reference setup")
    g.add_argument("--camera-preset", metavar="NAME", help="camera preset (see --list-presets)")
    old_spelling(g, "--camera", "--camera-preset")
    g.add_argument("--sensor-px", metavar="WxH", help="sensor size in pixels, e.g. 7952x5304")
    g.add_argument("--sensor-mm", metavar="WxH", help="sensor size in mm, e.g. 35.9x24")
    g.add_argument("--pixel-pitch-um", type=float, metavar="UM",
                   help="pixel pitch in µm (default: the camera's, or sensor mm / px)")
    g.add_argument("--lens", metavar="NAME", help="lens preset")
    g.add_argument("--focal-length-mm", type=float, metavar="MM", help="focal length")
    g = p.add_argument_group("scene and optics")
    g.add_argument("--near-m", type=float, metavar="M", help="nearest scene distance from the camera plane (default 1.77)")
    g.add_argument("--far-m", type=float, metavar="M", help="farthest scene distance (default 4.77)")
    g.add_argument("--coc-mm", type=float, metavar="MM", help="circle of confusion (default 0.029)")
    g.add_argument("--f-number", type=float, metavar="N", help="aperture to evaluate (default: the one the scene needs)")
    g.add_argument("--focus-m", type=float, metavar="M", help="focus distance (default: centres the sharp range on the scene)")
    g = p.add_argument_group("grid and rig")
    g.add_argument("--grid", metavar="CxR", help="columns x rows (default 101x21)")
    g.add_argument("--spacing-mm", metavar="HxV", help="spacing between neighbouring positions (default 4x6)")
    g.add_argument("--rig-profile", metavar="NAME", help="rig profile: repeatability, travel, speed, acceleration, settle")
    old_spelling(g, "--rig", "--rig-profile")
    g.add_argument("--repeatability-um", metavar="HxV", help="axis repeatability (default 80x50)")
    g.add_argument("--travel-mm", metavar="HxV", help="axis travel (default: the rig's)")
    g.add_argument("--max-speed-mm-s", metavar="HxV", help="axis speed (default: the rig's)")
    g.add_argument("--acceleration-mm-s2", metavar="HxV", help="axis acceleration (default: the rig's)")
    g.add_argument("--settle-s", type=float, metavar="S", help="settle time after each move")
    g.add_argument("--exposure-s", type=float, metavar="S", help="exposure time (default 0.5)")
    g.add_argument("--transfer-s", type=float, metavar="S", help="trigger + download time per image (default 2.5)")
    g.add_argument("--raw-bits", type=int, metavar="BITS", help="raw bits per pixel (default: the camera's)")
    g.add_argument("--bytes-per-image", type=int, metavar="B", help="file size per image (default: uncompressed raw)")
    g = p.add_argument_group("targets")
    g.add_argument("--max-error-px", type=float, metavar="PX", help="allowed repositioning error in the image (default 0.5)")
    g.add_argument("--max-disparity-px", type=float, metavar="PX",
                   help="wanted max neighbour disparity: proposes the spacing (default 1)")
    g.add_argument("--parallax-fraction", type=float, metavar="F",
                   help="wanted parallax as a fraction of the image size: proposes the grid")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.add_argument("--save", metavar="FILE", type=path_option("--save"), help="also write the plan to FILE (.toml or .json)")
    p.add_argument("--list-presets", action="store_true", help="list camera, lens and rig presets and exit")


_FLOAT_OPTIONS = ("pixel_pitch_um", "focal_length_mm", "near_m", "far_m", "coc_mm", "f_number", "focus_m",
                  "settle_s", "exposure_s", "transfer_s", "raw_bits", "bytes_per_image", "max_error_px",
                  "max_disparity_px")
_PAIR_OPTIONS = {"sensor_mm": ("--sensor-mm", float), "repeatability_um": ("--repeatability-um", float),
                 "travel_mm": ("--travel-mm", float), "max_speed_mm_s": ("--max-speed-mm-s", float),
                 "acceleration_mm_s2": ("--acceleration-mm-s2", float), "spacing_mm": ("--spacing-mm", float)}


def build_plan(args: argparse.Namespace):
    """The ScenePlan the options describe (reference setup or --plan, then presets, then values)."""
    from lfstudio.planning.presets import plan_from_presets, reference_plan
    from lfstudio.planning.scene_plan import load_plan

    base = load_plan(args.plan) if args.plan else reference_plan()
    plan = plan_from_presets(camera=args.camera_preset, lens=args.lens, rig=args.rig_profile, base=base)
    changes: dict = {}
    if args.sensor_px:
        try:
            changes["sensor_px"] = _pair(args.sensor_px, int)
        except ValueError:
            raise InputError("--sensor-px", f"{args.sensor_px!r} is not WIDTHxHEIGHT in pixels", "e.g. 7952x5304")
    for name, (option, conv) in _PAIR_OPTIONS.items():
        text = getattr(args, name)
        if text:
            try:
                changes[name] = _pair(text, conv)
            except ValueError:
                raise InputError(option, f"{text!r} is not HxV (two numbers)", "e.g. 4x6")
    if args.grid:
        try:
            changes["grid_columns"], changes["grid_rows"] = _pair(args.grid, int)
        except ValueError:
            raise InputError("--grid", f"{args.grid!r} is not COLUMNSxROWS", "e.g. 101x21")
    for name in _FLOAT_OPTIONS:
        value = getattr(args, name)
        if value is not None:
            changes[name] = value
    if args.parallax_fraction is not None:
        changes["target_parallax_fraction"] = args.parallax_fraction
    if (args.sensor_px or args.sensor_mm) and args.pixel_pitch_um is None:
        changes["pixel_pitch_um"] = None          # derive it from the new sensor size
        if not args.camera_preset:
            changes["camera_name"] = "custom camera"
    if args.focal_length_mm is not None and not args.lens:
        changes["lens_name"] = f"{args.focal_length_mm:g} mm"
    return plan.replace(**changes)


def _option_error(exc: InputError, args: argparse.Namespace | None = None) -> InputError:
    """The error naming the option that set the field, or the plan file's field when it came from --plan."""
    from lfstudio.planning.scene_plan import CLI_OPTION

    option = CLI_OPTION.get(exc.field, exc.field)
    if args is not None and args.plan and getattr(args, option.lstrip("-").replace("-", "_"), None) is None:
        option = f"{args.plan}: {exc.field}"
    message = str(exc).split(": ", 1)[-1]
    if exc.valid and message.endswith(f" (valid: {exc.valid})"):
        message = message[: -len(f" (valid: {exc.valid})")]
    return InputError(option, message, exc.valid)


def _m(value: float) -> str:
    return "∞" if value is None or math.isinf(value) else f"{value:.2f} m"


def _bytes(n: float) -> str:
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{int(n)} B"


def format_table(plan, result) -> str:
    """The human-readable report: label column aligned, one figure per line, warnings last."""
    from lfstudio.jobs import format_duration

    r = result
    hv = lambda d, fmt: f"{fmt.format(d['horizontal'])} horizontal, {fmt.format(d['vertical'])} vertical"  # noqa: E731
    sections = [
        ("Setup", [
            ("camera", f"{plan.camera_name}: {plan.sensor_px[0]} × {plan.sensor_px[1]} px, "
                       f"pixel pitch {r.pixel_pitch_um:.2f} µm"),
            ("lens", f"{plan.lens_name}: f = {plan.focal_length_mm:g} mm"),
            ("scene", f"{plan.near_m:g} – {plan.far_m:g} m, circle of confusion {plan.coc_mm:g} mm"),
            ("rig", f"{plan.rig_name}: repeatability {plan.repeatability_um[0]:g} × {plan.repeatability_um[1]:g} µm"),
        ]),
        ("Depth of field", [
            ("f-number required", f"f/{r.f_number_required:.1f}, focused at {r.focus_distance_m:.2f} m"),
            ("hyperfocal distance", f"{r.hyperfocal_m:.2f} m at f/{r.f_number_used:.1f}"),
            ("sharp range", f"{_m(r.dof_near_m)} – {_m(r.dof_far_m)} at f/{r.f_number_used:.1f} focused at "
                            f"{r.focus_used_m:.2f} m" + ("" if r.scene_sharp else "  (scene NOT all sharp)")),
            ("diffraction", f"Airy disk {r.airy_disk_um:.1f} µm; exceeds 2 px beyond f/{r.diffraction_f_number:.1f}"),
        ]),
        ("Repositioning", [
            ("min. scene distance", f"{r.min_distance_m:.2f} m for ≤ {plan.max_error_px:g} px "
                                    f"({r.min_distance_axis} axis)"),
            ("error at near distance", hv(r.reposition_error_px, "{:.2f} px")),
        ]),
        ("Disparity and parallax", [
            ("neighbour disparity", hv(r.neighbour_disparity_px, "{:.2f} px") + " (near – far)"),
            ("row parallax", f"{r.row_parallax_px:.0f} px = {100 * r.row_parallax_fraction:.1f} % of the image width "
                             f"(baseline {r.baseline_mm['horizontal']:g} mm)"),
            ("column parallax", f"{r.column_parallax_px:.0f} px = {100 * r.column_parallax_fraction:.1f} % of the "
                                f"image height (baseline {r.baseline_mm['vertical']:g} mm)"),
            (f"spacing for ≤ {plan.max_disparity_px:g} px", hv(r.proposed_spacing_mm, "{:.3g} mm")),
        ]),
        ("Capture", [
            ("images", f"{plan.grid_columns} × {plan.grid_rows} = {r.images} at "
                       f"{plan.spacing_mm[0]:g} × {plan.spacing_mm[1]:g} mm"),
            ("fits the travel", ("yes" if r.fits_travel else "NO") +
             f" ({r.baseline_mm['horizontal']:g} of {plan.travel_mm[0]:g} mm, "
             f"{r.baseline_mm['vertical']:g} of {plan.travel_mm[1]:g} mm)"),
            ("capture time", f"{format_duration(r.capture_time_s)} "
                             f"({r.capture_time_s / max(r.images, 1):.2f} s per view)"),
            ("disk space", f"{_bytes(r.storage_bytes)} ({_bytes(r.bytes_per_image)} per image)"),
        ]),
    ]
    if r.proposed_grid is not None:
        sections[2][1].append((f"grid for {100 * plan.target_parallax_fraction:g} % parallax",
                               f"{r.proposed_grid['columns']} × {r.proposed_grid['rows']}"))
    width = max(len(label) for _, rows in sections for label, _ in rows) + 2
    lines: list[str] = []
    for title, rows in sections:
        lines.append(title)
        lines.extend(f"  {label:<{width}}{value}" for label, value in rows)
    if r.warnings:
        lines.append("Warnings")
        lines.extend(f"  [{w.severity}] {w.field}: {w.message}" for w in r.warnings)
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if args.list_presets:
        from lfstudio.resources import load_presets

        for kind in ("cameras", "lenses", "rigs"):
            print(f"{kind}:")
            for name in load_presets(kind):
                print(f"  {name}")
        return 0
    try:
        plan = build_plan(args)
        result = plan.derive()
    except InputError as exc:
        raise _option_error(exc, args) from None
    if args.save:
        from lfstudio.planning.scene_plan import save_plan

        save_plan(args.save, plan)
    try:
        if args.json:
            out = result.to_dict()
            out["plan"] = plan.to_dict()
            json.dump(out, sys.stdout, ensure_ascii=False, allow_nan=False)
            sys.stdout.write("\n")
        else:
            print(format_table(plan, result))
            if args.save:
                print(f"\nplan saved to {args.save}")
        sys.stdout.flush()
    except BrokenPipeError:             # `lfstudio plan | head`: the reader left, that is fine
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0
