"""The check's figures in their one wording, shared by the command line (``lfstudio check``), the HTML
report (``quality/pictures.py``) and the window: the repeatability with its source, the tracked disparity
range and the dense map's statistics, each with its reference (from infinity, or relative to the
zero-disparity plane) named."""

from __future__ import annotations

from typing import Any

#: the source of the repeatability a check compares with (``repeatability.planned_from``), in words
REPEATABILITY_SOURCES = {"plan": "planned", "logged": "logged by the rig",
                         "default": "assumed: no plan or rig log states it"}


def repeatability_summary(rep: dict[str, Any]) -> str:
    """``x 355 µm, y 257 µm measured (logged by the rig 247.43, 192.01 µm; 25 views)``: the one wording
    of the check's repeatability (the command line, the HTML report)."""
    def um(x: Any) -> str:
        return "–" if x is None else f"{x:.0f}"

    source = REPEATABILITY_SOURCES.get(str(rep.get("planned_from")), "planned")
    return (f"x {um(rep.get('x_um'))} µm, y {um(rep.get('y_um'))} µm measured ({source} "
            f"{', '.join(f'{v:g}' for v in rep.get('planned_um', []))} µm; {rep.get('views', 0)} views)")


def disparity_reference_of(depth: dict[str, Any]) -> str:
    """The reference of a check's disparities (a document written before it was recorded: from its shear)."""
    zero = depth.get("zero_disparity") or {}
    if zero.get("disparity_reference"):
        return str(zero["disparity_reference"])
    if zero.get("shear_px_per_step") == 0.0 or "shear_px_per_step" not in zero:
        return "from infinity"
    return "relative to the zero-disparity plane" + ("" if zero.get("depth_m") else " (its depth not stated)")


def disparity_map_summary(disp: dict[str, Any], depth: dict[str, Any] | None = None) -> str:
    """The check's dense map of the centre view in the one wording (the command line, the report, the
    Disparity window): its median and 1st–99th percentile, its reference, how much matched."""
    reference = disp.get("reference") or disparity_reference_of(depth or {})
    parts = [f"{disp.get('view', '?')}: median " + ("–" if disp.get("median_px") is None else
                                                     f"{disp['median_px']:+.2f} px")]
    if disp.get("p1_px") is not None and disp.get("p99_px") is not None:
        parts.append(f"{disp['p1_px']:+.2f} … {disp['p99_px']:+.2f} px (1st–99th percentile of the map)")
    parts.append(f"between horizontal neighbours, {reference}")
    parts.append(f"{disp.get('valid_fraction', 0):.0%} of pixels matched")
    return ", ".join(parts)


def disparity_summary(depth: dict[str, Any]) -> str:
    """The tracks' disparity range with its reference named (the one wording of the check's range: the
    command line, the HTML report): the views' own range, and from infinity too when the views are
    sheared by a stated amount; what the exports write."""
    reference = disparity_reference_of(depth)
    lo = depth.get("views_disparity_min_px", depth.get("disparity_min_px"))
    hi = depth.get("views_disparity_max_px", depth.get("disparity_max_px"))
    if lo is None or hi is None:
        return "– (too few tracks)"
    text = f"{lo:+.2f} … {hi:+.2f} px between horizontal neighbours, {reference} (tracked points)"
    if reference != "from infinity" and depth.get("disparity_min_px") is not None:
        text += f"; from infinity {depth['disparity_min_px']:+.2f} … {depth['disparity_max_px']:+.2f} px"
    if depth.get("export_disp_min_px") is not None:
        text += f"; the exports write {depth['export_disp_min_px']:.2f} … {depth['export_disp_max_px']:.2f} px"
    return text
