"""The virtual studio: a synthetic 3-D scene of textured planar layers with exact ground truth,
rendered for any camera position on the acquisition plane.

Conventions (also in ``docs/conventions.md``; the calibration relies on them):

* **Rig frame**: x to the right, y down, z into the scene (right-handed). The acquisition plane is
  z = 0. Camera positions on it are given in **mm** (``x_mm``, ``y_mm``, as the rig reports them);
  scene geometry (layer depths, world points) is in **metres**. The camera centre of a view is
  ``C = (x_mm / 1000, y_mm / 1000, 0)`` m.
* **Intrinsics**: ``K_true = [[f, 0, cx], [0, f, cy], [0, 0, 1]]`` with ``f = focal_length_mm /
  (sensor_width_mm / width_px)`` px, ``cx = (width_px - 1) / 2 + pp_offset_px[0]``,
  ``cy = (height_px - 1) / 2 + pp_offset_px[1]``. Pixel (0, 0) is the centre of the top-left pixel.
* **Orientation error**: ``rotation_deg = [rx, ry, rz]``,
  ``R = scipy.spatial.transform.Rotation.from_euler("xyz", rotation_deg, degrees=True).as_matrix()``.
  A world point X (m) is captured at pixel ``p ~ K_true · R · (X − C)``.
* **Ideal (rectified) camera**: ``K0`` = same f, principal point at the image centre, no rotation:
  ``p_rect ~ K0 · (X − C)``. The rectifying homography (captured pixel → rectified pixel) is
  ``H = K0 · Rᵀ · K_true⁻¹``, the same for every view.
* **Disparity**: in rectified views, moving the camera by ``b`` mm to the right moves the image of a
  point at depth Z by ``disparity_px(Z, b) = f · b / (1000 · Z)`` px to the *left* (u decreases);
  moving it down by ``b`` mm moves the image up by the same amount.

Rendering composites the layers back to front, each warped with its plane-induced homography
(``cv2.warpPerspective`` into the layer's bounding box, premultiplied alpha). Output: float32 linear
RGB in [0, 1] (1 = sensor clipping). Deterministic for a seed.

**Fault injection** (ground truth for the dataset quality check, :mod:`lfstudio.quality`): a
:class:`ViewFault` spoils one view of a grid the way a real capture goes wrong —

* ``blur``: motion blur of ``blur_px`` full-resolution pixels along ``blur_angle_deg`` (0 =
  horizontal: the carriage still vibrating, a too-short settle time), :func:`motion_blur`;
* ``luminance``: the light changed by the factor ``gain`` for this shot (a flash or lamp step);
* ``displaced``: the camera stood ``offset_mm`` away from where the rig reported it;
* ``skipped``: the rig skipped the move, so the view shows the previous view's position (in
  capture order) while the manifest says it moved.

:func:`parse_fault` reads the command-line form ``KIND:VIEW[:VALUE]``, the view by its name
(``blur:r01_c002:6``); the former bare ``ROW,COLUMN`` is refused with that form, since a position
on the command line is now COLUMN,ROW.
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass
from typing import Any, Literal, overload

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from lfstudio.dataset.paths import parse_view_stem, view_stem
from lfstudio.optics import REFERENCE
from lfstudio.sim import textures

#: the reference sensor's aspect ratio (7952 x 5304)
REFERENCE_ASPECT = REFERENCE.sensor_px[1] / REFERENCE.sensor_px[0]
DEFAULT_WIDTH_PX = 2000
#: camera positions the reference grid covers (101 x 21 views at 4 x 6 mm from the origin: 400 x 120 mm)
REFERENCE_REGION_MM = (0.0, (REFERENCE.grid[0] - 1) * REFERENCE.spacing_mm[0],
                       0.0, (REFERENCE.grid[1] - 1) * REFERENCE.spacing_mm[1])


#: the orientation error and principal-point offset of the demo studio's camera: the ground truth a
#: calibration of a simulated scan should recover
DEMO_ROTATION_DEG = (1.0, -1.5, 0.7)
DEMO_PP_OFFSET_PX = (8.0, -5.0)


def demo_studio_kwargs(**overrides: Any) -> dict[str, Any]:
    """:class:`VirtualStudio` arguments of the demo studio (see :func:`demo_studio`), with ``overrides``."""
    return {"rotation_deg": DEMO_ROTATION_DEG, "pp_offset_px": DEMO_PP_OFFSET_PX, **overrides}


def demo_studio(**overrides: Any) -> "VirtualStudio":
    """The studio the simulated camera shows by default: the reference scene (1.77 … 4.77 m, grid
    region 400 x 120 mm from the origin) seen with a known orientation error and principal-point
    offset (:data:`DEMO_ROTATION_DEG`, :data:`DEMO_PP_OFFSET_PX`)."""
    return VirtualStudio(**demo_studio_kwargs(**overrides))


FAULT_KINDS = ("blur", "luminance", "displaced", "skipped")


@dataclass(frozen=True)
class ViewFault:
    """A defect injected into the view at (``row``, ``column``); see the module docstring."""

    kind: str
    row: int
    column: int
    blur_px: float = 0.0                       # blur: length of the motion, full-resolution pixels
    blur_angle_deg: float = 0.0                # blur: direction (0 = along the rows)
    gain: float = 1.0                          # luminance: light factor of this shot
    offset_mm: tuple[float, float] = (0.0, 0.0)  # displaced: true minus reported position

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {self.kind!r}; one of {', '.join(FAULT_KINDS)}")
        if self.row < 0 or self.column < 0:
            raise ValueError(f"fault at row {self.row}, column {self.column}: must be non-negative")
        if self.kind == "blur" and not self.blur_px > 0:
            raise ValueError(f"a blur fault needs a positive length in pixels, got {self.blur_px}")
        if self.kind == "luminance" and not (self.gain > 0 and self.gain != 1.0):
            raise ValueError(f"a luminance fault needs a positive factor other than 1, got {self.gain}")

    @property
    def cell(self) -> tuple[int, int]:
        return self.row, self.column

    def describe(self) -> dict[str, Any]:
        """JSON form (``ground_truth.json``: ``faults``): the kind, the view and the fault's own figures."""
        out: dict[str, Any] = {"kind": self.kind, "row": self.row, "column": self.column}
        keep = {"blur": ("blur_px", "blur_angle_deg"), "luminance": ("gain",), "displaced": ("offset_mm",),
                "skipped": ()}[self.kind]
        out.update({k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items() if k in keep})
        return out

    def spoil_image(self, rgb: np.ndarray) -> np.ndarray:
        """The rendered linear image as this fault leaves it (blur, luminance); others unchanged."""
        if self.kind == "blur":
            return motion_blur(rgb, self.blur_px, self.blur_angle_deg)
        if self.kind == "luminance":
            return rgb * np.float32(self.gain)
        return rgb

    def true_position_mm(self, intended_mm: tuple[float, float],
                         previous_mm: tuple[float, float] | None) -> tuple[float, float]:
        """Where the camera really stood: ``intended_mm`` (the reported position plus the rig's
        random error) moved by this fault; ``previous_mm``: the previous shot's true position."""
        if self.kind == "displaced":
            return intended_mm[0] + self.offset_mm[0], intended_mm[1] + self.offset_mm[1]
        if self.kind == "skipped":
            if previous_mm is None:
                raise ValueError(f"view row {self.row}, column {self.column} is the first shot: the rig "
                                 "cannot skip the move to it")
            return previous_mm
        return intended_mm


def parse_fault(text: str) -> ViewFault:
    """``KIND:VIEW[:VALUE]``: ``blur:r01_c002:6`` (6 px), ``blur:r01_c002:6,90`` (vertical),
    ``luminance:r00_c003:1.3``, ``displaced:r02_c002:1.0,0`` (mm), ``skipped:r01_c001``. ValueError
    names the fix; the former ``KIND:ROW,COLUMN`` is refused showing the view's name."""
    parts = text.strip().split(":")
    usage = ("KIND:VIEW[:VALUE], e.g. blur:r01_c002:6  luminance:r00_c003:1.3  displaced:r02_c002:1.0,0  "
             f"skipped:r01_c001 (kinds: {', '.join(FAULT_KINDS)})")
    old = re.fullmatch(r"\s*(\d+)\s*,\s*(\d+)\s*", parts[1]) if len(parts) > 1 else None
    if old:         # ROW,COLUMN before; COLUMN,ROW would silently spoil another view: name it instead
        parts[1] = view_stem(int(old.group(1)), int(old.group(2)))
        raise ValueError(f"fault {text!r}: the view is now given by its name (ROW,COLUMN is no longer read, "
                         f"positions are COLUMN,ROW): write {':'.join(parts)}")
    try:
        kind = parts[0].strip().lower()
        row, column = parse_view_stem(parts[1].strip())
        values = [float(v) for v in parts[2].split(",")] if len(parts) > 2 and parts[2].strip() else []
        if len(parts) > 3:
            raise ValueError
    except (IndexError, ValueError):
        raise ValueError(f"cannot read fault {text!r}; write {usage}") from None
    need = {"blur": (1, 2), "luminance": (1, 1), "displaced": (1, 2), "skipped": (0, 0)}.get(kind)
    if need is None:
        raise ValueError(f"unknown fault kind {kind!r} in {text!r}; write {usage}")
    if not need[0] <= len(values) <= need[1]:
        raise ValueError(f"fault {text!r}: {kind} takes {need[0]}–{need[1]} number(s) after the view; write {usage}")
    if kind == "blur":
        return ViewFault("blur", row, column, blur_px=values[0], blur_angle_deg=values[1] if len(values) > 1 else 0.0)
    if kind == "luminance":
        return ViewFault("luminance", row, column, gain=values[0])
    if kind == "displaced":
        return ViewFault("displaced", row, column, offset_mm=(values[0], values[1] if len(values) > 1 else 0.0))
    return ViewFault("skipped", row, column)


def motion_blur(rgb: np.ndarray, length_px: float, angle_deg: float = 0.0) -> np.ndarray:
    """``rgb`` smeared by a straight motion of ``length_px`` pixels along ``angle_deg`` (box
    profile, fractional ends weighted; the image size and mean brightness are kept)."""
    length = float(length_px)
    if length <= 0:
        return rgb
    half = int(np.ceil(length / 2.0))
    size = 2 * half + 1
    x = np.arange(size, dtype=np.float64) - half
    # weight of each pixel = its overlap with the segment [-length/2, length/2]
    line = np.clip(np.minimum(x + 0.5, length / 2.0) - np.maximum(x - 0.5, -length / 2.0), 0.0, 1.0)
    kernel = np.zeros((size, size), np.float32)
    kernel[half, :] = line
    if angle_deg % 180.0:
        rot = cv2.getRotationMatrix2D((float(half), float(half)), float(angle_deg), 1.0)
        kernel = cv2.warpAffine(kernel, rot, (size, size), flags=cv2.INTER_LINEAR)
    kernel /= kernel.sum()
    return cv2.filter2D(np.asarray(rgb, np.float32), -1, kernel, borderType=cv2.BORDER_REFLECT_101)


def rotation_matrix(rotation_deg: tuple[float, float, float] | list[float]) -> np.ndarray:
    """R from ``[rx, ry, rz]`` degrees (scipy ``from_euler("xyz", ..., degrees=True)``)."""
    return Rotation.from_euler("xyz", [float(v) for v in rotation_deg], degrees=True).as_matrix()


@dataclass(frozen=True)
class Layer:
    """A textured fronto-parallel plane at ``depth_m``.

    Texture pixel (s, t) has its centre at world ``(origin_m[0] + s * pixel_m, origin_m[1] + t *
    pixel_m, depth_m)``. ``rgba`` is uint16 premultiplied RGBA (alpha 65535 = opaque).
    ``reflect``: the texture continues mirrored beyond its border (the background).
    """

    name: str
    kind: str              # "background" | "layer" | "object"
    depth_m: float
    origin_m: tuple[float, float]
    pixel_m: float
    rgba: np.ndarray
    reflect: bool = False
    gain: float = 1.0      # radiance multiplier (a highlight brighter than white: > 1)

    @property
    def size_m(self) -> tuple[float, float]:
        h, w = self.rgba.shape[:2]
        return w * self.pixel_m, h * self.pixel_m

    def describe(self) -> dict[str, Any]:
        w_m, h_m = self.size_m
        return {"name": self.name, "kind": self.kind, "depth_m": self.depth_m,
                "x_range_m": [self.origin_m[0], self.origin_m[0] + w_m],
                "y_range_m": [self.origin_m[1], self.origin_m[1] + h_m],
                "texture_px": [int(self.rgba.shape[1]), int(self.rgba.shape[0])], "pixel_m": self.pixel_m}


def _premultiplied_rgba(rgb: np.ndarray, alpha: np.ndarray | None = None) -> np.ndarray:
    h, w = rgb.shape[:2]
    a = np.ones((h, w), np.float32) if alpha is None else alpha.astype(np.float32)
    out = np.empty((h, w, 4), np.uint16)
    out[..., :3] = np.rint(np.clip(rgb, 0, 1) * a[..., None] * 65535.0)
    out[..., 3] = np.rint(a * 65535.0)
    return out


class VirtualStudio:
    """A synthetic scene plus the camera that looks at it (intrinsics, orientation error).

    ``near_m``/``far_m``: nearest and farthest scene distance (the plan's M_F, M_B).
    ``view_region_mm``: ``(x_min, x_max, y_min, y_max)`` of the camera positions that must see the
    background in every pixel (the grid's extent; the scene is centred on it).
    ``texture_density``: texture pixels per image pixel at each layer's depth (capped so that no
    texture exceeds ``max_texture_px`` pixels).
    """

    def __init__(self, *, width_px: int = DEFAULT_WIDTH_PX, height_px: int | None = None,
                 focal_length_mm: float = REFERENCE.focal_length_mm, sensor_width_mm: float = REFERENCE.sensor_mm[0],
                 near_m: float = REFERENCE.near_m, far_m: float = REFERENCE.far_m,
                 rotation_deg: tuple[float, float, float] | list[float] = (0.0, 0.0, 0.0),
                 pp_offset_px: tuple[float, float] | list[float] = (0.0, 0.0),
                 view_region_mm: tuple[float, float, float, float] = REFERENCE_REGION_MM,
                 seed: int = 0, n_layers: int = 4, n_objects: int = 4,
                 texture_density: float = 1.0, max_texture_px: float = 40e6, highlight_gain: float = 0.0):
        if not 0 < near_m < far_m:
            raise ValueError(f"need 0 < near_m < far_m, got near_m={near_m}, far_m={far_m}")
        if width_px < 16:
            raise ValueError(f"width_px must be at least 16, got {width_px}")
        self.width_px = int(width_px)
        self.height_px = int(height_px) if height_px else int(round(self.width_px * REFERENCE_ASPECT / 2)) * 2
        self.focal_length_mm = float(focal_length_mm)
        self.sensor_width_mm = float(sensor_width_mm)
        self.near_m, self.far_m = float(near_m), float(far_m)
        self.rotation_deg = [float(v) for v in rotation_deg]
        self.pp_offset_px = [float(v) for v in pp_offset_px]
        self.view_region_mm = tuple(float(v) for v in view_region_mm)
        self.seed = int(seed)
        self.texture_density = float(texture_density)
        self.max_texture_px = float(max_texture_px)
        self.n_layers, self.n_objects = int(n_layers), int(n_objects)
        #: > 0: a lamp-like disc in front whose radiance peaks at this many times white (a highlight
        #: that clips at the reference exposure; true radiance in render(), clipped by the sensor)
        self.highlight_gain = float(highlight_gain)
        self.f_px = self.focal_length_mm / (self.sensor_width_mm / self.width_px)
        w, h = self.width_px, self.height_px
        self.K0 = np.array([[self.f_px, 0, (w - 1) / 2], [0, self.f_px, (h - 1) / 2], [0, 0, 1]])
        self.K_true = self.K0.copy()
        self.K_true[0, 2] += self.pp_offset_px[0]
        self.K_true[1, 2] += self.pp_offset_px[1]
        self.R = rotation_matrix(self.rotation_deg)
        self.H = self.K0 @ self.R.T @ np.linalg.inv(self.K_true)
        self.H /= self.H[2, 2]
        self.layers: list[Layer] = self._build_scene(n_layers, n_objects)

    def init_kwargs(self) -> dict[str, Any]:
        """Arguments that rebuild this studio (same scene and camera), e.g. in another process."""
        return dict(width_px=self.width_px, height_px=self.height_px, focal_length_mm=self.focal_length_mm,
                    sensor_width_mm=self.sensor_width_mm, near_m=self.near_m, far_m=self.far_m,
                    rotation_deg=tuple(self.rotation_deg), pp_offset_px=tuple(self.pp_offset_px),
                    view_region_mm=self.view_region_mm, seed=self.seed, n_layers=self.n_layers,
                    n_objects=self.n_objects, texture_density=self.texture_density,
                    max_texture_px=self.max_texture_px, highlight_gain=self.highlight_gain)

    # -- geometry -----------------------------------------------------------------------------------
    @staticmethod
    def camera_centre_m(x_mm: float, y_mm: float) -> np.ndarray:
        return np.array([x_mm / 1000.0, y_mm / 1000.0, 0.0])

    def camera_matrices(self, ideal: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(K, R) of the captured camera, or of the ideal one (K0, identity) with ``ideal``."""
        return (self.K0, np.eye(3)) if ideal else (self.K_true, self.R)

    def project(self, points_m: np.ndarray, x_mm: float, y_mm: float, ideal: bool = False) -> np.ndarray:
        """Pixel coordinates (N x 2) of world points (N x 3, m) seen from camera position (x_mm, y_mm)."""
        K, R = self.camera_matrices(ideal)
        X = np.atleast_2d(np.asarray(points_m, float)) - self.camera_centre_m(x_mm, y_mm)
        p = (K @ R @ X.T).T
        return p[:, :2] / p[:, 2:3]

    def disparity_px(self, depth_m: float | np.ndarray, baseline_mm: float) -> float | np.ndarray:
        """Disparity in (rectified) pixels of a point at ``depth_m`` between views ``baseline_mm`` apart."""
        return self.f_px * (baseline_mm / 1000.0) / np.asarray(depth_m, float) if np.ndim(depth_m) \
            else self.f_px * (baseline_mm / 1000.0) / float(depth_m)

    def layer_homography(self, layer: Layer, x_mm: float, y_mm: float, ideal: bool = False) -> np.ndarray:
        """3 x 3 homography from the layer's texture pixels to image pixels for this view."""
        K, R = self.camera_matrices(ideal)
        c = self.camera_centre_m(x_mm, y_mm)
        plane = np.array([[layer.pixel_m, 0.0, layer.origin_m[0] - c[0]],
                          [0.0, layer.pixel_m, layer.origin_m[1] - c[1]],
                          [0.0, 0.0, layer.depth_m - c[2]]])
        return K @ R @ plane

    def _frustum_box_m(self, depth_m: float, margin: float = 0.0) -> tuple[float, float, float, float]:
        """(x0, x1, y0, y1) at ``depth_m`` seen by any view in the region, captured or ideal."""
        x0r, x1r, y0r, y1r = self.view_region_mm
        w, h = self.width_px, self.height_px
        corners = np.array([[0, 0, 1], [w - 1, 0, 1], [0, h - 1, 1], [w - 1, h - 1, 1]], float).T
        xs, ys = [], []
        for K, R in (self.camera_matrices(False), self.camera_matrices(True)):
            d = R.T @ np.linalg.inv(K) @ corners           # ray directions in the rig frame
            for cx_mm in (x0r, x1r):
                for cy_mm in (y0r, y1r):
                    c = self.camera_centre_m(cx_mm, cy_mm)
                    t = depth_m / d[2]
                    xs += list(c[0] + d[0] * t)
                    ys += list(c[1] + d[1] * t)
        x0, x1, y0, y1 = min(xs), max(xs), min(ys), max(ys)
        mx, my = (x1 - x0) * margin, (y1 - y0) * margin
        return x0 - mx, x1 + mx, y0 - my, y1 + my

    def _pixel_m(self, depth_m: float, width_m: float, height_m: float) -> float:
        pixel_m = depth_m / (self.f_px * self.texture_density)
        n = (width_m / pixel_m) * (height_m / pixel_m)
        if n > self.max_texture_px:
            pixel_m *= float(np.sqrt(n / self.max_texture_px))
        return pixel_m

    # -- the scene ----------------------------------------------------------------------------------
    def layer_depths(self) -> tuple[list[float], list[float]]:
        """Depths (m) of the intermediate layers and of the small objects, spaced evenly in 1/Z."""
        inv_n, inv_f = 1.0 / self.near_m, 1.0 / self.far_m
        return ([1.0 / (inv_f + (inv_n - inv_f) * t) for t in (0.22, 0.45, 0.65, 0.82)],
                [1.0 / (inv_f + (inv_n - inv_f) * t) for t in (1.0, 0.96, 0.92, 0.88, 0.9, 0.94)])

    def _build_scene(self, n_layers: int, n_objects: int) -> list[Layer]:
        seeds = np.random.SeedSequence(self.seed).spawn(1 + n_layers + n_objects)
        layers: list[Layer] = []
        # background: covers every view of the region, plus a margin
        x0, x1, y0, y1 = self._frustum_box_m(self.far_m, margin=0.04)
        pm = self._pixel_m(self.far_m, x1 - x0, y1 - y0)
        tw, th = int(np.ceil((x1 - x0) / pm)) + 1, int(np.ceil((y1 - y0) / pm)) + 1
        rng = np.random.default_rng(seeds[0])
        rgb = textures.detailed_texture(rng, th, tw)
        layers.append(Layer("background", "background", self.far_m, (x0, y0), pm, _premultiplied_rgba(rgb),
                            reflect=True))

        mid_depths, obj_depths = self.layer_depths()
        kinds = ("foliage", "frame", "foliage", "board")
        for i in range(n_layers):
            rng = np.random.default_rng(seeds[1 + i])
            depth = mid_depths[i % len(mid_depths)] if i < len(mid_depths) else \
                float(rng.uniform(self.near_m * 1.2, self.far_m * 0.9))
            kind = kinds[i % len(kinds)]
            fx0, fx1, fy0, fy1 = self._frustum_box_m(depth)
            fw, fh = fx1 - fx0, fy1 - fy0
            if kind == "foliage":
                w_m, h_m = fw * 1.05, fh * rng.uniform(0.35, 0.5)
                lx = fx0 - fw * 0.025
                ly = fy1 - h_m if (i // 2) % 2 == 0 else fy0       # bottom or top band
            elif kind == "frame":
                w_m, h_m = fw * rng.uniform(0.3, 0.4), fh * rng.uniform(0.5, 0.7)
                lx = fx0 + fw * rng.uniform(0.02, 0.15)
                ly = fy0 + fh * rng.uniform(0.1, 0.3)
            else:
                w_m, h_m = fw * rng.uniform(0.2, 0.3), fh * rng.uniform(0.3, 0.45)
                lx = fx0 + fw * rng.uniform(0.6, 0.72)
                ly = fy0 + fh * rng.uniform(0.1, 0.4)
            pm = self._pixel_m(depth, w_m, h_m)
            tw, th = max(4, int(round(w_m / pm))), max(4, int(round(h_m / pm)))
            rgb = textures.detailed_texture(rng, th, tw, text=kind != "foliage")
            if kind == "foliage":
                green = np.array([0.35, 0.9, 0.3], np.float32)
                rgb = rgb * (0.4 + 0.6 * green)
                alpha = textures.blob_mask(rng, th, tw, coverage=0.45)
                alpha *= textures.shape_mask(th, tw, "rounded")
            else:
                alpha = textures.shape_mask(th, tw, "frame" if kind == "frame" else "rounded", rng)
            layers.append(Layer(f"{kind}-{i}", "layer", float(depth), (lx, ly), pm,
                                _premultiplied_rgba(rgb, alpha)))

        # small objects in front, inside the central part of the field
        for j in range(n_objects):
            rng = np.random.default_rng(seeds[1 + n_layers + j])
            depth = obj_depths[j % len(obj_depths)]
            fx0, fx1, fy0, fy1 = self._frustum_box_m(depth)
            fw, fh = fx1 - fx0, fy1 - fy0
            size_m = min(fw, fh) * rng.uniform(0.08, 0.16)
            w_m, h_m = size_m * rng.uniform(0.8, 1.5), size_m * rng.uniform(0.8, 1.5)
            cx = fx0 + fw * (0.15 + 0.7 * (j + rng.uniform(0.2, 0.8)) / max(1, n_objects))
            cy = fy0 + fh * rng.uniform(0.25, 0.75)
            pm = self._pixel_m(depth, w_m, h_m)
            tw, th = max(4, int(round(w_m / pm))), max(4, int(round(h_m / pm)))
            rgb = textures.detailed_texture(rng, th, tw)
            alpha = textures.shape_mask(th, tw, "disc" if j % 2 == 0 else "rounded")
            layers.append(Layer(f"object-{j}", "object", float(depth), (cx - w_m / 2, cy - h_m / 2), pm,
                                _premultiplied_rgba(rgb, alpha)))
        if self.highlight_gain > 0:
            depth = obj_depths[0]
            fx0, fx1, fy0, fy1 = self._frustum_box_m(depth)
            fw, fh = fx1 - fx0, fy1 - fy0
            size_m = min(fw, fh) * 0.22
            pm = self._pixel_m(depth, size_m, size_m)
            n = max(8, int(round(size_m / pm)))
            yy, xx = np.mgrid[0:n, 0:n].astype(np.float32)
            r = np.hypot(xx - (n - 1) / 2, yy - (n - 1) / 2) / (n / 2)
            glow = np.clip(1.0 - r * r, 0.0, 1.0)           # brightest in the middle, down to 0 at the rim
            rgb = np.repeat((0.05 + 0.95 * glow)[..., None], 3, axis=2) * np.array([1.0, 0.95, 0.85], np.float32)
            alpha = (r <= 1.0).astype(np.float32)
            cx, cy = fx0 + fw * 0.5, fy0 + fh * 0.45
            layers.append(Layer("highlight", "object", float(depth) * 0.98, (cx - size_m / 2, cy - size_m / 2), pm,
                                _premultiplied_rgba(rgb, alpha), gain=self.highlight_gain))
        layers.sort(key=lambda layer: -layer.depth_m)      # back to front
        return layers

    # -- rendering ----------------------------------------------------------------------------------
    @overload
    def render(self, x_mm: float, y_mm: float, *, ideal: bool = False, with_depth: Literal[False] = False,
               scale: float = 1.0) -> np.ndarray: ...

    @overload
    def render(self, x_mm: float, y_mm: float, *, ideal: bool = False, with_depth: Literal[True],
               scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]: ...

    def render(self, x_mm: float, y_mm: float, *, ideal: bool = False, with_depth: bool = False,
               scale: float = 1.0) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Render the view from camera position (x_mm, y_mm): H x W x 3 float32 linear RGB in [0, 1]
        (true radiance: a highlight (``highlight_gain``) goes beyond 1; the sensor clips it).

        ``ideal``: render with the ideal camera (K0, no rotation) instead of the captured one.
        ``with_depth``: also return the H x W float32 depth map (m, z of the visible surface).
        ``scale`` < 1: a smaller image of the same view (previews; textures are not filtered).
        """
        w, h = self.width_px, self.height_px
        S = None
        if scale != 1.0:
            w, h = max(2, int(round(w * scale))), max(2, int(round(h * scale)))
            sx, sy = w / self.width_px, h / self.height_px
            # pixel centres: u' + 0.5 = (u + 0.5) * s
            S = np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])
        out = np.zeros((h, w, 3), np.float32)
        depth = np.full((h, w), self.far_m, np.float32) if with_depth else None
        to_unit = np.float32(1.0 / 65535.0)
        for layer in self.layers:
            P = self.layer_homography(layer, x_mm, y_mm, ideal)
            if S is not None:
                P = S @ P
            if layer.reflect:
                warped = cv2.warpPerspective(layer.rgba[..., :3], P, (w, h), flags=cv2.INTER_LINEAR,
                                             borderMode=cv2.BORDER_REFLECT_101)
                np.multiply(warped, to_unit, out=out, dtype=np.float32, casting="unsafe")
                if depth is not None:
                    depth[:] = layer.depth_m
                continue
            box = _footprint(P, layer.rgba.shape[:2], (h, w))
            if box is None:
                continue
            x0, x1, y0, y1, T = box
            warped = cv2.warpPerspective(layer.rgba, T @ P, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR,
                                         borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0, 0))
            wf = warped.astype(np.float32)
            wf *= to_unit
            if layer.gain != 1.0:
                wf[..., :3] *= np.float32(layer.gain)
            alpha = wf[..., 3:4]
            roi = out[y0:y1, x0:x1]
            roi *= 1.0 - alpha
            roi += wf[..., :3]
            if depth is not None:
                depth[y0:y1, x0:x1][alpha[..., 0] > 0.5] = layer.depth_m
        return out if depth is None else (out, depth)

    def depth_map(self, x_mm: float, y_mm: float, *, ideal: bool = False) -> np.ndarray:
        """H x W float32 depth (m, z of the visible surface) in the view from (x_mm, y_mm): the same
        map as ``render(..., with_depth=True)`` (a pixel belongs to the nearest layer whose warped
        alpha is above one half), made from the layers' alpha only (no colour is composited)."""
        w, h = self.width_px, self.height_px
        depth = np.full((h, w), self.far_m, np.float32)
        for layer in self.layers:
            if layer.reflect:
                depth[:] = layer.depth_m
                continue
            P = self.layer_homography(layer, x_mm, y_mm, ideal)
            box = _footprint(P, layer.rgba.shape[:2], (h, w))
            if box is None:
                continue
            x0, x1, y0, y1, T = box
            alpha = cv2.warpPerspective(np.ascontiguousarray(layer.rgba[..., 3]), T @ P, (x1 - x0, y1 - y0),
                                        flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            depth[y0:y1, x0:x1][alpha.astype(np.float32) * np.float32(1.0 / 65535.0) > 0.5] = layer.depth_m
        return depth

    # -- ground truth -------------------------------------------------------------------------------
    def ground_truth(self) -> dict[str, Any]:
        """Everything a calibration needs to be checked against (JSON-able)."""
        return {
            "conventions": "rig frame x right, y down, z into the scene; camera positions in mm, scene in m; "
                           "p ~ K_true R (X - C); rectified p ~ K0 (X - C); H = K0 R^T K_true^-1 maps captured "
                           "to rectified pixels; R = Rotation.from_euler('xyz', rotation_deg, degrees=True)",
            "image_size_px": [self.width_px, self.height_px],
            "focal_length_px": self.f_px,
            "focal_length_mm": self.focal_length_mm,
            "sensor_width_mm": self.sensor_width_mm,
            "rotation_deg": list(self.rotation_deg),
            "R": self.R.tolist(),
            "pp_offset_px": list(self.pp_offset_px),
            "K_true": self.K_true.tolist(),
            "K0": self.K0.tolist(),
            "H": self.H.tolist(),
            "near_m": self.near_m,
            "far_m": self.far_m,
            "seed": self.seed,
            "view_region_mm": list(self.view_region_mm),
            "layers": [layer.describe() for layer in self.layers],
        }


def _footprint(P: np.ndarray, layer_hw: tuple[int, int], view_hw: tuple[int, int]):
    """The part of the view a layer warped by ``P`` can cover: ``(x0, x1, y0, y1, T)`` with ``T`` the
    shift that warps into that box alone (a pixel of margin for the interpolation), or None when the
    layer misses the view."""
    (th, tw), (h, w) = layer_hw, view_hw
    corners = np.array([[-1, -1, 1], [tw, -1, 1], [-1, th, 1], [tw, th, 1]], float).T
    pc = P @ corners
    u, v = pc[0] / pc[2], pc[1] / pc[2]
    x0, x1 = max(0, int(np.floor(u.min()))), min(w, int(np.ceil(u.max())) + 1)
    y0, y1 = max(0, int(np.floor(v.min()))), min(h, int(np.ceil(v.max())) + 1)
    if x1 <= x0 or y1 <= y0:
        return None
    return x0, x1, y0, y1, np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
