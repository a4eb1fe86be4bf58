import numpy as np

from lfstudio.calibration.features import FeatureCache, detect, epipole_ransac, match_pair, match_pairs
from lfstudio.calibration.model import apply_homography, rectifying_homography
from tests.calibration.synthetic import LayeredScene, make_layered_dataset

ROT = (1.0, -1.5, 2.0)


def _views(tmp_path, centres, size=(640, 427), f=900.0):
    import cv2
    scene = LayeredScene(seed=4)
    paths = []
    for k, c in enumerate(centres):
        p = tmp_path / f"v{k}.png"
        cv2.imwrite(str(p), scene.render(c, ROT, f, size))
        paths.append(p)
    return paths


def test_matches_of_a_horizontal_pair_line_up_after_the_true_rectification(tmp_path):
    a, b = _views(tmp_path, [(0.0, 0.0, 0.0), (0.1, 0.0, 0.0)])
    fa, fb = detect(a, None), detect(b, None)
    assert fa.count > 100 and fa.image_size_px == (640, 427)
    m = match_pair(fa, fb, "h")
    assert m.inliers > 50 and m.candidates >= m.inliers
    H = rectifying_homography(ROT, 900.0, (640, 427))
    dv = apply_homography(H, m.xy_a)[:, 1] - apply_homography(H, m.xy_b)[:, 1]
    du = apply_homography(H, m.xy_a)[:, 0] - apply_homography(H, m.xy_b)[:, 0]
    assert np.median(np.abs(dv)) < 0.3                 # rows line up
    assert np.all(du > -1.0)                           # scene moves left when the camera moves right


def test_downscaled_detection_keeps_full_resolution_coordinates(tmp_path):
    (a,) = _views(tmp_path, [(0.0, 0.0, 0.0)], size=(1200, 800), f=1700.0)
    full, small = detect(a, None), detect(a, 600)
    assert small.image_size_px == (1200, 800) and abs(small.scale - 2.0) < 1e-9
    assert small.xy[:, 0].max() > 900                  # scaled back up
    # each coarse keypoint has a fine one nearby (same image, same coordinates)
    d = np.min(np.linalg.norm(small.xy[:200, None, :] - full.xy[None, :, :], axis=2), axis=1)
    assert np.median(d) < 1.5


def test_epipole_ransac_rejects_wrong_matches():
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 1000, (300, 2))
    b = a + np.column_stack([-rng.uniform(5, 60, 300), 0.02 * (a[:, 0] - 500) * 0.05])   # one epipole far right
    wrong = rng.choice(300, 90, replace=False)
    b[wrong] = rng.uniform(0, 1000, (90, 2))
    mask, e = epipole_ransac(a, b, "h", threshold_px=1.0)
    good = np.setdiff1d(np.arange(300), wrong)
    assert mask[good].mean() > 0.97
    assert mask[wrong].mean() < 0.1


def test_feature_cache_is_reused_and_invalidated(tmp_path):
    ds = make_layered_dataset(tmp_path / "ds", columns=2, rows=1, size_px=(480, 320))
    cache = FeatureCache(ds.root, 400)
    v = ds.views[0]
    f1, cached1 = cache.get("r00_c000", ds.path_of(v))
    f2, cached2 = cache.get("r00_c000", ds.path_of(v))
    assert not cached1 and cached2 and np.array_equal(f1.xy, f2.xy)
    assert (ds.root / "cache" / "features" / "r00_c000.npz").is_file()
    import os
    st = os.stat(ds.path_of(v))
    os.utime(ds.path_of(v), ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    _, cached3 = cache.get("r00_c000", ds.path_of(v))
    assert not cached3


def test_matching_many_pairs_on_threads_gives_each_pair_s_own_result(tmp_path):
    paths = _views(tmp_path, [(0.0, 0.0, 0.0), (0.1, 0.0, 0.0), (0.2, 0.0, 0.0), (0.0, 0.06, 0.0)])
    feats = {k: detect(p, None) for k, p in enumerate(paths)}
    pairs = [(0, 1, "h"), (1, 2, "h"), (0, 2, "h"), (0, 3, "v")]
    done = []
    many = match_pairs(feats, pairs, threads=2, on_done=lambda i, r: done.append(i))
    assert sorted(done) == [0, 1, 2, 3]
    for (a, b, d), m in zip(pairs, many):
        one = match_pair(feats[a], feats[b], d)
        assert m.candidates == one.candidates and np.array_equal(m.xy_a, one.xy_a) and m.inliers > 30
        assert m.epipole is not None and np.linalg.norm(m.epipole) > 0


def test_repeated_keypoints_do_not_make_a_null_epipole():
    # SIFT repeats a keypoint with a second orientation: two identical matches span no epipole
    rng = np.random.default_rng(2)
    a = rng.uniform(0, 1000, (60, 2))
    b = a + np.column_stack([-rng.uniform(5, 60, 60), np.zeros(60)])
    b[30:] = rng.uniform(0, 1000, (30, 2))                      # half of them wrong
    a = np.vstack([a, a[:1]]).repeat(1, axis=0)
    b = np.vstack([b, b[:1]])
    mask, e = epipole_ransac(np.repeat(a, 2, axis=0), np.repeat(b, 2, axis=0), "h", threshold_px=1.0)
    assert np.linalg.norm(e) > 0 and mask.reshape(-1, 2)[30:60].mean() < 0.2
