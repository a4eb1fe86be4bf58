"""The light-field depth method (issue 37) on a small synthetic light field whose disparities are
known: a textured background plane behind a textured foreground square, rendered into a 5 x 5 grid
of sheared views (negative and positive disparities, occlusions at the square's edges). The centre,
an edge and a corner view are recovered alike; memory is bounded by strips."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from lfstudio.depth import dense

D_BACK, D_FRONT = -0.8, 1.6
SIZE = (120, 96)            # w, h
SQUARE = (38, 28, 84, 70)   # x0, y0, x1, y1 in the reference frame


def _texture(seed: int, w: int, h: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.2)
    t = (t - t.min()) / (t.max() - t.min())
    return (0.15 + 0.7 * t).astype(np.float32)


def _view(r: int, c: int) -> tuple[np.ndarray, np.ndarray]:
    """(grey image, true disparity) of the view at grid position (r, c): a layer of disparity d is
    seen at (x − d·c, y − d·r) of its own frame."""
    w, h = SIZE
    back = _texture(1, w + 40, h + 40)
    front = _texture(2, w + 40, h + 40)
    mask = np.zeros((h + 40, w + 40), np.float32)
    x0, y0, x1, y1 = SQUARE
    mask[y0 + 20:y1 + 20, x0 + 20:x1 + 20] = 1.0

    def sample(img, d):
        M = np.array([[1.0, 0.0, 20 + d * (c - 2)], [0.0, 1.0, 20 + d * (r - 2)]])
        return cv2.warpAffine(img, M, (w, h), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_REFLECT)

    alpha = sample(mask, D_FRONT)
    img = alpha * sample(front, D_FRONT) + (1 - alpha) * sample(back, D_BACK)
    truth = np.where(alpha > 0.5, D_FRONT, D_BACK).astype(np.float32)
    return img.astype(np.float32), truth


def _neighbours(r: int, c: int, radius: int = 2) -> list[dense.Neighbour]:
    out = []
    for dr in range(-radius, radius + 1):
        for dc in range(-radius, radius + 1):
            if (dr, dc) == (0, 0) or not (dr == 0 or dc == 0 or abs(dr) == abs(dc)):
                continue
            if 0 <= r + dr < 5 and 0 <= c + dc < 5:
                out.append(dense.Neighbour(_view(r + dr, c + dc)[0], float(dc), float(dr)))
    return out


def _bad(disp: np.ndarray, truth: np.ndarray, t: float = 0.1, m: int = 6) -> float:
    e = np.abs(np.nan_to_num(disp, nan=1e9) - truth)[m:-m, m:-m]
    return float((e > t).mean())


@pytest.mark.parametrize("view", [(2, 2), (2, 0), (0, 0), (4, 3)])
def test_known_disparities_are_recovered_in_the_centre_and_at_the_edges(view):
    ref, truth = _view(*view)
    res = dense.light_field_disparity(ref, _neighbours(*view), -1.2, 2.0)
    d = res.disparity_px
    assert np.isfinite(d).all()                                  # an edge view is never left NaN
    assert _bad(d, truth) < 0.04, _bad(d, truth)
    inner = (slice(6, -6), slice(6, -6))
    err = np.abs(d - truth)[inner]
    assert np.median(err) < 0.04, np.median(err)
    # not clamped at the range's ends, nor shifted
    assert (np.abs(d[inner] - (-1.2)) < 0.05).mean() < 0.01 and (np.abs(d[inner] - 2.0) < 0.05).mean() < 0.01
    assert abs(np.median((d - truth)[inner])) < 0.04      # under half a candidate step
    # the confidence means something: the sure half is right more often than the unsure half
    c = res.confidence[inner]
    sure = c > np.median(c)
    assert (err[sure] > 0.1).mean() <= (err[~sure] > 0.1).mean()


def test_the_strips_give_the_same_map_as_one_volume():
    ref, truth = _view(2, 2)
    nbs = _neighbours(2, 2)
    whole = dense.light_field_disparity(ref, nbs, -1.2, 2.0, volume_cells=10**9)
    strips = dense.light_field_disparity(ref, nbs, -1.2, 2.0, volume_cells=120 * 90 * 20)   # a few rows at a time
    agree = np.abs(whole.disparity_px - strips.disparity_px) < 0.05
    assert agree.mean() > 0.97, agree.mean()
    assert _bad(strips.disparity_px, truth) < 0.04


def test_the_cost_of_a_pixel_hidden_from_one_side_comes_from_the_other():
    """Background just left of the square is hidden from the views to its right at the background's
    disparity: the left half-plane still sees it, so it keeps the background's disparity."""
    ref, truth = _view(2, 2)
    res = dense.light_field_disparity(ref, _neighbours(2, 2), -1.2, 2.0)
    x0, y0, x1, y1 = SQUARE
    strip = (slice(y0 + 6, y1 - 6), slice(x0 - 7, x0 - 2))        # a band of background beside the square
    assert np.all(truth[strip] == D_BACK)
    assert (np.abs(res.disparity_px[strip] - D_BACK) < 0.1).mean() > 0.9


def test_the_neighbourhood_is_two_dimensional_and_uses_recorded_positions(tiny_dataset):
    """A view's neighbours: its row, its column and the diagonals, one-sided at the grid's edge; the
    offsets come from the positions the rig recorded when the dataset has them."""
    from lfstudio.dataset import Dataset
    from lfstudio.depth.run import DepthSettings, neighbours_of

    ds = tiny_dataset                                   # 5 x 3, spacing 4 x 6 mm
    captured = set(ds.captured_views())
    corner = {(int(v[0]), int(v[1])): (dx, dy) for v, dx, dy in neighbours_of(ds, (0, 0), DepthSettings(), captured)}
    assert set(corner) == {(0, 1), (0, 2), (0, 3), (0, 4), (1, 0), (2, 0), (1, 1), (2, 2)}
    assert corner[(1, 1)] == pytest.approx((1.0, 1.5)) and corner[(0, 4)] == pytest.approx((4.0, 0.0))
    ds.manifest.setdefault("import", {})["positions"] = {"source": "test"}
    for v in ds.manifest["views"]:
        v["reported_mm"] = [v["column"] * 4.0 + (0.2 if (v["row"], v["column"]) == (1, 1) else 0.0), v["row"] * 6.0]
    ds.save()
    ds = Dataset.open(ds.root)
    moved = {(int(v[0]), int(v[1])): (dx, dy) for v, dx, dy in neighbours_of(ds, (0, 0), DepthSettings(), captured)}
    assert moved[(1, 1)] == pytest.approx((1.05, 1.5)) and moved[(0, 4)] == pytest.approx((4.0, 0.0))


def _slot_view(r: int, c: int, slot: tuple[int, int] = (46, 49), d_near: float = 0.6,
               d_far: float = -1.4) -> tuple[np.ndarray, np.ndarray]:
    """A near plane with a horizontal slot (rows ``slot`` of the reference, 3 px) through which a far
    plane is seen (HCI backgammon's thin gaps): (grey image, true disparity) of view (r, c)."""
    w, h = SIZE
    back = _texture(3, w + 40, h + 40)
    front = _texture(4, w + 40, h + 40)
    mask = np.ones((h + 40, w + 40), np.float32)
    mask[slot[0] + 20:slot[1] + 20] = 0.0

    def sample(img, d):
        M = np.array([[1.0, 0.0, 20 + d * (c - 2)], [0.0, 1.0, 20 + d * (r - 2)]])
        return cv2.warpAffine(img, M, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_REFLECT)

    alpha = sample(mask, d_near)
    img = alpha * sample(front, d_near) + (1 - alpha) * sample(back, d_far)
    return img.astype(np.float32), np.where(alpha > 0.5, d_near, d_far).astype(np.float32)


def test_a_thin_gap_along_a_row_keeps_the_far_disparity():
    """A 3 px slot in a near plane: the views above and below (and the diagonals) see the near plane
    there at the far disparity, only the reference's row sees through it; the row's line of views
    gives the far surface (a half-plane mixes in the diagonals and filled the slot with the near)."""
    ref, truth = _slot_view(2, 2)
    nbs = [dense.Neighbour(_slot_view(2 + dr, 2 + dc)[0], float(dc), float(dr))
           for dr in range(-2, 3) for dc in range(-2, 3)
           if (dr, dc) != (0, 0) and (dr == 0 or dc == 0 or abs(dr) == abs(dc))]
    res = dense.light_field_disparity(ref, nbs, -1.8, 1.0)
    slot = (slice(46, 49), slice(10, -10))
    assert np.all(truth[slot] == -1.4)
    near_far = np.abs(res.disparity_px[slot] + 1.4) < 0.3
    assert near_far.mean() > 0.95, near_far.mean()
    assert _bad(res.disparity_px, truth) < 0.06, _bad(res.disparity_px, truth)


def test_recorded_positions_a_little_off_the_grid_keep_a_view_on_its_row():
    """Recorded (or measured) positions miss the grid by the rig's repeatability: a view of the
    reference's row recorded 0.02 spacings (80 µm of 4 mm) above or below it still belongs to the
    row's line of views, which alone sees through the slot (before, any vertical offset moved it into
    the upper or lower half-plane and the slot was filled with the near plane)."""
    ref, truth = _slot_view(2, 2)
    off = {-2: 0.02, -1: -0.015, 1: 0.02, 2: -0.02}         # the row's views, recorded a little off it
    nbs = [dense.Neighbour(_slot_view(2 + dr, 2 + dc)[0], float(dc) + 0.01 * dr,
                           float(dr) + (off[dc] if dr == 0 else 0.0))
           for dr in range(-2, 3) for dc in range(-2, 3)
           if (dr, dc) != (0, 0) and (dr == 0 or dc == 0 or abs(dr) == abs(dc))]
    res = dense.light_field_disparity(ref, nbs, -1.8, 1.0)
    slot = (slice(46, 49), slice(10, -10))
    near_far = np.abs(res.disparity_px[slot] + 1.4) < 0.3
    assert near_far.mean() > 0.95, near_far.mean()


def test_a_pixel_at_a_depth_edge_takes_the_surface_whose_colour_it_has():
    """A silhouette's anti-aliased pixels mostly showing the background match the nearer surface (they
    move with its edge) but look like the background: at depth edges each pixel takes the surface of
    the nearest-coloured pixel around it."""
    h, w = 20, 30
    rng = np.random.default_rng(5)
    colour = rng.uniform(-0.05, 0.05, (h, w, 3)).astype(np.float32)          # texture
    colour[:, :15] += (0.9, 0.9, 0.85)                  # a white statue left, a dark wall right
    colour[:, 15:] += (0.1, 0.15, 0.1)
    rim = [4, 12]
    colour[rim, 15] = 0.3 * colour[rim, 14] + 0.7 * colour[rim, 16]          # anti-aliased: mostly wall
    disp = np.where(np.arange(w)[None, :] < 15, 2.0, -1.0).astype(np.float32) * np.ones((h, 1), np.float32)
    wrong = disp.copy()
    wrong[rim, 15] = 2.0                                 # those given the statue's disparity
    wrong[8, 14] = -1.0                                  # and a statue pixel given the wall's
    assert np.array_equal(dense.colour_edges(wrong, colour), disp)
    # grey views work too (one channel); a map of another size is refused
    assert np.array_equal(dense.colour_edges(wrong, colour.mean(axis=2)), disp)
    with pytest.raises(ValueError):
        dense.colour_edges(wrong, colour[:10])


def test_the_disparities_of_a_slanted_surface_are_smoothed_along_it_and_steps_kept():
    """The sub-pixel fits' noise is averaged over a plane fitted to the pixel's neighbours on its own
    surface (within 0.05 px): a slanted surface comes out unbiased and less noisy, a step of 0.5 px
    stays sharp, NaN stays NaN."""
    rng = np.random.default_rng(7)
    h, w = 40, 60
    yy, xx = np.indices((h, w)).astype(np.float32)
    truth = 0.3 + 0.004 * xx - 0.003 * yy                 # a slanted surface
    truth[:, 30:] += 0.5                                 # a step
    noisy = (truth + rng.normal(0, 0.01, truth.shape)).astype(np.float32)
    noisy[5, 5] = np.nan
    out = dense.fit_planes(noisy)
    inner = (slice(3, -3), np.r_[3:27, 33:57])
    before = np.sqrt(np.nanmean((noisy - truth)[inner] ** 2))
    after = np.sqrt(np.nanmean((out - truth)[inner] ** 2))
    assert after < 0.5 * before, (before, after)
    assert abs(np.nanmean((out - truth)[inner])) < 0.002            # no bias on the slope
    assert np.all(np.abs(out - truth)[3:-3, 27:33] < 0.05)          # the step's sides stay apart
    assert np.isnan(out[5, 5]) and np.isfinite(out[5, 6])
