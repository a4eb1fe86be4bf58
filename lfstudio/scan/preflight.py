"""Pre-flight: does the whole scan fit the disk of its dataset folder and the camera's card?

A scan of thousands of views (times the frames of an exposure bracket) must not run for hours and
then pause on a full disk. Before it starts, and again as soon as the first view's frames are
stored, the space the views still to capture need is compared with what the disk has free:

``need = views left x bytes a view + the floor``

*bytes a view* is every frame of the view with its sidecars and thumbnail. It comes from, best
first: the views the dataset already holds (a resume: measured); the camera's own frame size where
the driver describes it (the simulated camera's sensor, 16-bit DNG); the scene plan's bytes per
image (the camera the operator planned with); else it is not known before the first picture (a
gphoto2 camera, a hot folder): then the scan engine checks right after the first view's frames
arrive (:meth:`lfstudio.scan.engine.ScanEngine` pauses with :func:`disk_shortfall`'s message).
The *floor* is the free space the engine keeps before every view (:func:`floor_bytes`), so a scan
that passes here does not pause on the way.

A gphoto2 camera that keeps its pictures on its card (``capturetarget`` not the camera's RAM, or
the driver told not to delete them after the download) is checked against the card's free space
and the camera's own count of pictures it still holds, where the driver can read them
(:meth:`lfstudio.rig.gphoto.GPhotoCamera.card_space`).

Below ``studio`` (the session refuses before the dataset is made) and beside the engine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lfstudio.dataset.storage import megabytes, mount_point
from lfstudio.errors import LfError

#: the free space the scan engine keeps at least before every view
MIN_FREE_BYTES = 8 * 2**20
#: a thumbnail, a sidecar and the journal's lines per view when only the frame's size is known
VIEW_OVERHEAD_BYTES = 64 * 1024
#: a 16-bit DNG's header and tags beside its pixels
DNG_OVERHEAD_BYTES = 16 * 1024
FIX = "free space there, choose a dataset folder on a larger disk, or scan fewer views or frames"


class ScanTooLarge(LfError):
    """The views left to capture do not fit the disk (or the card): ``need_bytes``, ``free_bytes``."""

    kind = "scan-too-large"

    def __init__(self, message: str, need_bytes: int, free_bytes: int):
        super().__init__(message)
        self.need_bytes = int(need_bytes)
        self.free_bytes = int(free_bytes)


@dataclass(frozen=True)
class ViewSize:
    """The bytes one view takes on the disk (every frame, sidecars, thumbnail) and where that came from."""

    bytes: int
    source: str          # "measured on the views stored", "the plan's 80 MB an image", ...
    frames: int = 1

    @property
    def frame_bytes(self) -> int:
        return max(1, self.bytes // max(1, self.frames))


def floor_bytes(view_bytes: int, manifest_bytes: int, min_free_bytes: int) -> int:
    """The free space the scan engine wants before each view: room for two views and a new copy of
    the manifest (a save writes a whole one), at least ``min_free_bytes``."""
    return max(int(min_free_bytes), 2 * int(view_bytes) + 2 * int(manifest_bytes) + 2**20)


def view_size(frames: int, *, stored_view_bytes: int = 0, sensor_px: Any = None,
              plan_bytes_per_image: int | None = None) -> ViewSize | None:
    """The best estimate of one view's bytes (see the module docstring), None when nothing tells it."""
    frames = max(1, int(frames))
    if stored_view_bytes > 0:
        return ViewSize(int(stored_view_bytes), "measured on the views already stored", frames)
    try:
        w, h = (int(v) for v in sensor_px)
    except (TypeError, ValueError):
        w = h = 0
    if w > 0 and h > 0:
        frame = 2 * w * h + DNG_OVERHEAD_BYTES
        return ViewSize(frames * frame + VIEW_OVERHEAD_BYTES,
                        f"the camera's {w} x {h} px 16-bit frames", frames)
    if plan_bytes_per_image and plan_bytes_per_image > 0:
        return ViewSize(frames * int(plan_bytes_per_image) + VIEW_OVERHEAD_BYTES,
                        f"the plan's {megabytes(plan_bytes_per_image)} an image", frames)
    return None


def _nearest_existing(folder: str | Path) -> Path:
    p = Path(folder).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def disk_shortfall(folder: str | Path, views: int, size: ViewSize, free_bytes: int, *,
                   min_free_bytes: int = 0, manifest_bytes: int = 0) -> ScanTooLarge | None:
    """The refusal when ``views`` views of ``size`` (plus the engine's floor) need more than
    ``free_bytes`` on the disk holding ``folder``; None when they fit. One line naming the need, how
    it was counted, the free space, the folder and the fix."""
    if views <= 0:
        return None
    need = views * size.bytes + floor_bytes(size.bytes, manifest_bytes, min_free_bytes)
    if need <= free_bytes:
        return None
    frames = f" x {size.frames} frames" if size.frames > 1 else ""
    fit = views_that_fit(free_bytes, size, min_free_bytes, manifest_bytes)
    where = _nearest_existing(folder)
    return ScanTooLarge(
        f"Disk too small for this scan: {views} views{frames} need about {megabytes(need)} in {Path(folder)} "
        f"({megabytes(size.bytes)} a view, {size.source}; free space kept while scanning included), "
        f"but the disk at {mount_point(where)} has {megabytes(free_bytes)} free: room for about {fit} views. "
        f"Fix: {FIX}.", need, free_bytes)


def card_shortfall(card: dict[str, Any] | None, views: int, frames: int,
                   frame_bytes: int | None) -> ScanTooLarge | None:
    """The refusal when the camera's card cannot hold the pictures it keeps during the scan.

    ``card``: :meth:`GPhotoCamera.card_space` (``keeps``: "all" the frames stay on the card, "one"
    each is deleted after its download, "none" they go to the camera's RAM; ``free_bytes`` and
    ``free_images`` as the camera reports them, None where it does not). None when they fit or
    nothing can be told."""
    if not card or card.get("keeps") in (None, "none") or views <= 0:
        return None
    pictures = views * max(1, frames) if card.get("keeps") == "all" else max(1, frames)
    label = card.get("label") or "the camera's card"
    free_images = card.get("free_images")
    if isinstance(free_images, int) and free_images >= 0 and pictures > free_images:
        return ScanTooLarge(
            f"Camera card too small for this scan: it keeps {pictures} pictures on {label}, which has room for "
            f"{free_images} more by the camera's count. Fix: {card_fix(card)}.",
            pictures * (frame_bytes or 0), (card.get("free_bytes") or 0))
    free = card.get("free_bytes")
    if frame_bytes and isinstance(free, int) and free >= 0 and pictures * frame_bytes > free:
        return ScanTooLarge(
            f"Camera card too small for this scan: it keeps {pictures} pictures of about {megabytes(frame_bytes)} "
            f"on {label} (about {megabytes(pictures * frame_bytes)}), which has {megabytes(free)} free. "
            f"Fix: {card_fix(card)}.", pictures * frame_bytes, free)
    return None


def card_fix(card: dict[str, Any]) -> str:
    if card.get("keeps") == "all":
        return "free the card (download or delete its pictures), use a larger card, or let lfstudio delete each " \
               "picture from the camera after its download"
    return "free the card (download or delete its pictures) or use a larger card"


def views_that_fit(free_bytes: int, size: ViewSize, min_free_bytes: int = 0, manifest_bytes: int = 0) -> int:
    """How many views of ``size`` the free space holds (the engine's floor kept)."""
    return max(0, math.floor((free_bytes - floor_bytes(size.bytes, manifest_bytes, min_free_bytes)) / max(1, size.bytes)))
