"""SIFT features per view (cached in the dataset) and matching of a pair of views.

Images are read as grey at a working width (RAW: LibRaw's half-size mode, which bins the Bayer
quads instead of demosaicing; PNG/TIFF/JPEG through OpenCV) and downscaled with area averaging.
Keypoints are stored in **full-resolution pixel coordinates** of the captured view (pixel centres
at integers: ``x_full = (x_work + 0.5) · s − 0.5``).

Matching: nearest neighbours on SIFT descriptors, Lowe's ratio test, mutual (cross) check, then a
geometric check suited to the rig: the two views differ by a pure translation and share one
orientation, so every correspondence line ``a → b`` passes through one epipole. A 2-point RANSAC
finds that epipole; a match is kept if ``b`` lies within a threshold of the line through ``a`` and
the epipole and moves the way the camera moved (scene points shift left when the camera moves right).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from lfstudio.dataset.atomic import atomic_write_with
from lfstudio.dataset.paths import folder_inside
from lfstudio.errors import DatasetError

RAW_SUFFIXES = {".dng", ".arw", ".cr2", ".cr3", ".nef", ".raf", ".orf", ".rw2", ".pef", ".srw", ".raw", ".3fr",
                ".iiq", ".erf", ".kdc", ".mrw", ".nrw", ".x3f"}
CACHE_VERSION = 2
DEFAULT_WORK_WIDTH_PX = 2000
DEFAULT_MAX_FEATURES = 6000


@dataclass
class Features:
    xy: np.ndarray            # N × 2 float32, full-resolution pixels
    descriptors: np.ndarray   # N × 128 float32
    image_size_px: tuple[int, int]   # full-resolution [w, h]
    scale: float              # full-resolution pixels per working pixel

    @property
    def count(self) -> int:
        return int(len(self.xy))


def _normalise_to_u8(grey: np.ndarray) -> np.ndarray:
    if grey.dtype == np.uint8:
        return grey
    g = grey.astype(np.float32)
    lo, hi = np.percentile(g[::4, ::4], (0.5, 99.8))
    if hi <= lo:
        hi = lo + 1.0
    return np.clip((g - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)


def read_grey(path: str | Path, max_width_px: int | None = DEFAULT_WORK_WIDTH_PX) -> tuple[np.ndarray, tuple[int, int], float]:
    """Grey uint8 image at (at most) ``max_width_px``; also the full-resolution size and the scale
    (full-resolution pixels per returned pixel)."""
    path = Path(path)
    if path.suffix.lower() in RAW_SUFFIXES:
        import rawpy
        try:
            with rawpy.imread(str(path)) as raw:
                sizes = raw.sizes   # read before postprocess: half_size changes them
                full = (int(sizes.width), int(sizes.height))
                if sizes.flip in (5, 6):
                    full = (full[1], full[0])
                rgb = raw.postprocess(half_size=True, use_camera_wb=True, no_auto_bright=True, output_bps=16,
                                      gamma=(2.222, 4.5))
        except Exception as exc:  # rawpy raises several LibRaw error types
            raise DatasetError(f"{path}: cannot be read as a RAW file ({exc}); re-copy it from the camera") from None
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    else:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH)
        if img is None:
            raise DatasetError(f"{path}: cannot be read as an image (missing or corrupt); re-copy it or "
                               "exclude the view")
        if img.ndim == 3:
            img = cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2GRAY)
        grey = img
        full = (int(img.shape[1]), int(img.shape[0]))
    grey = _normalise_to_u8(grey)
    h, w = grey.shape[:2]
    if max_width_px and w > max_width_px:
        new_w = int(max_width_px)
        new_h = max(1, int(round(h * new_w / w)))
        grey = cv2.resize(grey, (new_w, new_h), interpolation=cv2.INTER_AREA)
    return grey, full, full[0] / grey.shape[1]


def detect(path: str | Path, max_width_px: int | None = DEFAULT_WORK_WIDTH_PX,
           max_features: int = DEFAULT_MAX_FEATURES) -> Features:
    """SIFT keypoints and descriptors of one view (coordinates in full-resolution pixels)."""
    grey, full, scale = read_grey(path, max_width_px)
    sift = cv2.SIFT_create(nfeatures=int(max_features))
    kps, desc = sift.detectAndCompute(grey, None)
    if desc is None or not kps:
        return Features(np.zeros((0, 2), np.float32), np.zeros((0, 128), np.float32), full, scale)
    xy = np.array([k.pt for k in kps], np.float64)
    xy = (xy + 0.5) * scale - 0.5
    return Features(xy.astype(np.float32), desc.astype(np.float32), full, scale)


class FeatureCache:
    """Per-view feature files in ``DATASET/cache/features/r00_c000.npz``; stale entries (source file
    changed, other settings) are recomputed."""

    def __init__(self, root: str | Path, max_width_px: int | None = DEFAULT_WORK_WIDTH_PX,
                 max_features: int = DEFAULT_MAX_FEATURES):
        self.folder = folder_inside(root, "cache/features", create=False)   # refused when it leads outside
        self.max_width_px = max_width_px
        self.max_features = max_features

    def _key(self, source: Path) -> dict:
        st = os.stat(source)
        return {"version": CACHE_VERSION, "source": source.name, "size": st.st_size, "mtime_ns": st.st_mtime_ns,
                "max_width_px": self.max_width_px, "max_features": self.max_features}

    def get(self, stem: str, source: str | Path) -> tuple[Features, bool]:
        """Features of the view ``stem`` read from ``source``; also whether they came from the cache."""
        source = Path(source)
        if not source.is_file():
            raise DatasetError(f"{source}: image file of view {stem} is missing; re-capture or exclude the view")
        key = self._key(source)
        path = self.folder / f"{stem}.npz"
        if path.is_file():
            try:
                with np.load(path, allow_pickle=False) as z:
                    if json.loads(str(z["key"])) == key:
                        return Features(z["xy"], z["descriptors"], tuple(int(v) for v in z["size"]),
                                        float(z["scale"])), True
            except (OSError, ValueError, KeyError):
                pass  # unreadable cache entry: recompute
        feats = detect(source, self.max_width_px, self.max_features)
        self.folder.mkdir(parents=True, exist_ok=True)
        atomic_write_with(path, lambda p: np.savez(p, xy=feats.xy, descriptors=feats.descriptors,
                                                   size=np.array(feats.image_size_px), scale=feats.scale,
                                                   key=json.dumps(key)))
        return feats, False


@dataclass
class MatchResult:
    xy_a: np.ndarray          # inliers, full-resolution pixels
    xy_b: np.ndarray
    candidates: int           # after ratio test and mutual check
    inliers: int
    epipole: np.ndarray | None


def _ratio_matches(da: np.ndarray, db: np.ndarray, ratio: float) -> dict[int, int]:
    if len(da) * len(db) > 4_000_000:   # approximate nearest neighbours (kd-trees) for large sets
        matcher = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 4}, {"checks": 64})
    else:
        matcher = cv2.BFMatcher(cv2.NORM_L2)
    out: dict[int, int] = {}
    for m in matcher.knnMatch(np.ascontiguousarray(da, np.float32), np.ascontiguousarray(db, np.float32), k=2):
        if len(m) == 2 and m[0].distance < ratio * m[1].distance:
            out[m[0].queryIdx] = m[0].trainIdx
        elif len(m) == 1:
            out[m[0].queryIdx] = m[0].trainIdx
    return out


def epipole_ransac(xy_a: np.ndarray, xy_b: np.ndarray, direction: str, threshold_px: float,
                   iterations: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray | None]:
    """Inlier mask of matches consistent with a pure translation (one epipole), and the epipole.

    ``direction`` "h": b is to the right of a (points move left, −u); "v": b is below a (points move up).
    """
    n = len(xy_a)
    if n < 3:
        return np.zeros(n, bool), None
    norm = float(max(np.abs(xy_a).max(), 1.0))
    pa = np.column_stack([xy_a / norm, np.ones(n)])
    pb = np.column_stack([xy_b / norm, np.ones(n)])
    lines = np.cross(pa, pb)
    expected = np.array([-1.0, 0.0]) if direction == "h" else np.array([0.0, -1.0])
    moves_right_way = (xy_b - xy_a) @ expected > -threshold_px
    rng = np.random.default_rng(seed)
    i = rng.integers(0, n, iterations)
    j = rng.integers(0, n, iterations)
    keep = i != j
    e = np.cross(lines[i[keep]], lines[j[keep]])                 # M × 3 candidate epipoles
    best = np.zeros(n, bool)
    best_e = None
    for chunk in range(0, len(e), 100):
        ec = e[chunk:chunk + 100]
        lc = np.cross(pa[None, :, :], ec[:, None, :])              # M × N lines through a and e
        d = np.abs(np.einsum("mnk,nk->mn", lc, pb)) / np.maximum(np.hypot(lc[..., 0], lc[..., 1]), 1e-15)
        inl = (d * norm < threshold_px) & moves_right_way[None, :]
        counts = inl.sum(axis=1)
        k = int(np.argmax(counts))
        if counts[k] > best.sum():
            best, best_e = inl[k], ec[k]
    return best, best_e


def match_pair(fa: Features, fb: Features, direction: str, *, ratio: float = 0.8, mutual: bool = True,
               threshold_work_px: float = 1.5) -> MatchResult:
    """Match two views' features; keep geometrically consistent matches (see module docstring)."""
    if fa.count < 2 or fb.count < 2:
        empty = np.zeros((0, 2))
        return MatchResult(empty, empty, 0, 0, None)
    ab = _ratio_matches(fa.descriptors, fb.descriptors, ratio)
    if mutual:
        ba = _ratio_matches(fb.descriptors, fa.descriptors, ratio)
        pairs = [(i, j) for i, j in ab.items() if ba.get(j) == i]
    else:
        pairs = list(ab.items())
    if not pairs:
        empty = np.zeros((0, 2))
        return MatchResult(empty, empty, 0, 0, None)
    idx = np.array(pairs)
    xy_a = fa.xy[idx[:, 0]].astype(np.float64)
    xy_b = fb.xy[idx[:, 1]].astype(np.float64)
    threshold = threshold_work_px * max(fa.scale, fb.scale)
    mask, e = epipole_ransac(xy_a, xy_b, direction, threshold)
    return MatchResult(xy_a[mask], xy_b[mask], len(pairs), int(mask.sum()), e)
