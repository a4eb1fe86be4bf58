"""The rig's known camera poses and the pinhole camera of the exported views (COLMAP, nerfstudio).

Conventions (``docs/conventions.md``): rig frame x right, y down, z into the scene, metres; a view's
camera centre is ``C = (x_mm, y_mm, 0) / 1000`` from its *reported* axis position (the commanded one
when the controller reported none). The calibration (``calibration.json``, read through
:func:`lfstudio.calibration.model.load_calibration`) gives one orientation error ``R``
(``rotation_deg``, scipy ``from_euler("xyz")``) that maps rig-frame directions to camera-frame
directions and the intrinsics ``K_true`` (focal length, principal point): a world point X is seen at
``p ~ K_true · R · (X − C)``. The rectified views (processed with rectification) are those of the
ideal camera ``p ~ K0 · (X − C)``: same focal length, principal point at the image centre, no rotation.

So, in the usual world-to-camera form ``x_cam = R_cw · X + t``: ``R_cw = R`` (identity for rectified
views) and ``t = −R_cw · C``. Pixel coordinates here are OpenCV's (the centre of the top-left pixel
is (0, 0)); COLMAP and nerfstudio put that centre at (0.5, 0.5), so their principal point is ours
+ 0.5 (:meth:`PinholeCamera.principal_point_corner_px`).

Intrinsics are those of the *exported* images: the calibration's (full resolution) scaled per axis
with ``x_s = s·(x + 0.5) − 0.5``, ``s`` = exported size / calibrated size.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from lfstudio.dataset import Dataset
from lfstudio.dataset.grid import View
from lfstudio.dataset.paths import CALIBRATION_NAME
from lfstudio.errors import DatasetError


@dataclass(frozen=True)
class PinholeCamera:
    """One pinhole camera shared by every exported view (square pixels unless resized unevenly)."""

    size_px: tuple[int, int]                 # (width, height) of the exported images
    fx_px: float
    fy_px: float
    cx_px: float                              # OpenCV convention: top-left pixel centre at (0, 0)
    cy_px: float
    R: np.ndarray                             # 3 x 3, rig-frame direction -> camera-frame direction
    rectified: bool                           # the views are rectified: R is the identity
    rotation_from: str                        # where R comes from (for the manifest and the user)
    principal_point_from: str
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    warnings: tuple[str, ...] = field(default=())

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])

    def principal_point_corner_px(self) -> tuple[float, float]:
        """(cx, cy) with the top-left pixel's centre at (0.5, 0.5) (COLMAP, nerfstudio)."""
        return self.cx_px + 0.5, self.cy_px + 0.5

    def world_to_camera(self, centre_m: Sequence[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R_cw, t) with ``x_cam = R_cw · X + t`` for the camera centred at ``centre_m``."""
        C = np.asarray(centre_m, dtype=float)
        return self.R.copy(), -self.R @ C

    def project(self, points_m: np.ndarray, centre_m: Sequence[float]) -> np.ndarray:
        """OpenCV pixel coordinates (N x 2) of world points (N x 3, m) seen from ``centre_m``."""
        R, t = self.world_to_camera(centre_m)
        cam = np.atleast_2d(np.asarray(points_m, float)) @ R.T + t
        p = cam @ self.K.T
        return p[:, :2] / p[:, 2:3]

    def describe(self) -> dict[str, Any]:
        w, h = self.size_px
        return {"model": "PINHOLE", "image_size_px": [int(w), int(h)], "fx_px": self.fx_px, "fy_px": self.fy_px,
                "cx_px": self.cx_px, "cy_px": self.cy_px, "pixel_centre_convention": "top-left pixel centre (0, 0)",
                "rotation_deg": list(self.rotation_deg), "R": self.R.tolist(), "rectified": self.rectified,
                "rotation_from": self.rotation_from, "principal_point_from": self.principal_point_from}


def _scale_point(value: float, scale: float) -> float:
    """Pixel coordinate in an image resized by ``scale``: x_s = s·(x + 0.5) − 0.5."""
    return scale * (value + 0.5) - 0.5


def camera_for(ds: Dataset, size: Sequence[int], rectified: bool, calibration: dict | None = None) -> PinholeCamera:
    """The pinhole camera of ``ds``'s views exported at ``size`` (w, h): the calibrated camera
    (K_true, R), or the ideal rectified one (K0, identity) when ``rectified``. Without a calibration,
    the camera and lens of the manifest with the principal point at the centre and no rotation
    (a warning says so)."""
    from lfstudio.calibration.model import load_calibration, rotation_applied
    from lfstudio.calibration.model import rotation_matrix

    w, h = int(size[0]), int(size[1])
    cal = calibration if calibration is not None else load_calibration(ds)
    warnings: list[str] = []
    full = None
    f_full = None
    pp_full = None
    rot = (0.0, 0.0, 0.0)
    if cal:
        try:
            full = (float(cal["image_size_px"][0]), float(cal["image_size_px"][1]))
            f_full = float(cal["focal_length_px"]) if cal.get("focal_length_px") else None
            if cal.get("principal_point_px"):
                pp_full = (float(cal["principal_point_px"][0]), float(cal["principal_point_px"][1]))
            angles = [float(a) for a in cal.get("rotation_deg") or (0.0, 0.0, 0.0)]
            if len(angles) != 3 or not all(np.isfinite(angles)):
                raise ValueError("rotation_deg")
            rot = (angles[0], angles[1], angles[2])
        except (KeyError, TypeError, ValueError, IndexError):
            raise DatasetError(f"{ds.root / CALIBRATION_NAME}: image_size_px, focal_length_px, principal_point_px "
                               "or rotation_deg is unreadable; run 'lfstudio calibrate' again") from None
    if full is None:
        sensor_px = ds.camera.get("sensor_px")
        full = (float(sensor_px[0]), float(sensor_px[1])) if sensor_px else (float(w), float(h))
    sx, sy = w / full[0], h / full[1]
    if f_full is None:
        f_full = ds.focal_length_px(int(round(full[0])))
    nominal = ((full[0] - 1) / 2.0, (full[1] - 1) / 2.0)
    if rectified:
        if not cal:
            raise DatasetError(f"{ds.root}: the views are marked rectified but the dataset has no calibration.json; "
                               "calibrate and process again, or export the raw views")
        R = np.eye(3)
        pp, pp_from, rot_from = nominal, "rectified (image centre)", "rectified (identity)"
    elif cal:
        if not rotation_applied(cal):       # not significant: the views are left unrotated, so is the camera
            rot = (0.0, 0.0, 0.0)
        R = rotation_matrix(rot)
        pp = pp_full or nominal
        pp_from = "calibration (estimated)" if cal.get("principal_point_estimated") else "calibration (nominal centre)"
        rot_from = "calibration" if rotation_applied(cal) else "calibration (rotation not significant: none)"
    else:
        R = np.eye(3)
        pp, pp_from, rot_from = nominal, "image centre (no calibration)", "none (no calibration)"
        warnings.append("the dataset has no calibration: poses assume the camera looks exactly along the rig's z axis "
                        "(no orientation error); run 'lfstudio calibrate' first for the measured orientation")
    return PinholeCamera(size_px=(w, h), fx_px=f_full * sx, fy_px=f_full * sy,
                         cx_px=_scale_point(pp[0], sx), cy_px=_scale_point(pp[1], sy), R=R, rectified=rectified,
                         rotation_from=rot_from, principal_point_from=pp_from,
                         rotation_deg=(0.0, 0.0, 0.0) if rectified else rot, warnings=tuple(warnings))


def centre_m(ds: Dataset, view: View) -> np.ndarray:
    """Camera centre (m) of a view in the rig frame: its reported axis position (else the commanded one)."""
    rec = ds.view(*view)
    pos = rec.get("reported_mm") or rec.get("commanded_mm")
    if not pos or len(pos) < 2:
        raise DatasetError(f"{ds.manifest_path}: row {view[0]}, column {view[1]} has no reported or commanded "
                           "position; its pose is unknown")
    return np.array([float(pos[0]) / 1000.0, float(pos[1]) / 1000.0, 0.0])


def principal_point_shifts_px(ds: Dataset, views: Sequence[View], size: Sequence[int]
                              ) -> dict[View, tuple[float, float]] | None:
    """Each view's principal point offset (px of the exported images) for sheared views, None for
    parallel ones: a sheared view is the parallel one moved by ``shear · (position − reference)``
    (:mod:`lfstudio.dataset.zero_plane`), i.e. a pinhole camera whose principal point moved by that
    much; the reference is the middle of the views' positions (where archives centre their shear)."""
    from lfstudio.dataset.zero_plane import zero_plane

    zp = zero_plane(ds)
    if not zp.shear_px_per_mm:
        return None
    shear = zp.shear_at(size[0])
    centres = {v: centre_m(ds, v)[:2] * 1000.0 for v in views}
    ref = np.mean(list(centres.values()), axis=0)
    return {v: (float(shear * (c[0] - ref[0])), float(shear * (c[1] - ref[1]))) for v, c in centres.items()}


def position_warnings(ds: Dataset, views: Sequence[View]) -> list[str]:
    missing = [v for v in views if not ds.view(*v).get("reported_mm")]
    if not missing:
        return []
    return [f"{len(missing)} of {len(views)} views have no reported axis position; their commanded position is used"]


def quaternion_wxyz(R: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion (w, x, y, z) of a rotation matrix, w >= 0 (COLMAP's QW QX QY QZ)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(np.asarray(R, float)).as_quat()
    if w < 0:
        x, y, z, w = -x, -y, -z, -w
    return float(w), float(x), float(y), float(z)
