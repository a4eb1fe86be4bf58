"""The lens model: distortion and lateral chromatic aberration, as coordinate maps (processing's step 2).

It lives here, below processing, because the calibration uses the same model: it undistorts its
feature positions with it before fitting (:func:`undistort_points`), so the homography is fitted in
the coordinate system processing applies it in, and ``calibration.json`` records which model that
was (:func:`lens_fingerprint`); ``lfstudio.processing.steps.lens`` re-exports it.

A lens model answers one question: for a point of the *undistorted* image (full-resolution pixels,
OpenCV convention: the top-left pixel's centre is (0, 0)), where is it in the captured image, per
colour channel? The rectify step composes this with the rectifying homography into ONE remap.

Two sources: the lensfun database through lensfunpy (camera and lens by name), or explicit OpenCV
coefficients (camera matrix, ``k1 k2 p1 p2 [k3 [k4 k5 k6]]``) with lateral CA as a radial
magnification of red and blue relative to green.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from lfstudio.errors import InputError
from lfstudio.dataset.profile import LensStep

Coords = tuple[np.ndarray, np.ndarray]


@dataclass
class OpenCVLens:
    """Brown–Conrady distortion as in ``cv2.undistort``; TCA as radial scale of R and B about (cx, cy)."""

    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...]
    red_scale: float = 1.0
    blue_scale: float = 1.0
    distortion: bool = True
    tca: bool = True

    @property
    def per_channel(self) -> bool:
        return self.tca and (self.red_scale != 1.0 or self.blue_scale != 1.0)

    def distort(self, x: np.ndarray, y: np.ndarray) -> Coords:
        """Captured (distorted) pixel positions of undistorted pixel positions (green channel)."""
        if not self.distortion:
            return x, y
        d = list(self.dist) + [0.0] * (8 - len(self.dist))
        k1, k2, p1, p2, k3, k4, k5, k6 = d
        xn = (x.astype(np.float64) - self.cx) / self.fx
        yn = (y.astype(np.float64) - self.cy) / self.fy
        r2 = xn * xn + yn * yn
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
        yd = yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
        return xd * self.fx + self.cx, yd * self.fy + self.cy

    def source_coords(self, x: np.ndarray, y: np.ndarray) -> list[Coords]:
        """[(x, y)] for all channels, or [(xr, yr), (xg, yg), (xb, yb)] when lateral CA is corrected."""
        xd, yd = self.distort(x, y)
        if not self.per_channel:
            return [(xd.astype(np.float32), yd.astype(np.float32))]
        out = []
        for scale in (self.red_scale, 1.0, self.blue_scale):
            out.append(((self.cx + (xd - self.cx) * scale).astype(np.float32),
                        (self.cy + (yd - self.cy) * scale).astype(np.float32)))
        return out


class LensfunLens:
    """lensfun's correction maps for a camera + lens, computed once on the full-resolution grid."""

    per_channel = True

    def __init__(self, step: LensStep, full_size_wh: tuple[int, int], camera_name: str, lens_name: str,
                 focal_length_mm: float):
        # lensfunpy copies these names from its extension module into its namespace at import time,
        # where pyright cannot see them
        from lensfunpy import Database, Modifier, ModifyFlags  # pyright: ignore[reportAttributeAccessIssue]

        db = Database()
        cam_maker = step.camera_maker or None
        cam_model = step.camera_model or camera_name
        cams = _find_cameras(db, cam_maker, cam_model) if cam_model else []
        if not cams:
            raise InputError("processing.toml: [lens] camera_model",
                             f"lensfun knows no camera {cam_model!r}; give camera_maker/camera_model as lensfun "
                             "names them (e.g. 'Sony' / 'ILCE-7RM2') or use source = \"opencv\"")
        lens_model = step.lens_model or lens_name
        lenses = db.find_lenses(cams[0], step.lens_maker or None, lens_model) if lens_model else []
        if not lenses:
            raise InputError("processing.toml: [lens] lens_model",
                             f"lensfun knows no lens {lens_model!r} for {cams[0].maker} {cams[0].model}; "
                             "give lens_maker/lens_model as lensfun names them (e.g. 'FE 50mm f/1.8') "
                             "or use source = \"opencv\"")
        self.camera, self.lens = cams[0], lenses[0]
        w, h = full_size_wh
        flags = 0
        if step.distortion:
            flags |= ModifyFlags.DISTORTION
        if step.tca:
            flags |= ModifyFlags.TCA
        mod = Modifier(self.lens, self.camera.crop_factor, w, h)
        mod.initialize(focal_length_mm, step.aperture, step.distance_m, scale=1.0, flags=flags)
        coords = mod.apply_subpixel_geometry_distortion()
        if coords is None:  # no calibration data for this lens: identity
            ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
            coords = np.repeat(np.stack([xs, ys], axis=-1)[:, :, None, :], 3, axis=2)
        self.coords = np.ascontiguousarray(coords, dtype=np.float32)  # (h, w, 3, 2)
        self.description = f"lensfun: {self.camera.maker} {self.camera.model} + {self.lens.maker} {self.lens.model}"

    def source_coords(self, x: np.ndarray, y: np.ndarray) -> list[Coords]:
        out = []
        for c in range(3):
            mx = cv2.remap(self.coords[:, :, c, 0], x.astype(np.float32), y.astype(np.float32), cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
            my = cv2.remap(self.coords[:, :, c, 1], x.astype(np.float32), y.astype(np.float32), cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
            out.append((mx, my))
        return out


def _find_cameras(db, maker: str | None, model: str) -> list:
    found = db.find_cameras(maker, model)
    if not found and maker is None and " " in model.strip():  # "Sony ILCE-7RM2"
        first, rest = model.strip().split(" ", 1)
        found = db.find_cameras(first, rest)
    return found or db.find_cameras(maker, model, loose_search=True)


def lens_model(step: LensStep, full_size_wh: tuple[int, int], camera: dict | None = None,
               lens: dict | None = None):
    """The lens model the profile asks for, or None when the step is off."""
    if not step.enabled or not (step.distortion or step.tca):
        return None
    camera, lens = camera or {}, lens or {}
    focal_mm = step.focal_length_mm or float(lens.get("focal_length_mm") or 0.0)
    if step.source == "lensfun":
        if focal_mm <= 0:
            raise InputError("processing.toml: [lens] focal_length_mm",
                             "unknown (the dataset's lens has no focal_length_mm); give it")
        return LensfunLens(step, full_size_wh, str(camera.get("name", "")), str(lens.get("name", "")), focal_mm)
    w, h = full_size_wh
    fx = step.fx_px
    if fx <= 0:
        pitch_um = camera.get("pixel_pitch_um")
        sensor_px = camera.get("sensor_px")
        if focal_mm > 0 and pitch_um:
            fx = focal_mm / (float(pitch_um) / 1000.0)
            if sensor_px:
                fx *= w / float(sensor_px[0])
        else:
            raise InputError("processing.toml: [lens] fx_px",
                             "needed for OpenCV coefficients (the dataset gives no focal length and pixel pitch)")
    fy = step.fy_px or fx
    cx = step.cx_px or (w - 1) / 2.0
    cy = step.cy_px or (h - 1) / 2.0
    return OpenCVLens(fx, fy, cx, cy, tuple(step.dist_coeffs), step.tca_red_scale, step.tca_blue_scale,
                      distortion=step.distortion, tca=step.tca)


def green(model, x: np.ndarray, y: np.ndarray) -> Coords:
    """Captured positions of undistorted positions (the green channel; any array shape)."""
    shape = np.shape(x)
    xf = np.asarray(x, np.float64).reshape(-1)
    yf = np.asarray(y, np.float64).reshape(-1)
    if isinstance(model, OpenCVLens):
        gx, gy = model.distort(xf, yf)
    else:       # lensfun's maps: cv2.remap wants 2-D float32 maps of bounded width
        n = len(xf)
        cols = 1024
        rows = max(1, -(-n // cols))
        px = np.zeros(rows * cols, np.float32)
        py = np.zeros(rows * cols, np.float32)
        px[:n], py[:n] = xf, yf
        chans = model.source_coords(px.reshape(rows, cols), py.reshape(rows, cols))
        gx, gy = chans[1 if len(chans) == 3 else 0]
        gx, gy = np.asarray(gx, np.float64).reshape(-1)[:n], np.asarray(gy, np.float64).reshape(-1)[:n]
    return np.asarray(gx, np.float64).reshape(shape), np.asarray(gy, np.float64).reshape(shape)


def undistort_points(model, xy: np.ndarray, iterations: int = 20) -> np.ndarray:
    """Undistorted positions of captured points ``xy`` (N × 2, full-resolution pixels): the inverse
    of :func:`green` by fixed-point iteration (``u ← u − (distort(u) − x)``; converges for any real
    lens, whose distortion changes slowly across the image)."""
    x = np.asarray(xy, np.float64)
    if model is None or not len(x):
        return x.copy()
    u = x.copy()
    for _ in range(iterations):
        gx, gy = green(model, u[:, 0], u[:, 1])
        err = np.column_stack([gx, gy]) - x
        u -= err
        if np.max(np.abs(err)) < 1e-4:
            break
    return u


def lens_fingerprint(step: LensStep) -> dict:
    """What ``calibration.json`` records of the lens model the features were undistorted with
    (``"none"`` when the profile's lens step corrects no distortion) and processing compares."""
    import hashlib
    import json
    from dataclasses import asdict

    if not step.enabled or not step.distortion:
        return {"model": "none", "sha256": "none"}
    fields = asdict(step)
    fields.pop("tca", None)                 # lateral CA does not move the green channel
    fields.pop("tca_red_scale", None)
    fields.pop("tca_blue_scale", None)
    fields.pop("enabled", None)
    text = json.dumps(fields, sort_keys=True)
    return {"model": step.source, "step": fields, "sha256": hashlib.sha256(text.encode()).hexdigest()}
