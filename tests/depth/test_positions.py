"""The neighbours' offsets measured from the images (lfstudio.depth.positions): the rank-one model
of feature displacements, its scale pinned to the rig's offsets, the rig's repeatability as prior."""

from __future__ import annotations

import numpy as np

from lfstudio.depth import positions


def _scene(true_offsets: np.ndarray, n_features: int = 400, noise_px: float = 0.04, seed: int = 3):
    """Keypoints of a reference and of each neighbour: x_n = x_ref − D_i · o_n (+ noise), with
    unique random descriptors per feature."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 800, (n_features, 2))
    d = rng.uniform(1.0, 3.0, n_features)                       # px per horizontal spacing
    desc = rng.uniform(0, 1, (n_features, 128)).astype(np.float32)
    nbs = []
    for o in true_offsets:
        nxy = xy - d[:, None] * o[None, :] + rng.normal(0, noise_px, (n_features, 2))
        nbs.append((nxy, desc.copy()))
    return xy, desc, nbs


def test_offsets_off_the_grid_are_measured_and_their_scale_pinned_to_the_grid():
    grid = np.array([(dc, dr * 1.5) for dr in (-1, 0, 1) for dc in (-1, 1, 2, 3)] + [(0, -1.5), (0, 1.5)], float)
    rng = np.random.default_rng(1)
    error = rng.normal(0, 0.02, grid.shape)                     # the rig's 80 µm of 4 mm
    error -= error.mean(axis=0)
    truth = grid + error + np.array([0.015, -0.01])             # and the reference's own miss
    xy, desc, nbs = _scene(truth)
    got = positions.measure_offsets(xy, desc, nbs, grid, positions.prior_sigma_spacings((80, 50), 4.0))
    assert got.measured.all() and got.matches > 1000
    before = np.sqrt(((grid - truth) ** 2).mean())
    after = np.sqrt(((got.offsets - truth) ** 2).mean())
    assert before > 0.015 and after < 0.003, (before, after)
    # the prior decides where nothing needs measuring: 80 µm of an HCI folder's 100 mm spacing
    assert positions.worth_measuring(positions.prior_sigma_spacings((80, 50), 4.0))
    assert not positions.worth_measuring(positions.prior_sigma_spacings((80, 50), 100.0))


def test_a_precise_rig_keeps_its_offsets_and_too_few_matches_keep_the_grid():
    grid = np.array([(-1, 0), (1, 0), (2, 0), (0, 1)], float)
    truth = grid + np.array([[0.02, 0.0], [-0.02, 0.01], [0.0, 0.0], [0.01, -0.02]])
    xy, desc, nbs = _scene(truth)
    # a rig repeatable to 1e-6 spacings: the measurement barely moves its offsets
    got = positions.measure_offsets(xy, desc, nbs, grid, (1e-6, 1e-6))
    assert np.abs(got.offsets - grid).max() < 1e-4
    # five features: nothing measured, the grid kept
    xy, desc, nbs = _scene(truth, n_features=5)
    got = positions.measure_offsets(xy, desc, nbs, grid, (0.03, 0.03))
    assert not got.measured.any() and np.array_equal(got.offsets, grid)


def test_a_dataset_measures_its_offsets_only_where_its_positions_are_uncertain(calibrated):
    """The reference gantry (80 × 50 µm of a 4 mm spacing) measures; a rig stated repeatable to
    1 µm does not, nor an HCI folder (views rendered exactly where its format states)."""
    from lfstudio.dataset.grid import View
    from lfstudio.depth.run import DepthSettings, offset_measurement, plan_tasks

    ds = calibrated
    geo, tasks = plan_tasks(ds, [View(1, 2)], DepthSettings())
    assert tasks[0]["offsets"]["prior_sigma"][0] > positions.MEASURE_ABOVE_SPACINGS
    ds.manifest.setdefault("rig", {})["repeatability_um"] = 1.0
    assert offset_measurement(ds, geo) is None
    ds.manifest["rig"].pop("repeatability_um")
    ds.manifest["import"] = {"hci": {"grid": [9, 9]}}
    assert offset_measurement(ds, geo) is None


def test_a_neighbour_whose_matches_contradict_the_rig_keeps_the_rigs_offset():
    """Matches that put a neighbour 0.65 spacings from where a rig repeatable to 80 µm can stand (a
    repeated texture matched one period off, seen at 320 px) are not believed: that neighbour keeps
    the rig's offset and does not pin the others' scale (it made the scale 0.1 spacings wrong)."""
    grid = np.array([(dc, dr * 1.5) for dr in (-1, 0, 1) for dc in (-2, -1, 1, 2, 3)], float)
    rng = np.random.default_rng(4)
    truth = grid + rng.normal(0, 0.02, grid.shape)
    seen = truth.copy()
    seen[8] = (2.35, 0.0)                                        # the grid says 3: what its matches say
    xy, desc, nbs = _scene(seen)
    got = positions.measure_offsets(xy, desc, nbs, grid, positions.prior_sigma_spacings((80, 50), 4.0))
    assert not got.measured[8] and np.array_equal(got.offsets[8], grid[8])
    others = np.arange(len(grid)) != 8
    assert got.measured[others].all()
    before = np.sqrt(((grid[others] - truth[others]) ** 2).mean())
    after = np.sqrt(((got.offsets[others] - truth[others]) ** 2).mean())
    assert after < 0.5 * before, (before, after)
