"""Thumbnails of view files: made small before they are measured, JPEGs and RAW previews decoded at
reduced size, generated thumbnails cached in the dataset and replaced when the capture changes."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from lfstudio.dataset import Dataset
from lfstudio.dataset import images, thumbs
from lfstudio.sim.dng import mosaic_from_rgb, write_dng


def _scene(w: int, h: int) -> np.ndarray:
    """Linear RGB: a red left half, a blue right half, a grey band at the bottom."""
    img = np.zeros((h, w, 3), np.float32)
    img[:, : w // 2] = (0.6, 0.05, 0.05)
    img[:, w // 2:] = (0.05, 0.05, 0.6)
    img[-h // 4:] = 0.3
    return img


def test_16bit_image_is_scaled_on_its_small_version(tmp_path):
    img = (_scene(1200, 800) * 4000).astype(np.uint16)      # a dark linear 16-bit capture
    img[0, 0] = 65535                                       # one hot pixel must not set the scale
    cv2.imwrite(str(tmp_path / "v.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    t = images.thumbnail_array(tmp_path / "v.png", 160)
    assert t.shape == (107, 160, 3) and t.dtype == np.uint8
    left, right = t[20:60, 10:70].reshape(-1, 3).mean(axis=0), t[20:60, 90:150].reshape(-1, 3).mean(axis=0)
    assert left[2] > 200 and left[0] < 40                  # red (BGR), scaled up to near full range
    assert right[0] > 200 and right[2] < 40                # blue


_FILTERS = {"none": cv2.IMWRITE_PNG_FILTER_NONE, "sub": cv2.IMWRITE_PNG_FILTER_SUB, "up": cv2.IMWRITE_PNG_FILTER_UP,
            "mixed": cv2.IMWRITE_PNG_FILTER_NONE | cv2.IMWRITE_PNG_FILTER_SUB | cv2.IMWRITE_PNG_FILTER_UP}


@pytest.mark.parametrize("filters", sorted(_FILTERS))
@pytest.mark.parametrize("depth, channels", [(16, 3), (8, 3), (16, 1), (8, 4)])
def test_png_pixels_inflated_in_one_call_match_libpng(tmp_path, filters, depth, channels):
    """The fast PNG path (libdeflate + numpy unfiltering) gives libpng's pixels, for PNGs libpng
    itself wrote with each filter choice."""
    rng = np.random.default_rng(depth * 10 + channels)
    img = cv2.GaussianBlur((rng.random((67, 91, 3)) * 65535).astype(np.uint16), (5, 5), 2)
    if depth == 8:
        img = (img >> 8).astype(np.uint8)
    img = {1: img[..., 0], 3: img, 4: np.dstack([img, img[..., :1]])}[channels]
    path = tmp_path / "v.png"
    assert cv2.imwrite(str(path), np.ascontiguousarray(img), [cv2.IMWRITE_PNG_FILTER, _FILTERS[filters]])
    got = images._png_small(path, 1000)               # full size: every row, compared pixel for pixel
    want = cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
    assert got is not None and got.dtype == want.dtype and got.shape == want.shape
    assert np.array_equal(got, want)
    small = images._png_small(path, 30)               # thumbnail size: a subset of the rows
    ref = cv2.resize(want, (30, small.shape[0]), interpolation=cv2.INTER_AREA).astype(float)
    assert small.shape == (round(67 * 30 / 91), 30, 3)
    assert np.abs(small - ref).mean() < 0.03 * float(want.max())


def test_paeth_filtered_png_and_a_damaged_one_are_left_to_libpng(tmp_path):
    img = (_scene(300, 200) * 40000).astype(np.uint16)
    paeth = tmp_path / "paeth.png"
    cv2.imwrite(str(paeth), img, [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_PAETH])
    assert images._png_small(paeth, 160) is None
    assert images.thumbnail_array(paeth, 160).shape == (107, 160, 3)      # OpenCV decodes it
    cut = tmp_path / "cut.png"
    cv2.imwrite(str(cut), img, [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB])
    cut.write_bytes(cut.read_bytes()[: cut.stat().st_size // 2])
    assert images._png_small(cut, 160) is None


@pytest.mark.parametrize("width_px", [1600, 900, 500])
def test_jpeg_is_decoded_at_the_smallest_size_still_wide_enough(tmp_path, width_px):
    rgb8 = (_scene(width_px, width_px * 2 // 3) * 400).clip(0, 255).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "v.jpg"), cv2.cvtColor(rgb8, cv2.COLOR_RGB2BGR))
    t = images.thumbnail_array(tmp_path / "v.jpg", 160)
    full = cv2.resize(cv2.imread(str(tmp_path / "v.jpg")), (160, t.shape[0]), interpolation=cv2.INTER_AREA)
    assert t.shape == full.shape
    assert np.abs(t.astype(int) - full).mean() < 3


def test_raw_thumbnail_from_the_mosaic_keeps_the_colours(tmp_path):
    path = tmp_path / "v.dng"
    write_dng(path, mosaic_from_rgb(_scene(1000, 666)))
    t = images.thumbnail_array(path, 160)
    assert t.shape[1] <= 160 and t.shape[1] >= 80
    h, w = t.shape[:2]
    left, right = t[h // 8: h // 2, w // 8: w // 3].reshape(-1, 3).mean(axis=0), \
        t[h // 8: h // 2, 2 * w // 3: -w // 8].reshape(-1, 3).mean(axis=0)
    assert left[2] > 2 * left[0] and right[0] > 2 * right[2]


def _dataset(tmp_path, n=4, stored_thumb_for=()):
    ds = Dataset.create(tmp_path / "ds", camera={"name": "c"}, lens={"name": "l"},
                        grid={"columns": n, "rows": 1, "spacing_mm": [4.0, 6.0]})
    for v in ds.views:
        rel = ds.raw_name(0, v["column"], ".png")
        img = (_scene(400, 300) * (20000 + 5000 * v["column"])).astype(np.uint16)
        cv2.imwrite(str(ds.root / rel), img)
        v.update(file=rel, status="done")
        if v["column"] in stored_thumb_for:
            v["thumb"] = f"thumbs/r00_c{v['column']:03d}.jpg"
    ds.save()
    return ds


def test_generated_thumbnail_is_cached_in_the_dataset_and_renewed_when_the_capture_changes(tmp_path):
    ds = _dataset(tmp_path, n=1)
    path = ds.path_of(ds.view(0, 0))
    first = thumbs.cached_thumbnail(path, 160)
    cached, prefix = thumbs.cache_path(ds.root, path, 160)
    assert cached.is_file() and cached.parent == ds.root / "thumbs" / "generated"
    # the next request reads the cache, not the capture: show that with a marked cache file
    cv2.imwrite(str(cached), np.full_like(first, (0, 255, 0)))
    again = thumbs.cached_thumbnail(path, 160)
    assert again[..., 1].mean() > 240 and again[..., 0].mean() < 15
    # smaller requests are the cached thumbnail made smaller
    assert thumbs.cached_thumbnail(path, 48).shape[1] == 48
    # a re-captured view (new content, new size and time) gets a new thumbnail; the stale one goes
    cv2.imwrite(str(path), (_scene(600, 400) * 30000).astype(np.uint16))
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    renewed = thumbs.cached_thumbnail(path, 160)
    assert renewed[..., 1].mean() < 100                  # the capture's colours, not the marked cache
    new_cached, _ = thumbs.cache_path(ds.root, path, 160)
    assert new_cached != cached and new_cached.is_file() and not cached.exists()
    assert [p.name for p in new_cached.parent.iterdir()] == [new_cached.name]


def test_a_thumbnail_left_by_an_earlier_session_for_a_changed_capture_goes(tmp_path):
    ds = _dataset(tmp_path, n=2)
    thumbs.CacheFiller(ds.root, 160, workers=1).wait()              # an earlier session cached both
    folder = ds.root / "thumbs" / "generated"
    before = {p.name for p in folder.iterdir()}
    path = ds.path_of(ds.view(0, 1))
    cv2.imwrite(str(path), (_scene(600, 400) * 20000).astype(np.uint16))  # then view 1 was re-captured
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    thumbs.CacheFiller(ds.root, 160, workers=1).wait()              # this session
    after = {p.name for p in folder.iterdir()}
    assert len(after) == 2 and len(after & before) == 1             # view 0 kept, view 1 renewed
    assert thumbs.cache_path(ds.root, path, 160)[0].name in after - before


def test_cache_filler_makes_every_missing_thumbnail_and_a_read_only_place_still_shows_them(tmp_path):
    ds = _dataset(tmp_path, n=5, stored_thumb_for=(3,))
    filler = thumbs.CacheFiller(ds.root, 160, workers=2)
    filler.wait()
    made = sorted(p.name.split(".")[0] for p in (ds.root / "thumbs" / "generated").iterdir())
    assert made == ["raw~r00_c000", "raw~r00_c001", "raw~r00_c002", "raw~r00_c004"]   # not the stored one
    for c in (0, 4):
        assert filler.get(ds.path_of(ds.view(0, c))).shape == (120, 160, 3)
    # nowhere to write (the cache folder's place is taken by a file): thumbnails all the same
    ro = _dataset(tmp_path / "ro", n=1)
    (ro.root / "thumbs").rmdir()
    (ro.root / "thumbs").write_text("not a folder")
    img = thumbs.CacheFiller(ro.root, 160, workers=1).get(ro.path_of(ro.view(0, 0)))
    assert img is not None and img.shape == (120, 160, 3)


def test_a_request_for_another_dataset_stops_the_previous_filler(tmp_path):
    a, b = _dataset(tmp_path / "a", n=3), _dataset(tmp_path / "b", n=3)
    thumbs.cached_thumbnail(a.path_of(a.view(0, 0)))
    filler_a = thumbs._filler
    thumbs.cached_thumbnail(b.path_of(b.view(0, 0)))
    assert thumbs._filler is not filler_a and thumbs._filler.root == b.root
    assert filler_a._cancelled
    thumbs._filler.wait()
    assert len(list((b.root / "thumbs" / "generated").iterdir())) == 3
