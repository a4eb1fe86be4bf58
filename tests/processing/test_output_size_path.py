"""Demosaicing at the output's resolution (demosaic ``auto``), reused buffers and the PNG strategy.

The mosaic read by :func:`lfstudio.dataset.images.read_bayer` must carry LibRaw's own numbers (compared with
LibRaw's output), the split path must be at least as close to the virtual studio's ground truth as
LibRaw's AHD, and reusing work arrays from view to view must never leak one view into another.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import rawpy

from lfstudio.processing import worker
from lfstudio.processing.pipeline import make_plan, process_dataset
from lfstudio.dataset.profile import DebayerStep, Profile
from lfstudio.dataset import images
from lfstudio.processing.steps import debayer
from lfstudio.sim.dng import mosaic_from_rgb, write_dng
from lfstudio.sim.studio import VirtualStudio
from lfstudio.sim.virtual_dataset import load_ground_truth
from tests.processing.conftest import scene


def libraw_half(path, step: DebayerStep) -> np.ndarray:
    """LibRaw's own 2 x 2-block output (no demosaic) for ``step``'s white balance and colour space."""
    kw = dict(gamma=(1, 1), no_auto_bright=True, output_bps=16, adjust_maximum_thr=0.0, half_size=True,
              output_color=rawpy.ColorSpace.raw if step.color_space == "raw" else rawpy.ColorSpace.sRGB)
    if step.white_balance == "camera":
        kw["use_camera_wb"] = True
    elif step.white_balance == "fixed":
        kw["user_wb"] = list(step.wb_multipliers)
    with rawpy.imread(str(path)) as raw:
        return raw.postprocess(**kw).astype(np.float64)


def half_from(bayer: images.Bayer) -> np.ndarray:
    m = bayer.mosaic.astype(np.float64)
    greens = [divmod(i, 2) for i, c in enumerate(bayer.pattern) if c == "G"]
    (ry, rx), (by, bx) = bayer.site("R"), bayer.site("B")
    g = (m[greens[0][0]::2, greens[0][1]::2] + m[greens[1][0]::2, greens[1][1]::2]) / 2
    return np.clip(np.dstack([m[ry::2, rx::2], g, m[by::2, bx::2]]) @ bayer.rgb_cam.T, 0, 65535)


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
@pytest.mark.parametrize("step", [DebayerStep(), DebayerStep(color_space="raw"),
                                  DebayerStep(white_balance="fixed", wb_multipliers=[1.8, 1.0, 1.4, 1.0])],
                         ids=["camera-srgb", "camera-raw", "fixed"])
def test_mosaic_carries_libraws_levels_for_every_pattern(tmp_path, pattern, step):
    rgb = scene(64, 48, seed=1) * 1.6          # some pixels clip: saturation must match too
    path = tmp_path / "v.dng"
    write_dng(path, mosaic_from_rgb(rgb, pattern=pattern), pattern=pattern)
    bayer = images.read_bayer(path, step)
    assert bayer is not None and bayer.pattern == pattern and bayer.mosaic.dtype == np.uint16
    mine, theirs = half_from(bayer), libraw_half(path, step)
    assert mine.shape == theirs.shape
    assert np.abs(mine - theirs).max() <= 4       # LibRaw truncates where we round: a few 1/65535
    assert theirs.max() > 60000                   # the clipped pixels were in the comparison


def test_mosaic_buffer_is_reused_and_other_files_fall_back(tmp_path):
    path = tmp_path / "v.dng"
    write_dng(path, mosaic_from_rgb(scene(64, 48)))
    buf = np.empty((48, 64), np.uint16)
    assert images.read_bayer(path, DebayerStep(), out=buf).mosaic is buf
    cv2.imwrite(str(tmp_path / "v.png"), np.zeros((4, 4, 3), np.uint16))
    assert images.read_bayer(tmp_path / "v.png", DebayerStep()) is None   # LibRaw-free images: decode()


@pytest.mark.parametrize("orientation", [3, 6, 8])
def test_rotated_captures_keep_their_colours_and_orientation(tmp_path, orientation):
    rgb = scene(64, 48, seed=4)
    path = tmp_path / "v.dng"
    write_dng(path, mosaic_from_rgb(rgb), orientation=orientation)
    bayer = images.read_bayer(path, DebayerStep())
    full = debayer.output_rgb(debayer.demosaic_ea(bayer), bayer.rgb_cam).astype(np.float64)
    libraw = images.develop(path, DebayerStep(demosaic="AHD")).astype(np.float64)
    turned = orientation in (6, 8)
    assert full.shape == libraw.shape and full.shape[:2] == (rgb.shape[1::-1] if turned else rgb.shape[:2])
    inner = (slice(3, -3), slice(3, -3))
    assert np.abs(full[inner] - libraw[inner]).mean() < 0.01 * libraw.mean()
    np.testing.assert_allclose(half_from(bayer), libraw_half(path, DebayerStep()), atol=4)


def _psnr(out: np.ndarray, truth: np.ndarray) -> float:
    return float(10 * np.log10(65535.0 ** 2 / np.mean((out.astype(np.float64) - truth) ** 2)))


def test_output_size_path_is_as_close_to_the_truth_as_ahd(make_tiny_dataset):
    ds = make_tiny_dataset("dng", noise=0.002, vignetting=0.2)
    truth = load_ground_truth(ds.root)
    (ds.root / "calibration.json").write_text(json.dumps(
        {"homography": truth["H"].tolist(), "image_size_px": truth["image_size_px"]}))
    studio = VirtualStudio(width_px=truth["image_size_px"][0], rotation_deg=tuple(truth["rotation_deg"]),
                           pp_offset_px=tuple(truth["pp_offset_px"]), view_region_mm=tuple(truth["view_region_mm"]),
                           seed=truth["seed"], near_m=truth["near_m"], far_m=truth["far_m"])
    scores = {}
    for demosaic in ("auto", "AHD"):
        profile = Profile()
        profile.color.enabled = False               # linear output, comparable with the ideal rendering
        profile.deflicker.enabled = False
        profile.shading.enabled = True
        profile.shading.mode = "model"
        profile.shading.coefficients = [-0.2]
        profile.debayer.demosaic = demosaic
        assert make_plan(ds, profile).split_demosaic is (demosaic == "auto")
        report = process_dataset(ds.root, profile, workers=0, force=True)
        assert report.ok
        psnr = []
        for v in truth["views"][:4]:
            out = cv2.cvtColor(cv2.imread(str(ds.root / f"processed/r{v['row']:02d}_c{v['column']:03d}.png"),
                                          cv2.IMREAD_UNCHANGED), cv2.COLOR_BGR2RGB)
            h, w = out.shape[:2]
            ideal = cv2.resize(studio.render(*v["true_mm"], ideal=True), (w, h), interpolation=cv2.INTER_AREA)
            inner = (slice(h // 10, -h // 10), slice(w // 10, -w // 10))
            psnr.append(_psnr(out[inner], ideal[inner].astype(np.float64) * 65535))
        scores[demosaic] = float(np.mean(psnr))
    assert scores["AHD"] > 28
    assert scores["auto"] >= scores["AHD"] - 0.1, scores


def _two_view_dataset(make_dataset, **kw):
    ds = make_dataset(rows=1, cols=3, w=96, h=64, gains={(0, 1): 0.6, (0, 2): 1.2},
                      H=[[1.0, 0.01, 1.5], [-0.01, 1.0, -1.0], [0.0, 0.0, 1.0]], **kw)
    return ds


def test_buffers_are_reused_and_never_leak_one_view_into_the_next(make_dataset):
    ds = _two_view_dataset(make_dataset)
    profile = Profile()
    plan = make_plan(ds, profile)
    assert plan.split_demosaic
    worker._CACHE.clear()
    a_path, b_path = ds.path_of(ds.view(0, 1)), ds.path_of(ds.view(0, 2))
    first, _ = worker.render(plan, a_path)
    first = first.copy()
    buffers = worker.prepare(plan).buffers
    n_buffers = len(buffers)
    other, _ = worker.render(plan, b_path)
    assert not np.array_equal(other, first)              # different view, different pixels
    again, _ = worker.render(plan, a_path)
    assert np.shares_memory(again, other)                 # the same output buffer, reused...
    np.testing.assert_array_equal(again, first)           # ...with nothing of the other view left in it
    assert len(buffers) == n_buffers                      # no new arrays for the same sizes
    worker._CACHE.clear()                                 # a fresh process: fresh buffers, same result
    fresh, _ = worker.render(plan, a_path)
    np.testing.assert_array_equal(fresh, first)


@pytest.mark.parametrize("changes", [
    {"lens__enabled": True, "lens__source": "opencv", "lens__fx_px": 120.0, "lens__dist_coeffs": [-0.1, 0, 0, 0, 0],
     "lens__tca_red_scale": 1.002, "lens__tca_blue_scale": 0.998},
    {"rectify__enabled": False},
], ids=["lens-with-lateral-ca", "nothing-to-warp"])
def test_output_size_path_agrees_with_ahd_with_lens_maps_and_without_warp(make_dataset, changes):
    ds = _two_view_dataset(make_dataset)
    outs = {}
    for demosaic in ("auto", "AHD"):
        profile = Profile()
        profile.debayer.demosaic = demosaic
        for key, value in changes.items():
            step, _, name = key.partition("__")
            setattr(getattr(profile, step), name, value)
        assert process_dataset(ds.root, profile, workers=0, force=True).ok
        outs[demosaic] = cv2.imread(str(ds.root / "processed/r00_c001.png"), cv2.IMREAD_UNCHANGED)
    inner = (slice(5, -5), slice(5, -5))
    assert _psnr(outs["auto"][inner], outs["AHD"][inner].astype(np.float64)) > 33


def test_png_strategy_follows_what_compresses(tmp_path):
    rng = np.random.default_rng(0)   # a photograph: smooth structure and sensor noise in the low bits
    noisy = (scene(96, 64) * 60000 + rng.normal(0, 150, (64, 96, 3))).clip(0, 65535).astype(np.uint16)
    flat = np.zeros((64, 96, 3), np.uint16)
    flat[:, 48:] = 40000
    assert worker.choose_png_strategy(noisy, 1) == "huffman"
    assert worker.choose_png_strategy(flat, 1) == "deflate"
    assert worker.choose_png_strategy(noisy, 0) == "deflate"     # level 0 stores: nothing faster
    for img in (noisy, flat):
        for strategy in ("huffman", "deflate"):
            ok, data = cv2.imencode(".png", img, worker.png_params(1, strategy))
            np.testing.assert_array_equal(cv2.imdecode(data, cv2.IMREAD_UNCHANGED), img)   # lossless
    p = Profile()
    q = p.copy()
    q.output.png_strategy = "huffman"
    assert p.sha256() == q.sha256()      # same pixels: finished views stay finished
