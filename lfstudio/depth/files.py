"""The files of depth and points: PFM (disparity, confidence), float32 TIFF (depth in metres),
16-bit PNG (depth in millimetres), binary PLY (a coloured point cloud). Not atomic by themselves:
callers write into a temporary folder or through :func:`lfstudio.dataset.atomic.atomic_write_with`.

- **PFM** (Portable Float Map, as the HCI benchmark stores disparities): header ``Pf`` (one
  channel), ``W H``, the scale (negative: little-endian), then rows **bottom to top**, float32.
  :func:`read_pfm` returns the image top row first.
- **Depth TIFF**: float32, metres, NaN where unknown (deflate-compressed).
- **Depth PNG**: uint16 millimetres, 0 where unknown or beyond 65.535 m (nerfstudio's
  ``depth_file_path`` default: ``depth_unit_scale_factor`` 1e-3).
- **PLY**: ``binary_little_endian 1.0``, vertex x y z (float32) red green blue (uchar).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from lfstudio.errors import DatasetError


def write_pfm(path: str | os.PathLike, image: np.ndarray) -> None:
    """One-channel float32 PFM (little-endian, rows bottom to top)."""
    data = np.asarray(image, dtype="<f4")
    if data.ndim != 2:
        raise ValueError(f"a PFM here holds one channel, got shape {data.shape}")
    h, w = data.shape
    with open(path, "wb") as fh:
        fh.write(f"Pf\n{w} {h}\n-1.0\n".encode("ascii"))
        fh.write(np.ascontiguousarray(data[::-1]).tobytes())


def read_pfm(path: str | os.PathLike) -> np.ndarray:
    """A PFM as float32, top row first (one channel ``Pf`` or three ``PF``)."""
    path = Path(path)
    with open(path, "rb") as fh:
        try:
            kind = fh.readline().strip()
            w, h = (int(v) for v in fh.readline().split())
            scale = float(fh.readline().strip())
        except ValueError:
            raise DatasetError(f"{path}: not a PFM file (bad header)") from None
        if kind not in (b"Pf", b"PF"):
            raise DatasetError(f"{path}: not a PFM file (starts with {kind[:8]!r})")
        channels = 3 if kind == b"PF" else 1
        data = np.frombuffer(fh.read(), dtype="<f4" if scale < 0 else ">f4")
    if data.size != w * h * channels:
        raise DatasetError(f"{path}: PFM holds {data.size} values, its header says {w} x {h} x {channels}")
    shape = (h, w, channels) if channels == 3 else (h, w)
    return np.ascontiguousarray(data.reshape(shape)[::-1]).astype(np.float32)


def write_depth_tiff(path: str | os.PathLike, depth_m: np.ndarray) -> None:
    import tifffile

    tifffile.imwrite(path, np.asarray(depth_m, np.float32), compression="zlib")


def read_depth_tiff(path: str | os.PathLike) -> np.ndarray:
    import tifffile

    return np.asarray(tifffile.imread(path), np.float32)


def depth_png_mm(depth_m: np.ndarray) -> np.ndarray:
    """uint16 millimetres (0: unknown or farther than 65.535 m)."""
    d = np.asarray(depth_m, np.float64) * 1000.0
    ok = np.isfinite(d) & (d > 0) & (d <= 65535.0)
    return np.where(ok, np.rint(np.where(ok, d, 0.0)), 0).astype(np.uint16)


def write_depth_png(path: str | os.PathLike, depth_m: np.ndarray) -> None:
    import cv2

    if not cv2.imwrite(str(path), depth_png_mm(depth_m)):
        raise OSError(f"{path}: cannot write the PNG (disk full or folder not writable?)")


def write_ply(path: str | os.PathLike, xyz: np.ndarray, rgb: np.ndarray) -> None:
    """Binary little-endian PLY of coloured points (x y z float32, red green blue uchar)."""
    xyz = np.asarray(xyz, np.float64).reshape(-1, 3)
    rgb = np.asarray(rgb, np.uint8).reshape(-1, 3)
    if len(xyz) != len(rgb):
        raise ValueError(f"{len(xyz)} points but {len(rgb)} colours")
    vertex = np.empty(len(xyz), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                      ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    vertex["x"], vertex["y"], vertex["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    vertex["red"], vertex["green"], vertex["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    header = ("ply\nformat binary_little_endian 1.0\ncomment written by lfstudio\n"
              f"element vertex {len(xyz)}\nproperty float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(vertex.tobytes())


def read_ply(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """(xyz float32 (N, 3), rgb uint8 (N, 3)) of a PLY written by :func:`write_ply`."""
    path = Path(path)
    raw = path.read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply\n") or end < 0:
        raise DatasetError(f"{path}: not a PLY file")
    header = raw[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in header:
        raise DatasetError(f"{path}: only binary little-endian PLY is read here")
    n = next(int(line.split()[2]) for line in header if line.startswith("element vertex"))
    dtype = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    v = np.frombuffer(raw[end + len(b"end_header\n"):], dtype=dtype, count=n)
    return (np.column_stack([v["x"], v["y"], v["z"]]).astype(np.float32),
            np.column_stack([v["red"], v["green"], v["blue"]]).astype(np.uint8))
