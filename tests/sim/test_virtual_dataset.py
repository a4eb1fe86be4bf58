"""make_virtual_dataset: a real dataset folder with ground truth; the sensor model as configured."""

from __future__ import annotations

import hashlib
import json

import cv2
import numpy as np
import pytest
import rawpy

from lfstudio.dataset import Dataset
from lfstudio.errors import InputError
from lfstudio.sim.sensor import SensorModel
from lfstudio.sim.studio import VirtualStudio
from lfstudio.dataset.grid import grid_order
from lfstudio.sim.virtual_dataset import load_ground_truth, make_virtual_dataset


def test_tiny_dataset_png_is_a_valid_dataset_with_ground_truth(tiny_dataset):
    ds = Dataset.open(tiny_dataset.root)
    assert ds.grid.columns == 5 and ds.grid.rows == 3
    assert len(ds.done_views()) == 15
    v = ds.view(1, 3)
    assert v["file"] == "raw/r01_c003.png"
    assert v["commanded_mm"] == [12.0, 6.0]
    path = ds.path_of(v)
    assert hashlib.sha256(path.read_bytes()).hexdigest() == v["sha256"]
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint16 and img.shape == (426, 640, 3)
    truth = load_ground_truth(ds.root)
    assert ds.focal_length_px(640) == pytest.approx(truth["focal_length_px"])
    assert truth["rotation_deg"] == [1.0, -1.5, 0.7]
    K0, K, R, H = truth["K0"], truth["K_true"], truth["R"], truth["H"]
    H2 = K0 @ R.T @ np.linalg.inv(K)
    np.testing.assert_allclose(H, H2 / H2[2, 2], atol=1e-12)
    assert len(truth["views"]) == 15
    assert {"true_mm", "commanded_mm", "row", "column", "file"} <= set(truth["views"][0])
    depths = [layer["depth_m"] for layer in truth["layers"]]
    assert min(depths) == pytest.approx(1.77) and max(depths) == pytest.approx(4.77)


def test_tiny_dataset_png_matches_the_render(tiny_dataset):
    truth = load_ground_truth(tiny_dataset.root)
    studio = VirtualStudio(width_px=640, rotation_deg=truth["rotation_deg"], pp_offset_px=truth["pp_offset_px"],
                           view_region_mm=truth["view_region_mm"], seed=truth["seed"])
    view = next(v for v in truth["views"] if v["row"] == 2 and v["column"] == 1)
    expected = studio.render(*view["true_mm"])
    img = cv2.imread(str(tiny_dataset.root / view["file"]), cv2.IMREAD_UNCHANGED)
    got = cv2.cvtColor(img, cv2.COLOR_BGR2RGB).astype(np.float32) / 65535.0
    assert np.abs(got - np.clip(expected, 0, 1)).max() < 1e-4


def test_every_view_has_its_grid_thumbnail_made_from_the_render(tiny_dataset):
    from lfstudio.dataset import images

    ds = Dataset.open(tiny_dataset.root)
    for v in ds.views:
        assert v["thumb"] == f"thumbs/r{v['row']:02d}_c{v['column']:03d}.jpg"
        stored = cv2.imread(str(ds.root / v["thumb"]))
        from_file = images.thumbnail_array(ds.path_of(v), 160)   # what the grid would make from the PNG
        assert stored.shape == from_file.shape == (106, 160, 3)
        blocks = [cv2.resize(t, (16, 11), interpolation=cv2.INTER_AREA).astype(int) for t in (stored, from_file)]
        assert np.abs(blocks[0] - blocks[1]).mean() < 4


def test_tiny_dataset_dng_opens_in_rawpy(tiny_dataset_dng):
    v = tiny_dataset_dng.view(0, 0)
    assert v["file"].endswith(".dng")
    with rawpy.imread(str(tiny_dataset_dng.path_of(v))) as raw:
        assert raw.raw_image.shape == (426, 640)
        assert raw.white_level == 16383


def test_position_noise_flicker_and_meander(tmp_path):
    ds = make_virtual_dataset(tmp_path / "d", 4, 2, width_px=96, fmt="png", position_noise_um=(80, 50),
                              flicker=0.05, seed=3)
    truth = json.loads((ds.root / "ground_truth.json").read_text())
    offsets = np.array([np.subtract(v["true_mm"], v["commanded_mm"]) for v in truth["views"]])
    assert np.all(np.abs(offsets) < 0.5) and np.all(np.abs(offsets).max(axis=0) > 0.005)
    gains = [v["gain"] for v in truth["views"]]
    assert len(set(gains)) == len(gains)
    shots = sorted(truth["views"], key=lambda v: v["shot"])
    assert [(v["row"], v["column"]) for v in shots] == grid_order(4, 2, "row-meander")
    assert grid_order(3, 2, "row-meander") == [(0, 0), (0, 1), (0, 2), (1, 2), (1, 1), (1, 0)]


def test_bad_arguments_raise_input_error(tmp_path):
    with pytest.raises(InputError) as info:
        make_virtual_dataset(tmp_path / "x", 2, 2, width_px=64, fmt="tiff")
    assert str(info.value) == "fmt: unknown format 'tiff' (valid: dng or png)"      # not "['dng', 'png']"
    with pytest.raises(InputError, match="even"):
        make_virtual_dataset(tmp_path / "y", 2, 2, width_px=65, fmt="dng")
    # pixels wider than a manifest holds (35.9 mm / 32 px): refused before any view is written
    with pytest.raises(InputError, match=r"width_px: 32 px wide images .*pixel_pitch_um: 1121.88 µm"):
        make_virtual_dataset(tmp_path / "z", 2, 1, width_px=32, fmt="png")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_flicker_is_measurable_as_configured():
    sensor = SensorModel(flicker=0.04, seed=1)
    rgb = np.full((16, 16, 3), 0.4, np.float32)
    gains = []
    for shot in range(200):
        out, gain = sensor.apply(rgb, shot)
        assert float(out.mean()) == pytest.approx(0.4 * gain, rel=1e-5)
        gains.append(float(out.mean()) / 0.4)
    assert np.std(gains) == pytest.approx(0.04, rel=0.2)
    assert sensor.shot_gain(7) == SensorModel(flicker=0.04, seed=1).shot_gain(7)
    assert SensorModel().shot_gain(3) == 1.0


def test_vignetting_is_measurable_as_configured():
    studio = VirtualStudio(width_px=200, view_region_mm=(0, 4, 0, 4), n_layers=0, n_objects=0)
    rgb = studio.render(2.0, 2.0)
    out, _ = SensorModel(vignetting=0.3, noise=0.001, seed=2).apply(rgb, 0)
    ratio = out / np.maximum(rgb, 1e-3)
    h, w = ratio.shape[:2]
    centre = float(np.median(ratio[h // 2 - 3:h // 2 + 3, w // 2 - 3:w // 2 + 3]))
    corner = float(np.median(ratio[:4, :4]))
    assert centre == pytest.approx(1.0, abs=0.02)
    assert corner / centre == pytest.approx(0.7, abs=0.03)


def test_noise_level_is_as_configured():
    rgb = np.full((64, 64, 3), 0.25, np.float32)
    sensor = SensorModel(noise=0.002, full_well_e=20000, seed=0)
    out, _ = sensor.apply(rgb, 0)
    expected = np.sqrt(0.25 * 20000 + (0.002 * 20000) ** 2) / 20000
    assert float(out.std()) == pytest.approx(expected, rel=0.05)
    again, _ = sensor.apply(rgb, 0)
    assert np.array_equal(out, again)


def test_two_processes_render_the_same_files_as_one(tmp_path):
    kw = dict(width_px=64, fmt="dng", rotation_deg=(0.5, 0.2, 0.1), noise=0.002, seed=5)
    one = make_virtual_dataset(tmp_path / "one", 2, 2, **kw)
    two = make_virtual_dataset(tmp_path / "two", 2, 2, workers=2, **kw)
    assert [v["sha256"] for v in one.views] == [v["sha256"] for v in two.views]


def test_only_some_views_of_a_grid_are_rendered_each_as_in_the_whole_grid(tmp_path):
    from lfstudio.dataset.grid import Grid

    whole = make_virtual_dataset(tmp_path / "whole", 5, 3, width_px=96, fmt="png", seed=4, position_noise_um=(80, 50))
    chosen = Grid(5, 3).select("array:2ex2", Grid(5, 3).views())
    part = make_virtual_dataset(tmp_path / "part", 5, 3, width_px=96, fmt="png", seed=4, position_noise_um=(80, 50),
                                only_views=chosen)
    assert part.grid.columns == 5 and part.grid.rows == 3
    assert sorted(part.captured_views()) == sorted(chosen) == [(0, 0), (0, 4), (2, 0), (2, 4)]
    for v in chosen:      # the same position error and image as in the whole grid
        a = cv2.imread(str(whole.path_of(whole.view(*v))), cv2.IMREAD_UNCHANGED)
        b = cv2.imread(str(part.path_of(part.view(*v))), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(a, b)
    with pytest.raises(InputError, match="only_views"):
        make_virtual_dataset(tmp_path / "none", 5, 3, width_px=96, fmt="png", only_views=[(7, 7)])


def test_every_rendered_view_has_its_ground_truth_depth_and_disparity(tiny_dataset):
    """truth/depth, truth/depth_rectified (m) and truth/disparity_rectified (px between horizontal
    neighbours) per view; checked against the scene's own geometry, not against the same code path."""
    from lfstudio.sim.virtual_dataset import TRUTH_MAPS, read_truth_map, truth_map_path

    truth = load_ground_truth(tiny_dataset.root)
    assert set(truth["truth_maps"]) >= set(TRUTH_MAPS)
    layer_depths = sorted({layer["depth_m"] for layer in truth["layers"]})
    f_px = truth["focal_length_px"]
    for view in truth["views"]:
        for kind in TRUTH_MAPS:
            assert truth_map_path(tiny_dataset.root, kind, view["row"], view["column"]).is_file()
    view = next(v for v in truth["views"] if v["row"] == 1 and v["column"] == 2)
    depth = read_truth_map(tiny_dataset.root, "depth", 1, 2)
    rect = read_truth_map(tiny_dataset.root, "depth_rectified", 1, 2)
    disp = read_truth_map(tiny_dataset.root, "disparity_rectified", 1, 2)
    assert depth.shape == rect.shape == disp.shape == (426, 640)
    # every pixel lies on one of the scene's layers; the near objects and the background are seen
    assert np.isin(np.round(np.unique(rect), 4), np.round(np.array(layer_depths, np.float32), 4)).all()
    assert rect.min() == pytest.approx(min(layer_depths), rel=1e-5) and rect.max() == pytest.approx(4.77, rel=1e-5)
    np.testing.assert_allclose(disp, f_px * 4.0 / (1000.0 * rect), rtol=1e-6)
    # a world point on the nearest object, projected into the captured and the rectified view, lands
    # where the two maps give its depth
    K0, K, R = truth["K0"], truth["K_true"], truth["R"]
    near = min(truth["layers"], key=lambda layer: layer["depth_m"])
    X = np.array([np.mean(near["x_range_m"]), np.mean(near["y_range_m"]), near["depth_m"]])
    C = np.array([view["true_mm"][0] / 1000.0, view["true_mm"][1] / 1000.0, 0.0])
    for K_, R_, m in ((K, R, depth), (K0, np.eye(3), rect)):
        p = K_ @ R_ @ (X - C)
        u, v = int(round(p[0] / p[2])), int(round(p[1] / p[2]))
        assert m[v, u] == pytest.approx(near["depth_m"], rel=1e-5)
    # the captured view's map differs from the rectified one (the camera is rotated)
    assert (depth != rect).mean() > 0.001


def test_truth_maps_can_be_left_out(tmp_path):
    from lfstudio.sim.virtual_dataset import TRUTH_DIR

    make_virtual_dataset(tmp_path / "d", 2, 1, width_px=64, fmt="png", truth_maps=False)
    assert not (tmp_path / "d" / TRUTH_DIR).exists()
    assert load_ground_truth(tmp_path / "d")["truth_maps"] is None
