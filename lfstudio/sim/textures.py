"""Procedural textures for the virtual studio: deterministic for a random generator, with fine
detail (down to ~2 texture pixels), colour, text-like strokes and checker patches.

All images are float32 linear RGB in [0, 1] (H x W x 3) or masks in [0, 1] (H x W).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

_LETTERS = "ABCDEFGHJKLMNPQRSTUVWXYZabcdefghkmnopqrstuvwxyz0123456789"
_FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX,
          cv2.FONT_HERSHEY_TRIPLEX, cv2.FONT_HERSHEY_SCRIPT_SIMPLEX)


def fractal_noise(rng: np.random.Generator, height: int, width: int, *, base_cells: float = 3.0,
                  persistence: float = 0.62, finest_px: float = 2.0) -> np.ndarray:
    """Sum of octaves of bicubically upsampled Gaussian noise, normalised to [0, 1].

    The coarsest octave has ``base_cells`` cells across the longer side; each octave doubles it
    until a cell is ``finest_px`` pixels.
    """
    height, width = int(height), int(width)
    longest = max(height, width)
    out = np.zeros((height, width), np.float32)
    amp = 1.0
    cells = float(base_cells)
    while True:
        gw = max(2, int(math.ceil(cells * width / longest)) + 1)
        gh = max(2, int(math.ceil(cells * height / longest)) + 1)
        grid = rng.standard_normal((gh, gw)).astype(np.float32)
        out += amp * cv2.resize(grid, (width, height), interpolation=cv2.INTER_CUBIC)
        amp *= persistence
        if longest / cells <= finest_px * 2:
            break
        cells *= 2.0
    lo, hi = np.percentile(out[:: max(1, height // 256), :: max(1, width // 256)], (0.5, 99.5))
    out -= lo
    out *= 1.0 / max(float(hi - lo), 1e-6)
    np.clip(out, 0.0, 1.0, out=out)
    return out


def random_colour(rng: np.random.Generator, saturation: float = 0.7) -> np.ndarray:
    """A random linear RGB colour with moderate brightness."""
    hue = rng.random()
    h6 = hue * 6.0
    c = np.clip(np.array([abs(h6 - 3) - 1, 2 - abs(h6 - 2), 2 - abs(h6 - 4)]), 0, 1)
    value = rng.uniform(0.25, 0.85)
    rgb = value * ((1 - saturation) + saturation * c)
    return (rgb ** 2.2).astype(np.float32)      # perceptual -> linear


def colour_field(rng: np.random.Generator, height: int, width: int, n_colours: int = 4,
                 base_cells: float = 3.0) -> np.ndarray:
    """Regions of random colours blending into each other, modulated by fine luminance noise."""
    sh, sw = max(2, height // 4), max(2, width // 4)       # the colour regions are smooth: work small
    weights = np.stack([fractal_noise(rng, sh, sw, base_cells=base_cells, finest_px=2.0)
                        for _ in range(n_colours)], axis=-1)
    weights = np.exp((weights - weights.max(axis=-1, keepdims=True)) * 12.0)
    weights /= weights.sum(axis=-1, keepdims=True)
    colours = np.stack([random_colour(rng, rng.uniform(0.3, 0.9)) for _ in range(n_colours)])
    small = (weights.reshape(-1, n_colours) @ colours).reshape(sh, sw, 3).astype(np.float32)
    rgb = cv2.resize(small, (width, height), interpolation=cv2.INTER_LINEAR)
    detail = fractal_noise(rng, height, width, base_cells=base_cells * 4, persistence=0.8)
    rgb *= (0.45 + 1.0 * detail)[..., None]
    return rgb


def draw_text_strokes(rng: np.random.Generator, rgb: np.ndarray, count: int, *, min_height_px: float = 6.0,
                      max_height_px: float = 40.0) -> None:
    """Draw ``count`` random words (Hershey fonts, various sizes, dark or bright) into ``rgb`` in place."""
    h, w = rgb.shape[:2]
    for _ in range(count):
        word = "".join(rng.choice(list(_LETTERS), size=int(rng.integers(3, 10))))
        height_px = float(np.exp(rng.uniform(np.log(min_height_px), np.log(max_height_px))))
        scale = height_px / 22.0
        thickness = max(1, int(round(height_px / 12.0 * rng.uniform(0.6, 1.6))))
        font = int(rng.choice(_FONTS))
        org = (int(rng.integers(-w // 20, w)), int(rng.integers(0, h + int(height_px))))
        colour = np.clip(random_colour(rng, 0.5) * (0.15 if rng.random() < 0.6 else 1.6), 0, 0.95)
        (tw, th), base = cv2.getTextSize(word, font, scale, thickness)
        pad = thickness + 2
        bx0, by0 = org[0] - pad, org[1] - th - pad
        mask = np.zeros((th + base + 2 * pad, tw + 2 * pad), np.uint8)
        cv2.putText(mask, word, (pad, th + pad), font, scale, 255, thickness, cv2.LINE_AA)
        _blend_patch(rgb, mask, bx0, by0, colour)


def _blend_patch(rgb: np.ndarray, mask: np.ndarray, x0: int, y0: int, colour: np.ndarray) -> None:
    """rgb[y0:, x0:] = mix(rgb, colour, mask / 255) over the mask's extent, clipped to the image."""
    h, w = rgb.shape[:2]
    mh, mw = mask.shape
    ax0, ay0, ax1, ay1 = max(0, x0), max(0, y0), min(w, x0 + mw), min(h, y0 + mh)
    if ax1 <= ax0 or ay1 <= ay0:
        return
    m = mask[ay0 - y0:ay1 - y0, ax0 - x0:ax1 - x0].astype(np.float32)[..., None] * (1.0 / 255.0)
    roi = rgb[ay0:ay1, ax0:ax1]
    roi *= 1.0 - m
    roi += m * colour.astype(np.float32)


def draw_checkers(rng: np.random.Generator, rgb: np.ndarray, count: int, *, min_cell_px: int = 2,
                  max_cell_px: int = 14) -> None:
    """Paste ``count`` small checkerboard patches of random cell size and colours into ``rgb``."""
    h, w = rgb.shape[:2]
    for _ in range(count):
        cell = int(rng.integers(min_cell_px, max_cell_px + 1))
        nx, ny = int(rng.integers(3, 12)), int(rng.integers(3, 12))
        pw, ph = min(w, nx * cell), min(h, ny * cell)
        x0, y0 = int(rng.integers(0, max(1, w - pw))), int(rng.integers(0, max(1, h - ph)))
        yy, xx = np.mgrid[0:ph, 0:pw]
        board = ((yy // cell + xx // cell) % 2).astype(bool)
        a, b = random_colour(rng, 0.4) * 0.25, np.clip(random_colour(rng, 0.4) * 1.5, 0, 0.9)
        rgb[y0:y0 + ph, x0:x0 + pw] = np.where(board[..., None], a, b)


def draw_scribbles(rng: np.random.Generator, rgb: np.ndarray, count: int) -> None:
    """Random-walk polylines (twigs, cracks, hand-writing-like strokes), anti-aliased."""
    h, w = rgb.shape[:2]
    for _ in range(count):
        n = int(rng.integers(5, 40))
        start = np.array([rng.uniform(0, w), rng.uniform(0, h)])
        step = rng.uniform(3, max(4.0, min(h, w) / 25))
        angles = np.cumsum(rng.normal(0, 0.6, n)) + rng.uniform(0, 2 * np.pi)
        pts = start + np.cumsum(np.stack([np.cos(angles), np.sin(angles)], -1) * step, axis=0)
        colour = np.clip(random_colour(rng, 0.6) * (0.2 if rng.random() < 0.5 else 1.4), 0, 0.95)
        thickness = int(rng.integers(1, 4))
        ipts = np.round(pts).astype(np.int32)
        x0, y0 = ipts.min(axis=0) - thickness - 1
        x1, y1 = ipts.max(axis=0) + thickness + 2
        mask = np.zeros((int(y1 - y0), int(x1 - x0)), np.uint8)
        cv2.polylines(mask, [ipts - [x0, y0]], False, 255, thickness, cv2.LINE_AA)
        _blend_patch(rgb, mask, int(x0), int(y0), colour)


def detailed_texture(rng: np.random.Generator, height: int, width: int, *, text: bool = True) -> np.ndarray:
    """A rich texture: colour regions, fine noise, words, checker patches and scribbles."""
    rgb = colour_field(rng, height, width, n_colours=int(rng.integers(3, 6)))
    area = height * width
    if text:
        draw_text_strokes(rng, rgb, max(2, int(area / 30000)))
    draw_checkers(rng, rgb, max(1, int(area / 150000)))
    draw_scribbles(rng, rgb, max(2, int(area / 40000)))
    np.clip(rgb, 0.0, 0.95, out=rgb)
    return rgb


def blob_mask(rng: np.random.Generator, height: int, width: int, coverage: float = 0.5,
              base_cells: float = 4.0) -> np.ndarray:
    """Foliage-like mask: thresholded low-frequency noise (blobs with holes), anti-aliased edges."""
    n = fractal_noise(rng, height, width, base_cells=base_cells, persistence=0.55, finest_px=3.0)
    thr = float(np.quantile(n[:: max(1, height // 200), :: max(1, width // 200)], 1.0 - coverage))
    edge = 0.02
    return np.clip((n - thr) / edge + 0.5, 0.0, 1.0).astype(np.float32)


def shape_mask(height: int, width: int, kind: str, rng: np.random.Generator | None = None) -> np.ndarray:
    """An anti-aliased mask filling the canvas: "disc", "rounded", "frame" (panel with windows)."""
    mask = np.zeros((height, width), np.uint8)
    if kind == "disc":
        cv2.ellipse(mask, (width // 2, height // 2), (max(1, width // 2 - 2), max(1, height // 2 - 2)),
                    0, 0, 360, 255, -1, cv2.LINE_AA)
    elif kind == "rounded":
        r = max(2, min(height, width) // 6)
        cv2.rectangle(mask, (r, 1), (width - 1 - r, height - 2), 255, -1, cv2.LINE_AA)
        cv2.rectangle(mask, (1, r), (width - 2, height - 1 - r), 255, -1, cv2.LINE_AA)
        for cx, cy in ((r, r), (width - 1 - r, r), (r, height - 1 - r), (width - 1 - r, height - 1 - r)):
            cv2.circle(mask, (cx, cy), r - 1, 255, -1, cv2.LINE_AA)
    elif kind == "frame":
        mask[1:-1, 1:-1] = 255
        rng = rng or np.random.default_rng(0)
        nx, ny = int(rng.integers(2, 4)), int(rng.integers(1, 3))
        bw, bh = width / (nx * 2 + 1), height / (ny * 2 + 1)
        for i in range(nx):
            for j in range(ny):
                x0, y0 = int((2 * i + 1) * bw), int((2 * j + 1) * bh)
                mask[y0:int(y0 + bh), x0:int(x0 + bw)] = 0
    else:
        raise ValueError(f"unknown shape kind {kind!r}")
    return mask.astype(np.float32) / 255.0
