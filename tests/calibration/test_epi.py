import numpy as np

from lfstudio.calibration.epi import consecutive, dataset_epis, horizontal_epi, rectify_image, vertical_epi
from lfstudio.calibration.model import rectifying_homography
from tests.calibration.synthetic import LayeredScene, make_layered_dataset

ROT = (1.0, -1.0, 3.0)
SIZE, F = (480, 320), 660.0


def _corr(a, b):
    a, b = a.astype(float).ravel(), b.astype(float).ravel()
    a, b = a - a.mean(), b - b.mean()
    return float(a @ b / np.linalg.norm(a) / np.linalg.norm(b))


def test_rectified_epis_match_the_ideal_rigs_epis():
    scene = LayeredScene(seed=5, texels=700)
    xs = [0.01 * k for k in range(8)]
    captured = [scene.render((x, 0, 0), ROT, F, SIZE) for x in xs]
    ideal = [scene.render((x, 0, 0), (0, 0, 0), F, SIZE) for x in xs]
    H = rectifying_homography(ROT, F, SIZE)
    ident = [np.eye(3)] * len(xs)
    truth = horizontal_epi(ideal, ident, 160)
    after = horizontal_epi(captured, [H] * len(xs), 160)
    before = horizontal_epi(captured, ident, 160)
    inner = slice(60, 420)       # away from the borders the rotation uncovers
    assert _corr(after[:, inner], truth[:, inner]) > 0.97
    assert _corr(before[:, inner], truth[:, inner]) < _corr(after[:, inner], truth[:, inner]) - 0.1
    assert vertical_epi(captured[:3], ident[:3], 100).shape == (320, 3)
    full = rectify_image(captured[0], H)
    assert _corr(full[80:240, 80:400], ideal[0][80:240, 80:400]) > 0.97


def test_dataset_epis_before_and_after(tmp_path):
    ds = make_layered_dataset(tmp_path / "ds", columns=6, rows=3, spacing_mm=(15, 15), size_px=(320, 214),
                              rotation_deg=ROT)
    H = rectifying_homography(ROT, ds.focal_length_px(320), (320, 214))
    e = dataset_epis(ds, {"homography": H.tolist()}, row=1, column=2, width_px=320)
    assert e["horizontal"]["before"].shape == (6, 320) and e["horizontal"]["after"].shape == (6, 320)
    assert e["vertical"]["before"].shape == (214, 3) and e["vertical"]["views"] == [(0, 2), (1, 2), (2, 2)]
    none = dataset_epis(ds, None, row=0, column=0, width_px=160)
    assert none["horizontal"]["after"] is None and none["horizontal"]["before"].shape == (6, 160)
    assert consecutive(range(101), 50, 4) == [48, 49, 50, 51] and consecutive([0, 1], 50, 4) == [0, 1]
