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

:func:`match_pairs` matches many pairs at once on a thread pool: one nearest-neighbour index per
view (FLANN kd-trees for large sets, brute force for small ones), built once and used by one task
only (no concurrent queries on one index), forward queries ``a → b`` first, then the mutual check's
reverse queries only for the descriptors of ``b`` that some ``a`` chose. OpenCV releases the GIL
while it searches, so two threads use both cores.
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import cv2
import numpy as np

from lfstudio.dataset import images
from lfstudio.dataset.atomic import atomic_write_with
from lfstudio.dataset.paths import folder_inside
from lfstudio.errors import DatasetError

CACHE_VERSION = 2
#: detection width and keypoints per view: on the default views of a 4000 px virtual dataset 1400 px /
#: 3000 keypoints take half the CPU of 2000 px / 6000 (29 vs 59 s cold) at the same accuracy, which
#: the rig's position noise sets (rotation error 0.0018° vs 0.0014°; with exact positions, 2 × 3:
#: 0.0027° vs 0.0021°); 1000 px is too coarse (0.021°). benchmarks/calibration_speed.py
DEFAULT_WORK_WIDTH_PX = 1400
DEFAULT_MAX_FEATURES = 3000


@dataclass
class Features:
    xy: np.ndarray            # N × 2 float32, full-resolution pixels
    descriptors: np.ndarray   # N × 128 float32
    image_size_px: tuple[int, int]   # full-resolution [w, h]
    scale: float              # full-resolution pixels per working pixel

    @property
    def count(self) -> int:
        return int(len(self.xy))


def detect(path: str | Path, max_width_px: int | None = DEFAULT_WORK_WIDTH_PX,
           max_features: int = DEFAULT_MAX_FEATURES) -> Features:
    """SIFT keypoints and descriptors of one view (coordinates in full-resolution pixels)."""
    grey, full, scale = images.read_grey(path, max_width_px)
    sift = cv2.SIFT.create(nfeatures=int(max_features))
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
                        width, height = (int(v) for v in z["size"])
                        return Features(z["xy"], z["descriptors"], (width, height), float(z["scale"])), True
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


#: above this many descriptor pairs (query × index) a FLANN kd-tree index replaces brute force
_FLANN_ABOVE = 4_000_000
#: leaves a FLANN query visits: 32 keeps 99.7 % of the inliers 64 finds, at 2/3 of the time
FLANN_CHECKS = 32


class DescriptorIndex:
    """Nearest-neighbour search over one view's descriptors; the kd-tree is built on first use.

    Not for concurrent use: :func:`match_pairs` gives each index to one task.
    """

    def __init__(self, descriptors: np.ndarray):
        self.descriptors = np.ascontiguousarray(descriptors, np.float32)
        self._flann = None

    def knn2(self, queries: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The two nearest neighbours of each query: indices (n × 2, -1 = none) and squared distances."""
        q = np.ascontiguousarray(queries, np.float32)
        n = len(q)
        idx = np.full((n, 2), -1, np.int64)
        dist = np.full((n, 2), np.inf, np.float32)
        if n == 0 or len(self.descriptors) == 0:
            return idx, dist
        if len(self.descriptors) >= 2 and n * len(self.descriptors) > _FLANN_ABOVE:
            if self._flann is None:
                # the kd-trees are randomised from OpenCV's RNG, which is per thread: seeded here, in the
                # thread that builds them, the same views give the same matches on every run
                cv2.setRNGSeed(0)
                self._flann = cv2.flann.Index(self.descriptors, {"algorithm": 1, "trees": 4})
            i, d = self._flann.knnSearch(q, 2, params={"checks": FLANN_CHECKS})
            return i.astype(np.int64), d.astype(np.float32)
        for row, ms in enumerate(cv2.BFMatcher(cv2.NORM_L2).knnMatch(q, self.descriptors, k=2)):
            for k, m in enumerate(ms[:2]):
                idx[row, k] = m.trainIdx
                dist[row, k] = m.distance * m.distance
        return idx, dist


def _ratio(idx: np.ndarray, dist: np.ndarray, ratio: float) -> np.ndarray:
    """Per query: the index of its match if it passes Lowe's ratio test, else -1."""
    ok = (idx[:, 0] >= 0) & ((idx[:, 1] < 0) | (dist[:, 0] < ratio * ratio * dist[:, 1]))
    return np.where(ok, idx[:, 0], -1)


def epipole_ransac(xy_a: np.ndarray, xy_b: np.ndarray, direction: str, threshold_px: float,
                   iterations: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray | None]:
    """Inlier mask of matches consistent with a pure translation (one epipole), and the epipole.

    ``direction`` "h": b is to the right of a (points move left, −u); "v": b is below a (points move up).
    Any other direction is a programming error (ValueError), not a looser check.
    """
    if direction not in ("h", "v"):
        raise ValueError(f"direction {direction!r}: 'h' or 'v'")
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
    # two matches on one line (SIFT repeats a keypoint with another orientation) give e = 0, which
    # every line "passes through": not a candidate
    scale = np.linalg.norm(lines[i[keep]], axis=1) * np.linalg.norm(lines[j[keep]], axis=1)
    e = e[np.linalg.norm(e, axis=1) > 1e-9 * np.maximum(scale, 1e-300)]
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


def _finish(fa: Features, fb: Features, direction: str, pairs: np.ndarray, threshold_work_px: float) -> MatchResult:
    """Geometric check of candidate index pairs (k × 2: index in a, index in b)."""
    if not len(pairs):
        empty = np.zeros((0, 2))
        return MatchResult(empty, empty, 0, 0, None)
    xy_a = fa.xy[pairs[:, 0]].astype(np.float64)
    xy_b = fb.xy[pairs[:, 1]].astype(np.float64)
    threshold = threshold_work_px * max(fa.scale, fb.scale)
    mask, e = epipole_ransac(xy_a, xy_b, direction, threshold)
    return MatchResult(xy_a[mask], xy_b[mask], len(pairs), int(mask.sum()), e)


def match_pair(fa: Features, fb: Features, direction: str, *, ratio: float = 0.8, mutual: bool = True,
               threshold_work_px: float = 1.5) -> MatchResult:
    """Match two views' features; keep geometrically consistent matches (see module docstring)."""
    if fa.count < 2 or fb.count < 2:
        empty = np.zeros((0, 2))
        return MatchResult(empty, empty, 0, 0, None)
    return match_pairs({"a": fa, "b": fb}, [("a", "b", direction)], ratio=ratio, mutual=mutual,
                       threshold_work_px=threshold_work_px, threads=1)[0]


def match_pairs(features: dict, pairs: Sequence[tuple[Any, Any, str]], *, ratio: float = 0.8, mutual: bool = True,
                threshold_work_px: float = 1.5, threads: int = 2,
                on_done: Callable[[int, MatchResult], None] | None = None,
                check: Callable[[], None] | None = None) -> list[MatchResult]:
    """Match every ``(key_a, key_b, direction)`` of ``pairs`` (keys into ``features``) in parallel.

    ``on_done(i, result)`` is called (from a worker thread) as each pair finishes; ``check()`` is
    called between tasks and may raise (cancel). Results are in the order of ``pairs``.
    """
    indexes = {k: DescriptorIndex(f.descriptors) for k, f in features.items()}
    forward: dict[int, np.ndarray] = {}
    reverse: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    live = [i for i, (a, b, _) in enumerate(pairs) if features[a].count >= 2 and features[b].count >= 2]

    def grouped(key_of) -> dict:
        out: dict = {}
        for i in live:
            out.setdefault(key_of(i), []).append(i)
        return out

    def forward_task(jobs):
        for i in jobs:
            if check:
                check()
            a, b, _ = pairs[i]
            forward[i] = _ratio(*indexes[b].knn2(features[a].descriptors), ratio)

    def reverse_task(jobs):
        for i in jobs:
            if check:
                check()
            a, b, _ = pairs[i]
            chosen = np.unique(forward[i][forward[i] >= 0])
            reverse[i] = (chosen, _ratio(*indexes[a].knn2(features[b].descriptors[chosen]), ratio))

    results: list[MatchResult | None] = [None] * len(pairs)

    def finish_task(i):
        if check:
            check()
        a, b, direction = pairs[i]
        best = forward[i]
        q = np.nonzero(best >= 0)[0]
        cand = np.column_stack([q, best[q]]) if len(q) else np.zeros((0, 2), np.int64)
        if mutual and len(cand):
            chosen, back = reverse[i]
            back_of = np.full(features[b].count, -2, np.int64)
            back_of[chosen] = back
            cand = cand[back_of[cand[:, 1]] == cand[:, 0]]
        results[i] = _finish(features[a], features[b], direction, cand, threshold_work_px)
        if on_done:
            on_done(i, results[i])

    workers = max(1, int(threads))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        passes = [(forward_task, grouped(lambda i: pairs[i][1]))]
        if mutual:          # the reverse pass is the mutual check's
            passes.append((reverse_task, grouped(lambda i: pairs[i][0])))
        for task, groups in passes:
            futures = [pool.submit(task, jobs) for jobs in _balanced(groups, features)]
            _wait_all(futures)
        _wait_all([pool.submit(finish_task, i) for i in live])
    empty = np.zeros((0, 2))
    return [r if r is not None else MatchResult(empty, empty, 0, 0, None) for r in results]


def _balanced(groups: dict, features: dict) -> list[list[int]]:
    """The jobs of each index as one task, largest first (so two threads finish together)."""
    return [jobs for _, jobs in sorted(groups.items(), key=lambda kv: -len(kv[1]) * features[kv[0]].count)]


def _wait_all(futures) -> None:
    try:
        for fut in futures:
            fut.result()
    except BaseException:
        for fut in futures:
            fut.cancel()
        raise
