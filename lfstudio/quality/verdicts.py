"""Thresholds and verdicts: each measured figure becomes ``pass``, ``warn`` or ``fail`` with the
limit that was used and one sentence why.

Every check of a view yields ``{"value": …, "verdict": …, "limit": …, "why": …}`` (``value`` None
and verdict ``"n/a"`` when it could not be measured, e.g. a view without captured neighbours); a
view's verdict is the worst of its checks (``n/a`` counts as a pass). The defaults are explained in
``docs/quality.md``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Iterable

PASS, WARN, FAIL, NA = "pass", "warn", "fail", "n/a"
_RANK = {NA: 0, PASS: 0, WARN: 1, FAIL: 2}
#: the repeatability assumed when the dataset's plan does not give one (the reference rig), µm
DEFAULT_REPEATABILITY_UM = (80.0, 50.0)


@dataclass(frozen=True)
class Thresholds:
    """Limits of the per-view checks (see ``docs/quality.md``)."""

    sharpness_warn: float = 0.85      # focus energy relative to the neighbours below this: warn
    sharpness_fail: float = 0.70
    exposure_warn: float = 0.04       # |brightness / neighbours − 1| above this: warn
    exposure_fail: float = 0.10
    clipped_warn: float = 0.005       # fraction of clipped pixels
    clipped_fail: float = 0.02
    crushed_warn: float = 0.02        # fraction of crushed (black) pixels
    crushed_fail: float = 0.10
    position_warn_mm: float | None = None   # None: max(3 × repeatability, 5 % of the spacing)
    position_fail_mm: float | None = None   # None: max(6 × repeatability, 10 % of the spacing)
    residual_warn_factor: float = 2.5  # track residual over the dataset's median residual
    residual_fail_factor: float = 5.0
    residual_floor_px: float = 0.5    # ... but never below this (full-resolution pixels)
    depth_tolerance: float = 0.05     # measured near/far beyond the plan by more than this: warn

    def position_limits_mm(self, repeatability_um: Iterable[float], spacing_mm: Iterable[float]) -> tuple[float, float]:
        eps_mm = max(float(v) for v in repeatability_um) / 1000.0
        step = min(float(v) for v in spacing_mm if float(v) > 0) if any(float(v) > 0 for v in spacing_mm) else 1.0
        warn = self.position_warn_mm if self.position_warn_mm is not None else max(3 * eps_mm, 0.05 * step)
        fail = self.position_fail_mm if self.position_fail_mm is not None else max(6 * eps_mm, 0.10 * step)
        return float(warn), float(max(fail, warn))

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def worst(verdicts: Iterable[str]) -> str:
    out = PASS
    for v in verdicts:
        if _RANK.get(v, 0) > _RANK[out]:
            out = v
    return out


def check(value: float | None, verdict: str, limit: float | None, why: str, **extra: Any) -> dict[str, Any]:
    return {"value": value, "verdict": verdict, "limit": limit, "why": why, **extra}


def not_measured(why: str) -> dict[str, Any]:
    return check(None, NA, None, why)


def sharpness(ratio: float | None, t: Thresholds) -> dict[str, Any]:
    if ratio is None:
        return not_measured("no captured neighbour to compare the focus with")
    if ratio < t.sharpness_fail:
        return check(ratio, FAIL, t.sharpness_fail, f"{ratio:.0%} of the neighbours' fine detail (below "
                     f"{t.sharpness_fail:.0%}): blurred — vibration, a short settle time or a missed focus")
    if ratio < t.sharpness_warn:
        return check(ratio, WARN, t.sharpness_warn, f"{ratio:.0%} of the neighbours' fine detail (below "
                     f"{t.sharpness_warn:.0%}): slightly soft")
    return check(ratio, PASS, t.sharpness_warn, f"{ratio:.0%} of the neighbours' fine detail")


def exposure(ratio: float | None, t: Thresholds, deflicker_gain: float | None = None) -> dict[str, Any]:
    extra = {} if deflicker_gain is None else {"deflicker_gain": deflicker_gain}
    if ratio is None:
        return {**not_measured("no captured neighbour to compare the brightness with"), **extra}
    dev = ratio - 1.0
    word = "brighter" if dev > 0 else "darker"
    text = f"{abs(dev):.1%} {word} than the neighbours"
    if abs(dev) > t.exposure_fail:
        return check(ratio, FAIL, t.exposure_fail, f"{text} (more than {t.exposure_fail:.0%}): the light or the "
                     "exposure changed for this shot", **extra)
    if abs(dev) > t.exposure_warn:
        return check(ratio, WARN, t.exposure_warn, f"{text} (more than {t.exposure_warn:.0%}): flicker; "
                     "de-flicker will even it out", **extra)
    return check(ratio, PASS, t.exposure_warn, text, **extra)


def clipping(clipped: float, crushed: float, t: Thresholds) -> dict[str, Any]:
    parts, verdicts = [], []
    for name, value, warn, fail in (("clipped highlights", clipped, t.clipped_warn, t.clipped_fail),
                                    ("crushed shadows", crushed, t.crushed_warn, t.crushed_fail)):
        if value > fail:
            verdicts.append(FAIL)
            parts.append(f"{value:.1%} {name} (more than {fail:.1%})")
        elif value > warn:
            verdicts.append(WARN)
            parts.append(f"{value:.1%} {name} (more than {warn:.1%})")
    verdict = worst(verdicts)
    why = "; ".join(parts) if parts else f"{clipped:.2%} clipped, {crushed:.2%} crushed"
    limit = {PASS: t.clipped_warn, WARN: t.clipped_warn, FAIL: t.clipped_fail}[verdict]
    return check(clipped, verdict, limit, why, crushed=crushed)


def position(error_mm: tuple[float, float] | None, limits_mm: tuple[float, float], error_px_near: float | None,
             measured_mm: tuple[float, float] | None = None) -> dict[str, Any]:
    if error_mm is None:
        return not_measured("too few tracked neighbours to locate this view")
    dx, dy = error_mm
    norm = float((dx * dx + dy * dy) ** 0.5)
    warn, fail = limits_mm
    extra = {"error_mm": [float(dx), float(dy)], "error_px_near": error_px_near,
             **({"measured_mm": [float(measured_mm[0]), float(measured_mm[1])]} if measured_mm is not None else {})}
    where = f"taken {norm:.3f} mm from where the manifest says (dx {dx:+.3f}, dy {dy:+.3f} mm" + \
        (f"; {error_px_near:.2f} px at the nearest depth)" if error_px_near is not None else ")")
    if norm > fail:
        return check(norm, FAIL, fail, f"{where}, more than {fail:.3f} mm: wrong place or a skipped step", **extra)
    if norm > warn:
        return check(norm, WARN, warn, f"{where}, more than {warn:.3f} mm", **extra)
    return check(norm, PASS, warn, where, **extra)


def residual(rms_px: float | None, typical_px: float | None, t: Thresholds) -> dict[str, Any]:
    if rms_px is None or typical_px is None:
        return not_measured("no tracks to fit")
    warn = max(t.residual_floor_px, t.residual_warn_factor * typical_px)
    fail = max(2 * t.residual_floor_px, t.residual_fail_factor * typical_px)
    text = f"tracks fit to {rms_px:.2f} px RMS after rectification (typical {typical_px:.2f} px)"
    if rms_px > fail:
        return check(rms_px, FAIL, fail, f"{text}, more than {fail:.2f} px: the view does not line up with its "
                     "neighbours (camera knocked, lens changed, or a different scene)")
    if rms_px > warn:
        return check(rms_px, WARN, warn, f"{text}, more than {warn:.2f} px")
    return check(rms_px, PASS, warn, text)


def bracket_clipping(frames: list[tuple[float, float, float]], t: Thresholds) -> dict[str, Any]:
    """The clipping check of an exposure-bracketed view, judged on what the merge keeps: a pixel is
    clipped after the merge when even the shortest frame clips it, in the noise floor when even the
    longest frame leaves it crushed. ``frames``: each frame's (exposure s, clipped, crushed) share.
    Beyond the limits the bracket does not cover the scene's range, and the fix is named."""
    shortest = min(frames, key=lambda f: f[0])
    longest = max(frames, key=lambda f: f[0])
    merged_clipped, merged_crushed = shortest[1], longest[2]
    out = clipping(merged_clipped, merged_crushed, t)
    listed = ", ".join(f"{e:.4g} s: {c:.2%} clipped, {k:.2%} crushed" for e, c, k in frames)
    fixes = []
    if merged_clipped > t.clipped_warn:
        fixes.append(f"the shortest frame ({shortest[0]:.4g} s) still clips {merged_clipped:.1%}: add a shorter "
                     "frame (e.g. 2 EV below it)")
    if merged_crushed > t.crushed_warn:
        fixes.append(f"the longest frame ({longest[0]:.4g} s) still leaves {merged_crushed:.1%} in the noise floor: "
                     "add a longer frame")
    out["why"] = (("the bracket does not cover the scene's range: " + "; ".join(fixes)) if fixes else
                  f"after the merge {merged_clipped:.2%} clipped, {merged_crushed:.2%} crushed") + f" (frames: {listed})"
    out["frames"] = [{"exposure_s": e, "clipped": c, "crushed": k} for e, c, k in frames]
    out["merged"] = {"clipped": merged_clipped, "crushed": merged_crushed}
    out["covers_range"] = not fixes
    return out
