"""Helpers of the disparity map."""

from __future__ import annotations

import numpy as np

from lfstudio.quality.disparity import nan_median, partner_cells, steps_for


def test_nan_median_matches_numpy():
    rng = np.random.default_rng(0)
    stack = rng.normal(size=(4, 30, 40)).astype(np.float32)
    stack[rng.random(stack.shape) < 0.4] = np.nan
    stack[:, 0, 0] = np.nan
    got = nan_median(stack)
    with np.errstate(all="ignore"):
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            want = np.nanmedian(stack, axis=0)
    np.testing.assert_allclose(got, want, equal_nan=True, rtol=1e-6)
    assert np.isnan(got[0, 0])


def test_partners_are_the_farthest_available_within_the_steps():
    available = {(r, c) for r in range(5) for c in range(9)} - {(2, 8)}
    parts = partner_cells((2, 4), available, 9, 5, 4, 2)
    assert parts == [((2, 7), "right", 3), ((2, 0), "left", 4), ((4, 4), "down", 2), ((0, 4), "up", 2)]
    assert steps_for(3.0) == 4 and steps_for(10.0) == 3 and steps_for(100.0) == 1 and steps_for(0.0) == 1
