"""The camera model shared by calibration, simulation, processing and the virtual studio.

Conventions (see ``docs/conventions.md``):

- rig frame: x to the right, y down, z into the scene; pixel (0, 0) is the centre of the top-left
  pixel, u to the right, v down;
- ``K = [[f, 0, cx], [0, f, cy], [0, 0, 1]]``; the nominal principal point is ``((w-1)/2, (h-1)/2)``;
- orientation error ``rotation_deg = [rx, ry, rz]``,
  ``R = Rotation.from_euler("xyz", rotation_deg, degrees=True).as_matrix()``;
- a world point X seen from camera centre C is captured at ``p ~ K_true · R · (X − C)``;
- the ideal (rectified) camera ``K0`` has the same f and the nominal centre: ``p_rect ~ K0 · (X − C)``;
- so the rectifying homography (captured full-resolution pixel → rectified pixel) is
  ``H = K0 · Rᵀ · K_true⁻¹``.

Also the fields of ``calibration.json`` that describe how far to trust it
(:class:`CalibrationUncertainty`, key ``uncertainty``; files written before it existed have none and
still load). scipy is imported only where a rotation is computed, so reading a document stays cheap.
"""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike

from lfstudio.dataset import Dataset
from lfstudio.dataset.atomic import atomic_write_json
from lfstudio.dataset.paths import CALIBRATION_NAME, resolve_inside
from lfstudio.errors import DatasetError

log = logging.getLogger(__name__)

ROTATION_CONVENTION = (
    "R = scipy.spatial.transform.Rotation.from_euler('xyz', rotation_deg, degrees=True).as_matrix(); "
    "rig frame x right, y down, z into the scene; a point X seen from camera centre C is captured at "
    "p ~ K_true R (X - C); rectified p_rect ~ K0 (X - C); H = K0 R^T K_true^-1 maps a captured "
    "full-resolution pixel to the rectified pixel; pixel centres at integer coordinates")


def rotation_matrix(rotation_deg: ArrayLike) -> np.ndarray:
    """3 × 3 orientation error R from ``[rx, ry, rz]`` in degrees (extrinsic x-y-z)."""
    from scipy.spatial.transform import Rotation
    return Rotation.from_euler("xyz", np.asarray(rotation_deg, dtype=float), degrees=True).as_matrix()


def rotation_deg_from_matrix(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return Rotation.from_matrix(R).as_euler("xyz", degrees=True)


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle of the rotation taking R_a to R_b (geodesic distance), degrees."""
    from scipy.spatial.transform import Rotation
    return float(np.degrees(Rotation.from_matrix(R_a.T @ R_b).magnitude()))


def nominal_principal_point(image_size_px: Sequence[int]) -> np.ndarray:
    w, h = image_size_px
    return np.array([(w - 1) / 2.0, (h - 1) / 2.0])


def intrinsics(focal_length_px: float, principal_point_px: ArrayLike) -> np.ndarray:
    cx, cy = np.asarray(principal_point_px, dtype=float)
    f = float(focal_length_px)
    return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])


def rectifying_homography(rotation_deg: ArrayLike, focal_length_px: float, image_size_px: Sequence[int],
                          principal_point_px: ArrayLike | None = None) -> np.ndarray:
    """``H = K0 · Rᵀ · K_true⁻¹`` normalised to ``H[2, 2] = 1`` (captured full-res pixel → rectified pixel)."""
    nominal = nominal_principal_point(image_size_px)
    pp = nominal if principal_point_px is None else np.asarray(principal_point_px, dtype=float)
    K0 = intrinsics(focal_length_px, nominal)
    K = intrinsics(focal_length_px, pp)
    H = K0 @ rotation_matrix(rotation_deg).T @ np.linalg.inv(K)
    return H / H[2, 2]


def apply_homography(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Map points ``xy`` (N × 2) through H; returns N × 2."""
    xy = np.asarray(xy, dtype=float)
    p = xy @ H[:, :2].T + H[:, 2]
    w = p[:, 2:3]
    w = np.where(np.abs(w) < 1e-12, 1e-12, w)
    return p[:, :2] / w


def pixel_scale_matrix(scale: float) -> np.ndarray:
    """Map pixel coordinates of an image to those of the same image scaled by ``scale``.

    Pixel centres sit at integer coordinates, so ``x_scaled = (x + 0.5) · scale − 0.5``.
    """
    s = float(scale)
    o = 0.5 * s - 0.5
    return np.array([[s, 0.0, o], [0.0, s, o], [0.0, 0.0, 1.0]])


def homography_at_scale(H: np.ndarray, scale: float) -> np.ndarray:
    """The full-resolution homography H for images scaled by ``scale`` (e.g. 0.5: half-size
    debayering): ``S · H · S⁻¹`` with ``S`` = :func:`pixel_scale_matrix` (pixel-centre convention;
    it equals the plain scaling only in the pixel-corner convention)."""
    S = pixel_scale_matrix(scale)
    return S @ np.asarray(H, dtype=float) @ np.linalg.inv(S)


def scale_homography(H: np.ndarray, from_size_px: Sequence[int], to_size_px: Sequence[int]) -> np.ndarray:
    """The homography H of images of ``from_size_px`` expressed for images of ``to_size_px`` (same aspect)."""
    return homography_at_scale(H, float(to_size_px[0]) / float(from_size_px[0]))


def project(points_m: np.ndarray, centre_m: np.ndarray, R: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of world points (N × 3) seen from ``centre_m``: ``p ~ K R (X − C)``; also the depth."""
    cam = (np.asarray(points_m) - np.asarray(centre_m)) @ R.T
    p = cam @ K.T
    return p[:, :2] / p[:, 2:3], cam[:, 2]


# -- calibration.json -----------------------------------------------------------------------------------


def calibration_problems(document: Any) -> list[str]:
    """What makes a ``calibration.json`` document unusable (empty when it is fine): its homography
    must be an invertible 3 × 3 matrix of numbers, its ``image_size_px`` [width, height] in pixels."""
    if not isinstance(document, dict):
        return [f"{CALIBRATION_NAME}: must be a JSON object"]
    problems = []
    try:
        H = np.asarray(document.get("homography"), dtype=float)
        ok = H.shape == (3, 3) and bool(np.all(np.isfinite(H))) and abs(np.linalg.det(H)) >= 1e-12
    except (TypeError, ValueError):
        ok = False
    if not ok:
        problems.append(f"{CALIBRATION_NAME}: homography: must be an invertible 3x3 matrix of numbers")
    size = document.get("image_size_px")
    size_ok = (isinstance(size, list) and len(size) == 2
               and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size))
    if not size_ok:
        problems.append(f"{CALIBRATION_NAME}: image_size_px: must be [width, height] in pixels")
    rotation = document.get("rotation_deg")
    if rotation is not None:
        try:
            angles = np.asarray(rotation, dtype=float)
            angles_ok = angles.shape == (3,) and bool(np.all(np.isfinite(angles)))
        except (TypeError, ValueError):
            angles_ok = False
        if not angles_ok:
            problems.append(f"{CALIBRATION_NAME}: rotation_deg: must be [rx, ry, rz] in degrees")
        elif np.any(np.abs(angles) > MAX_ANGLE_DEG + 1e-9):
            problems.append(f"{CALIBRATION_NAME}: rotation_deg {[round(float(a), 3) for a in angles]} lies outside "
                            f"the fit's bounds (±{MAX_ANGLE_DEG:g}° per angle): a failed fit, not a camera")
    if ok and size_ok and isinstance(size, list):
        shift = corner_shift_fraction(H, size)
        if not shift <= MAX_CORNER_SHIFT_FRACTION:
            problems.append(f"{CALIBRATION_NAME}: homography moves an image corner by "
                            + ("an unbounded distance (behind the camera)" if not np.isfinite(shift) else
                               f"{100 * shift:.0f} % of the image diagonal")
                            + f" (at most {100 * MAX_CORNER_SHIFT_FRACTION:.0f} % is a camera's orientation "
                            "error): it would turn the views black")
    return problems


#: the fit's bounds on each angle (deg): a saved or loaded calibration outside them is refused
MAX_ANGLE_DEG = 15.0
#: the farthest a calibration's homography may move an image corner, as a fraction of the image
#: diagonal (15° of pan moves the corners of a 50 mm lens on the reference sensor by ~30 %)
MAX_CORNER_SHIFT_FRACTION = 0.5


def corner_shift_fraction(H: np.ndarray, image_size_px: Sequence[int]) -> float:
    """How far ``H`` moves the farthest of the four image corners, as a fraction of the image
    diagonal (inf when a corner maps to or behind infinity)."""
    w, h = float(image_size_px[0]), float(image_size_px[1])
    corners = np.array([[0.0, 0.0], [w - 1, 0.0], [0.0, h - 1], [w - 1, h - 1]])
    p = corners @ np.asarray(H, float)[:, :2].T + np.asarray(H, float)[:, 2]
    if not np.all(p[:, 2] > 1e-9 * np.abs(p[:, :2]).max(initial=1.0)):
        return float("inf")
    moved = p[:, :2] / p[:, 2:3] - corners
    return float(np.max(np.hypot(moved[:, 0], moved[:, 1])) / np.hypot(w, h))


def load_calibration(dataset_or_root) -> dict[str, Any] | None:
    """The dataset's ``calibration.json`` (checked: :func:`calibration_problems`), or None when it has
    none (JSON only: cheap to call from a GUI). :class:`DatasetError` naming the file and the fix."""
    path = resolve_inside(Dataset.root_of(dataset_or_root), CALIBRATION_NAME)      # a symlink leading outside the dataset is refused
    if not path.is_file():
        return None
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DatasetError(f"{path}: cannot be read ({exc}); run 'lfstudio calibrate' again") from None
    problems = calibration_problems(document)
    if problems:
        raise DatasetError(f"{path}: invalid calibration; run 'lfstudio calibrate' again", problems)
    return document


def save_calibration(dataset, document: dict[str, Any]) -> Path:
    """Write ``calibration.json`` atomically into the dataset and note it in the manifest."""
    problems = calibration_problems(document)
    if problems:
        raise DatasetError("the calibration result cannot be saved", problems)
    path = resolve_inside(dataset.root, CALIBRATION_NAME)
    atomic_write_json(path, document)
    after = ((document.get("residual_px") or {}).get("after") or {}).get("rms")     # None: a document without it
    dataset.manifest["calibration"] = {"file": CALIBRATION_NAME, "created": document.get("created"),
                                       "rotation_deg": document.get("rotation_deg"),
                                       "residual_after_rms_px": after}
    dataset.save()
    log.info("calibration saved to %s", path)
    return path


def homography_for(document: dict[str, Any], image_size_px: Sequence[int] | None = None) -> np.ndarray:
    """The document's homography, expressed for images of ``image_size_px`` (default: full resolution)."""
    H = np.array(document["homography"], float)
    if image_size_px is None or list(image_size_px) == list(document["image_size_px"]):
        return H
    return scale_homography(H, document["image_size_px"], image_size_px)


def held_angles(doc: dict[str, Any]) -> dict[str, dict]:
    """The angles a calibration document holds (not determined by its views): key -> entry of
    ``observability.held`` (empty for documents written before observability was recorded)."""
    obs = doc.get("observability")
    if not isinstance(obs, dict):
        return {}
    return {str(h.get("angle")): h for h in obs.get("held") or () if isinstance(h, dict)}


#: a fitted rotation is applied (the views warped by it) only when an angle the views determine lies
#: at least this many of its stated σ from zero; a smaller one cannot be told from no rotation, and
#: warping perfect views by it makes them worse (issue 37: rendered HCI views warped by 2–3 σ "rotations")
ROTATION_SIGNIFICANCE_SIGMAS = 2.0
RECTIFICATION_KEY = "rectification"


def rotation_decision(rotation_deg: ArrayLike, rotation_std_deg: ArrayLike,
                      determined: Sequence[bool] = (True, True, True),
                      sigmas: float = ROTATION_SIGNIFICANCE_SIGMAS) -> dict[str, Any]:
    """Whether a fitted rotation is significant, so worth warping the views by: ``rotation_applied``
    when some determined angle lies ≥ ``sigmas`` of its σ from zero; ``z`` (angle / σ per angle, None
    for a held one) and ``decision`` (one line that says what was decided, for the report, the CLI and
    the window)."""
    angles = np.asarray(rotation_deg, float)
    std = np.asarray(rotation_std_deg, float)
    z: list[float | None] = [float(a / s) if d and s > 0 else None
                             for a, s, d in zip(angles, std, determined)]
    significant = [name for name, value in zip(("rx", "ry", "rz"), z)
                   if value is not None and abs(value) >= sigmas]
    shown = ", ".join(f"{name} {value:+.1f}σ" for name, value in zip(("rx", "ry", "rz"), z) if value is not None)
    if significant:
        decision = (f"rotation significant (|{'|, |'.join(significant)}| ≥ {sigmas:g}σ; {shown}): "
                    "views rectified by it")
    else:
        names = [name for name, value in zip(("rx", "ry", "rz"), z) if value is not None]
        decision = (f"rotation not significant (|{'|, |'.join(names) or 'no angle'}| < {sigmas:g}σ; {shown or 'none determined'}): "
                    "views left unrotated")
    return {"rotation_applied": bool(significant), "significance_sigmas": float(sigmas), "z": z,
            "decision": decision}


def rotation_applied(document: dict[str, Any]) -> bool:
    """Whether the document's homography rotates the views (documents written before the decision
    was recorded always did)."""
    rect = document.get(RECTIFICATION_KEY)
    return not isinstance(rect, dict) or bool(rect.get("rotation_applied", True))


def rectification_decision(document: dict[str, Any]) -> str | None:
    """The document's one-line decision about rotating the views, or None (older documents)."""
    rect = document.get(RECTIFICATION_KEY)
    text = rect.get("decision") if isinstance(rect, dict) else None
    return str(text) if text else None


UNCERTAINTY_KEY = "uncertainty"
#: the order of :attr:`CalibrationUncertainty.covariance`
PARAMETERS = ("rx_deg", "ry_deg", "rz_deg", "cx_offset_px", "cy_offset_px")


@dataclass(frozen=True)
class CalibrationUncertainty:
    """What a calibration's stated uncertainty is, as ``calibration.json`` stores it under ``uncertainty``.

    ``rotation_std_deg``: 1 σ per angle; ``covariance``: 5 × 5 over :data:`PARAMETERS` (the
    principal-point rows hold its prior when it was held at the centre). ``corner_error_px``: the
    1σ and 2σ bounds (68.3 % / 95.4 % quantiles) of the largest rectification error at the four image
    corners, for a pair as far apart as the grid's first and last column (``row_baseline_mm``, rows
    must agree) and one as far apart as its first and last row (``column_baseline_mm``), at the
    nearest scene depth (``row_disparity_px`` / ``column_disparity_px`` between those views).
    ``degenerate``: the views cannot fix the rotation well enough for the whole grid (see warnings).
    ``formal_rotation_std_deg``: the older statement (independent residuals), for comparison.
    ``linear_rotation_deg``: the linear epipole closed form, the cross-check, and
    ``linear_residual_px`` the RMS residual it leaves on the matches the fit kept.
    """

    rotation_std_deg: tuple[float, float, float]
    covariance: tuple[tuple[float, ...], ...] | None = None
    corner_error_px: tuple[float, float] | None = None
    row_baseline_mm: float | None = None
    column_baseline_mm: float | None = None
    row_disparity_px: float | None = None
    column_disparity_px: float | None = None
    position_sigma_um: tuple[float, float] | None = None
    feature_sigma_px: float | None = None
    formal_rotation_std_deg: tuple[float, float, float] | None = None
    principal_point_std_px: tuple[float, float] | None = None
    linear_rotation_deg: tuple[float, float, float] | None = None
    linear_residual_px: float | None = None
    degenerate: bool = False
    method: str = ""

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in out.items()}

    @classmethod
    def from_document(cls, document: dict[str, Any]) -> "CalibrationUncertainty | None":
        """The document's uncertainty; for older files (no ``uncertainty``) the formal
        ``rotation_std_deg`` alone when present, else None."""
        u = document.get(UNCERTAINTY_KEY)
        if isinstance(u, dict) and isinstance(u.get("rotation_std_deg"), list):
            def tup(key):
                v = u.get(key)
                return tuple(tuple(r) if isinstance(r, list) else r for r in v) if isinstance(v, list) else v
            known: dict[str, Any] = {k: tup(k) for k in cls.__dataclass_fields__ if k in u}
            return cls(**known)
        std = document.get("rotation_std_deg")
        if isinstance(std, list) and len(std) == 3:
            rx, ry, rz = (float(x) for x in std)
            return cls(rotation_std_deg=(rx, ry, rz), formal_rotation_std_deg=(std[0], std[1], std[2]),
                       method="formal (independent residuals; written before measured uncertainties)")
        return None
