"""Step 2: lens distortion and lateral chromatic aberration, as coordinate maps.

The model is :mod:`lfstudio.calibration.lens` (the calibration undistorts its features with the same
one, so the homography is fitted in the coordinate system processing applies it in); this module is
processing's name for it.
"""

from lfstudio.calibration.lens import Coords, LensfunLens, OpenCVLens, green, lens_fingerprint, lens_model, \
    undistort_points

__all__ = ["Coords", "LensfunLens", "OpenCVLens", "green", "lens_fingerprint", "lens_model", "undistort_points"]
