"""The zero-disparity plane of a dataset's views: parallel (a scan) or sheared (most archives).

One model for every dataset (``docs/dataset-format.md``, "Zero-disparity plane"). A scene point at
depth ``Z`` seen from camera position ``p`` (mm on the acquisition plane) appears at

    o = a − (s − shear) · p          s = f / (1000 · Z)  (px per mm of baseline)

with ``f`` the focal length in pixels. A **parallel** capture (every lfstudio scan) has
``shear = 0``: zero disparity at infinity, every disparity positive. Archive light fields (the
Stanford archive, the HCI benchmark, Lytro sub-aperture stacks) are published **sheared**: each view
is shifted by ``shear · p`` so that the plane at ``Z0 = f / (1000 · shear)`` has zero disparity and
points behind it have negative disparity.

Matches between views measure ``s − shear`` only (the signed disparity per mm): a shift of every
view in proportion to its position is the same for every point, so no correspondence tells it from a
change of every depth's inverse by one constant. What the matches do tell: the signed disparity
range, and when a disparity is significantly negative, that the views are sheared and that the zero
plane is no farther than where the farthest point would sit at infinity. The zero plane's depth
itself is stated (``import-images --zero-disparity-depth-m``, an HCI ``parameters.cfg``) or not
known; a stage that needs depths then says so instead of guessing.

``dataset.json`` → ``zero_disparity`` holds the record (:func:`record`); a dataset without it (a
scan, an older import) is parallel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from lfstudio.errors import words

RECORD = "zero_disparity"
#: the one meaning of "disparity" in every view of lfstudio (labels add :meth:`ZeroPlane.disparity_words`)
DISPARITY_DEFINITION = ("disparity: how far a scene point moves between a view and its right-hand neighbour, in "
                        "full-resolution pixels of the views as they are; 0 px is infinitely far for parallel views, "
                        "on the zero-disparity plane for sheared ones")
#: where a record's shear came from
SOURCE_SCAN = "scan"                 # captured by lfstudio: parallel
SOURCE_MEASURED_PARALLEL = "measured"   # no significantly negative disparity: read as parallel
SOURCE_MEASURED_SHEARED = "measured-sheared"   # sheared, zero plane not stated (shear unknown)
SOURCE_STATED = "--zero-disparity-depth-m"
SOURCE_PARALLEL = "--parallel-views"
SOURCE_HCI = "parameters.cfg"


@dataclass(frozen=True)
class ZeroPlane:
    """A dataset's zero-disparity plane. ``shear_px_per_mm`` is in pixels of the full-size image
    (``camera.sensor_px``) per mm of baseline: 0 for parallel views, None when the views are sheared
    by an amount nobody stated."""

    shear_px_per_mm: float | None
    depth_m: float | None                  # None: at infinity (shear 0) or not known (shear None)
    source: str = SOURCE_SCAN
    width_px: float | None = None          # the image width the shear is given for
    measured: dict[str, Any] = field(default_factory=dict)

    @property
    def known(self) -> bool:
        return self.shear_px_per_mm is not None

    @property
    def parallel(self) -> bool:
        return self.shear_px_per_mm == 0.0

    def shear_at(self, image_width_px: float | None = None) -> float | None:
        """The shear in px per mm of an image ``image_width_px`` wide (default: the full size)."""
        if self.shear_px_per_mm is None:
            return None
        if image_width_px is None or not self.width_px:
            return self.shear_px_per_mm
        return self.shear_px_per_mm * float(image_width_px) / float(self.width_px)

    def shear_or_zero(self, image_width_px: float | None = None) -> float:
        s = self.shear_at(image_width_px)
        return 0.0 if s is None else s

    def disparity_reference(self) -> str:
        """What 0 px means for these views' disparities, for every label of one (the import summary,
        the check, its report and Disparity window, the depth maps): "from infinity" (parallel views),
        "relative to the zero-disparity plane at 1.20 m", or "... (its depth not stated)"."""
        if self.shear_px_per_mm == 0.0:
            return "from infinity"
        if self.shear_px_per_mm is None or not self.depth_m:
            return "relative to the zero-disparity plane (its depth not stated)"
        return f"relative to the zero-disparity plane at {self.depth_m:.2f} m"

    def disparity_words(self) -> str:
        """``between horizontal neighbours, <reference>``: the one definition of disparity in lfstudio
        (full-resolution px a scene point moves from one view to its right neighbour, in the views as
        they are; see :data:`DISPARITY_DEFINITION`)."""
        return f"between horizontal neighbours, {self.disparity_reference()}"

    def describe(self, front_words: bool = False) -> str:
        """One line for summaries: where zero disparity lies and how it is known. For views sheared by
        an unstated amount: what works without the plane and what needs it. ``front_words``: the
        options are :func:`lfstudio.errors.words` parts (a summary the window shows too; stored and
        printed text keeps the command line's words)."""
        def option(cli: str, window: str) -> str:
            return words(cli, window) if front_words else cli

        if self.shear_px_per_mm is None:
            bound = self.measured.get("depth_max_m")
            return ("sheared views (negative disparities measured), zero-disparity plane not stated"
                    + (f" (nearer than {bound:.2f} m)" if bound else "")
                    + ": calibration (the farthest tracked point taken at infinity), the check, disparities in px "
                    "and the PNG and HEVC exports work without it; depths in metres and the HCI, COLMAP and "
                    "nerfstudio exports need it (import again with "
                    + option("--zero-disparity-depth-m", "Zero disparity: Sheared, zero-disparity plane at") + ")")
        source = {SOURCE_PARALLEL: option("--parallel-views", "Zero disparity: Parallel views"),
                  SOURCE_STATED: option("--zero-disparity-depth-m", "Zero disparity: Sheared, zero-disparity plane at")
                  }.get(self.source, self.source)
        if self.shear_px_per_mm == 0.0:
            how = {SOURCE_SCAN: "scan", SOURCE_MEASURED_PARALLEL: "measured: no negative disparity"}.get(self.source,
                                                                                                         source)
            return f"parallel views, zero disparity at infinity ({how})"
        depth = f"{self.depth_m:.3f} m" if self.depth_m else "unknown depth (no focal length)"
        return f"sheared views, zero-disparity plane at {depth} ({self.shear_px_per_mm:.4f} px/mm; {source})"


def shear_for_depth(focal_length_px: float, depth_m: float) -> float:
    """The shear (px per mm) that puts zero disparity at ``depth_m`` for a focal length in px."""
    return float(focal_length_px) / (1000.0 * float(depth_m))


def depth_for_shear(focal_length_px: float | None, shear_px_per_mm: float | None) -> float | None:
    """The zero-disparity depth (m) of a shear; None at infinity (shear 0) or when unknown."""
    if focal_length_px is None or not shear_px_per_mm or shear_px_per_mm <= 0:
        return None
    return float(focal_length_px) / (1000.0 * float(shear_px_per_mm))


def record(shear_px_per_mm: float | None, depth_m: float | None, source: str, width_px: float | None,
           measured: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``dataset.json`` ``zero_disparity`` object."""
    return {"shear_px_per_mm": None if shear_px_per_mm is None else float(shear_px_per_mm),
            "depth_m": None if depth_m is None else float(depth_m),
            "parallel": shear_px_per_mm == 0.0, "source": source,
            "image_width_px": None if width_px is None else float(width_px),
            "measured": dict(measured or {})}


def _number(x: Any) -> float | None:
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else None


def zero_plane(dataset_or_manifest: Any) -> ZeroPlane:
    """The zero plane a dataset (or its manifest dict) records; parallel when it records none."""
    manifest = dataset_or_manifest if isinstance(dataset_or_manifest, dict) else dataset_or_manifest.manifest
    rec = manifest.get(RECORD)
    sensor = (manifest.get("camera") or {}).get("sensor_px")
    width = float(sensor[0]) if isinstance(sensor, (list, tuple)) and sensor else None
    if not isinstance(rec, dict):
        return ZeroPlane(0.0, None, SOURCE_SCAN, width)
    shear = _number(rec.get("shear_px_per_mm"))
    depth = _number(rec.get("depth_m"))
    measured = rec.get("measured")
    return ZeroPlane(shear, depth if depth and depth > 0 else None, str(rec.get("source") or SOURCE_SCAN),
                     _number(rec.get("image_width_px")) or width, measured if isinstance(measured, dict) else {})
