"""``lfstudio plan``: depth of field, aperture, minimum distance, disparity, parallax, images, time and disk."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import NoReturn

from lfstudio.cli.args import old_spelling, path_option
from lfstudio.errors import InputError
from lfstudio.numbers import Number, parse_numbers
from lfstudio.optics import REFERENCE

HELP = "plan a scene: aperture, depth of field, disparity, parallax, capture time and disk space"

PAIR, WHOLE_PAIR = "pair", "whole pair"      # AxB (also A×B, A,B; numbers.parse_numbers); one number sets both
PATH = "path"                                # a file name (~, $VARIABLES expanded: dataset.paths.path_option)
PRESET = "preset"                            # a preset's name, applied first (planning.presets.plan_from_presets)

#: the fields a preset sets first, by name (their option takes the preset's name)
_PRESET_FIELDS = {"camera_name", "lens_name", "rig_name"}


def _kind(name: str, param) -> object:
    if name in _PRESET_FIELDS:
        return PRESET
    if param.number is None:
        return str
    if param.pair or name in ("grid_columns", "grid_rows"):
        return WHOLE_PAIR if param.number.integer else PAIR
    return int if param.number.integer else float


def _default_text(name: str, param, value) -> str:
    if name in _PRESET_FIELDS or value in (None, ""):
        return "" if not param.optional else f" (default: {param.optional})"
    if name == "grid_columns":
        return " (default {0}x{1})".format(*REFERENCE.grid)
    if isinstance(value, tuple):
        return " (default {0:g}x{1:g})".format(*value)
    return f" (default {value:g})"


def _options() -> tuple:
    """Every option that sets the plan, by group: (option, metavar, kind, help), made from the scene
    plan's own field descriptions (lfstudio.planning.scene_plan.PARAMS); --plan is read first."""
    from lfstudio.planning.scene_plan import PARAMS, ScenePlan

    defaults = ScenePlan()
    groups: dict[str, list] = {}
    seen: set[str] = set()
    for name, param in PARAMS.items():
        if param.option in seen:
            continue                           # --grid sets two fields
        seen.add(param.option)
        help_text = param.tip + _default_text(name, param, getattr(defaults, name))
        groups.setdefault(param.group, []).append((param.option, param.metavar, _kind(name, param), help_text))
    first = next(iter(groups))
    groups[first].insert(0, ("--plan", "FILE", PATH,
                             "start from this plan file (.toml or .json) instead of the reference setup"))
    return tuple((title, tuple(options)) for title, options in groups.items())


OPTIONS = _options()

#: the earlier names of options whose meaning did not change (accepted, hidden from --help)
OLD_SPELLINGS = {"--camera-preset": "--camera", "--rig-profile": "--rig"}

_EXAMPLES = {"--sensor-px": "7952x5304", "--grid": "101x21"}


def _type(option: str, kind):
    """The argparse ``type=`` of an option of this ``kind`` (pairs stay text until :func:`build_plan`)."""
    if kind == PATH:
        return path_option(option)
    return kind if kind in (float, int) else str        # str: the text as given (argparse's default)


def _pair(option: str, text: str, kind: str) -> tuple:
    """The two numbers of an AxB option (:func:`lfstudio.numbers.parse_numbers`; one number sets both)."""
    return parse_numbers(option, text, Number("", integer=kind == WHOLE_PAIR), 2, _EXAMPLES.get(option, "4x6"),
                         one_for_all=True)


def _dest(option: str) -> str:
    return option[2:].replace("-", "_")


def add_arguments(p: argparse.ArgumentParser) -> None:
    def one_line_error(message: str) -> NoReturn:   # a bad value: one line naming the option, exit 2
        p.exit(2, f"lfstudio plan: error: {message}\n")

    p.error = one_line_error
    for title, options in OPTIONS:
        g = p.add_argument_group(title)
        for option, metavar, kind, help_text in options:
            g.add_argument(option, metavar=metavar, type=_type(option, kind), help=help_text)
            if option in OLD_SPELLINGS:
                old_spelling(g, OLD_SPELLINGS[option], option)
    p.add_argument("--fly", action="store_true",
                   help="plan a fly scan (continuous motion): refused (exit 2) with the numbers when no speed "
                        "meets every limit")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.add_argument("--save", metavar="FILE", type=path_option("--save"), help="also write the plan to FILE (.toml or .json)")
    p.add_argument("--list-presets", action="store_true", help="list camera, lens and rig presets and exit")


def build_plan(args: argparse.Namespace):
    """The ScenePlan the options describe (reference setup or --plan, then presets, then values)."""
    from lfstudio.planning.presets import plan_from_presets, reference_plan
    from lfstudio.planning.scene_plan import CLI_OPTION, load_plan

    base = load_plan(args.plan) if args.plan else reference_plan()
    plan = plan_from_presets(camera=args.camera_preset, lens=args.lens, rig=args.rig_profile, base=base)
    fields_of: dict[str, list[str]] = {}
    for name, option in CLI_OPTION.items():
        fields_of.setdefault(option, []).append(name)
    changes: dict = {}
    for _, options in OPTIONS:
        for option, _, kind, _ in options:
            value = getattr(args, _dest(option))
            if kind in (PRESET, PATH) or value is None:
                continue
            if kind in (PAIR, WHOLE_PAIR):
                value = _pair(option, value, kind)
            fields = fields_of[option]             # --grid: columns, rows; any other: its one field
            changes.update(zip(fields, value) if len(fields) > 1 else ((fields[0], value),))
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
    fly = r.fly
    if fly is not None:
        from lfstudio.planning.fly import format_fly

        rows = [("step scan", f"{format_duration(r.capture_time_s)}"),
                ("fly scan", (f"{format_duration(fly.time_s)} ({fly.time_s / max(r.images, 1):.2f} s per view)"
                              if fly.possible else "not possible (see row speed)")),
                ("row speed", format_fly(fly)),
                ("limits", ", ".join(f"{k} {v:.4g}" for k, v in fly.limits_mm_s.items()) + " mm/s")]
        rows.extend(("note", n) for n in fly.notes)
        sections.append(("Fly scanning (continuous motion)", rows))
    if r.frames_per_view > 1:
        sections[-2 if fly is not None else -1][1].insert(1, ("exposure bracket", f"{r.frames_per_view} frames a view ("
                                  + ", ".join(f"{t:.4g} s" for t in r.frame_exposures_s) + f"), {r.frames} pictures"))
    if r.proposed_grid is not None:
        sections[2][1].append((f"grid for {100 * plan.target_parallax_fraction:g} % parallax",
                               f"{r.proposed_grid.columns} × {r.proposed_grid.rows}"))
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
    if getattr(args, "fly", False) and result.fly is not None and not result.fly.possible:
        raise InputError("--fly", result.fly.refusal)
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
