"""What the simulated sensor and lighting do to a rendered image: global flicker, vignetting, noise.

* **Flicker**: the whole image is multiplied by a gain ``1 + flicker * N(0, 1)`` drawn per shot
  (seeded by the shot number, so a dataset is reproducible).
* **Vignetting**: a radial falloff ``1 - vignetting * (r / r_corner)^2`` around the image centre;
  the corners receive ``1 - vignetting`` of the centre's light.
* **Noise**: shot noise for a full well of ``full_well_e`` electrons plus Gaussian read noise of
  ``noise`` (fraction of the clipping level, e.g. 0.002); ``noise = 0`` disables both.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np


@dataclass(frozen=True)
class SensorModel:
    flicker: float = 0.0
    vignetting: float = 0.0
    noise: float = 0.0
    full_well_e: float = 30000.0
    seed: int = 0

    def shot_gain(self, shot: int) -> float:
        """The global illumination gain of shot number ``shot`` (deterministic)."""
        if self.flicker <= 0:
            return 1.0
        rng = np.random.default_rng([self.seed, 0x5F11C4E5, int(shot)])
        return float(max(0.05, 1.0 + self.flicker * rng.standard_normal()))

    def vignetting_map(self, height_px: int, width_px: int) -> np.ndarray | None:
        """H x W float32 falloff (1 at the centre, ``1 - vignetting`` in the corners) or None."""
        if self.vignetting <= 0:
            return None
        return _vignetting_map(float(self.vignetting), int(height_px), int(width_px))

    def apply(self, rgb: np.ndarray, shot: int) -> tuple[np.ndarray, float]:
        """Return (the image as the sensor records it, float32 linear, 1 = clipping; the shot's gain).

        ``rgb`` is not modified.
        """
        gain = self.shot_gain(shot)
        out = rgb * np.float32(gain)
        vig = self.vignetting_map(*rgb.shape[:2])
        if vig is not None:
            out *= vig[..., None]
        if self.noise > 0:
            rng = np.random.default_rng([self.seed, 0x0015E, int(shot)])
            fw = np.float32(self.full_well_e)
            # sigma = sqrt(signal_e + read_e^2) / full_well, in place to stay fast on large frames
            sigma = np.maximum(out, 0)
            sigma *= fw
            sigma += np.float32((self.noise * self.full_well_e) ** 2)
            np.sqrt(sigma, out=sigma)
            sigma *= rng.standard_normal(out.shape, dtype=np.float32)
            sigma /= fw
            out += sigma
        return out, gain


@lru_cache(maxsize=4)
def _vignetting_map(vignetting: float, height_px: int, width_px: int) -> np.ndarray:
    y = (np.arange(height_px, dtype=np.float32) - (height_px - 1) / 2)[:, None]
    x = (np.arange(width_px, dtype=np.float32) - (width_px - 1) / 2)[None, :]
    r2 = (x * x + y * y) / np.float32(((width_px - 1) / 2) ** 2 + ((height_px - 1) / 2) ** 2)
    vig = (1.0 - vignetting * r2).astype(np.float32)
    vig.setflags(write=False)
    return vig
