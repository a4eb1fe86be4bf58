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


def test_colour_bar_labels_never_overlap_and_always_name_both_ends():
    from lfstudio.quality.pictures import _text_width_px, colour_bar_labels

    for width_px in (160, 320, 640, 1400):
        for scale in (None, 2.67):
            ticks = colour_bar_labels(0.5, 2.5, width_px - 40, width_px, scale)
            texts = [lines[0][0] for _, lines in ticks]
            assert texts[0] == "0.50 px" and texts[-1] == "2.50 px", (width_px, texts)
            spans = sorted((min(left for _, left in lines),
                            max(left + _text_width_px(t) for t, left in lines)) for _, lines in ticks)
            assert all(a[1] <= b[0] for a, b in zip(spans, spans[1:])), (width_px, scale, spans)
            assert all(0 <= s[0] and s[1] <= width_px for s in spans), (width_px, spans)
            if scale:
                assert ticks[0][1][1][0] == f"{scale / 0.5:.2f} m"
    # a wide picture has room for all five
    assert len(colour_bar_labels(0.5, 2.5, 1360, 1400, 2.67)) == 5


def test_the_disparity_picture_keeps_its_size_with_depth_labels():
    from lfstudio.quality.pictures import disparity_picture

    d = np.linspace(0.5, 2.5, 200 * 300).reshape(200, 300)
    grey = np.full((200, 300), 128, np.uint8)
    plain = disparity_picture(d, grey)
    with_depth = disparity_picture(d, grey, "depth = 2.67 m px / disparity", depth_scale_m_px=2.67)
    assert plain.shape[1] == with_depth.shape[1] == 300
    assert with_depth.shape[0] > plain.shape[0] > 200


def test_the_colour_bar_s_ticks_stay_clear_of_their_labels():
    """The ticks touched the labels' digits and, shown at half size (the Disparity window, the HTML
    report), ran through them (issue 41 item 8): a band of at least 5 white rows separates them."""
    from lfstudio.quality.pictures import disparity_picture

    d = np.linspace(-1.0, 4.0, 200 * 600).reshape(200, 600)
    grey = np.full((200, 600), 128, np.uint8)
    for scale in (None, 2.67):
        pic = disparity_picture(d, grey, depth_scale_m_px=scale)
        under = pic[200 + 23:].min(axis=2) < 160            # dark pixels under the colour bar (it ends at 22)
        ticks = sorted({int(x) for x in np.flatnonzero(under[0])})          # the first row: ticks only
        assert len(ticks) >= 5
        off_ticks = under.copy()
        off_ticks[:, ticks] = False
        label_top = int(np.flatnonzero(off_ticks.any(axis=1))[0])          # a label's first row of ink
        tick_end = int(np.flatnonzero(under[:, ticks].any(axis=1) & ~off_ticks.any(axis=1))[-1]) \
            if label_top else 0
        tick_rows = [r for r in range(label_top) if under[r, ticks].any()]
        assert label_top - max(tick_rows) - 1 >= 5, (scale, tick_rows, label_top, tick_end)   # 2 px at half size


def _pair_with_disparities(top_px: int, bottom_px: int) -> tuple[np.ndarray, np.ndarray]:
    """A textured left image and its right partner: a point at x in the left view is at x − d in the
    right one, d = ``top_px`` in the upper half and ``bottom_px`` in the lower half."""
    import cv2

    rng = np.random.default_rng(3)
    left = cv2.GaussianBlur(rng.integers(0, 256, (160, 320)).astype(np.uint8), (3, 3), 0)
    right = np.empty_like(left)
    for rows, d in ((slice(0, 80), top_px), (slice(80, 160), bottom_px)):
        right[rows] = np.roll(left[rows], -d, axis=1)
    return left, right


def test_sheared_views_of_an_unstated_shear_are_searched_over_their_signed_range():
    """Issue 27: behind the zero plane of sheared views the disparities are negative; the matcher
    searched only 0 … max, so those pixels were lost (or matched wrongly)."""
    from lfstudio.quality.disparity import search_range, sgbm

    left, right = _pair_with_disparities(6, -5)
    inner = (slice(None), slice(40, 280))
    signed = sgbm(left, right, 6.0, -5.0)
    top, bottom = signed[10:70][inner], signed[90:150][inner]
    assert np.isfinite(top).mean() > 0.8 and np.isfinite(bottom).mean() > 0.8
    assert np.nanmedian(top) == 6.0 and np.nanmedian(bottom) == -5.0
    positive_only = sgbm(left, right, 6.0)           # what an unsigned search finds behind the plane
    assert not np.any(np.abs(positive_only[90:150][inner] + 5.0) < 0.5)
    first, n = search_range(-5.0, 6.0)
    assert first <= -5 and first + n - 1 >= 6 and n % 16 == 0
    assert search_range(0.0, 6.0)[0] == 0 and search_range(2.0, 6.0)[0] == 0
