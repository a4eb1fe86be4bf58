"""The bracket merge on a real bracketed scan of the virtual studio with a highlight that clips at
the middle exposure (the simulated camera writes real DNGs; LibRaw develops them): the merged
radiance matches the rendered truth where the middle exposure clips, the clipped share drops, the
files are real OpenEXR / float TIFF, and the frames of a still rig line up."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from lfstudio.dataset import Dataset
from lfstudio.dataset.bracket import parse_bracket
from lfstudio.dataset.profile import Profile
from lfstudio.processing.hdr import MergeOptions, merge_dataset, merge_frames, read_radiance
from lfstudio.rig.profile import load_rig
from lfstudio.scan.engine import ScanEngine
from lfstudio.scan.events import ScanState
from lfstudio.scan.scan_plan import ScanPlan
from lfstudio.sim.instant import InstantRig
from lfstudio.sim.sim_camera import SimulatedCamera
from lfstudio.sim.studio import VirtualStudio
from lfstudio.studio.session import create_scan_dataset

RIG = load_rig()


def linear_profile() -> Profile:
    profile = Profile()
    for step in (profile.color, profile.deflicker, profile.shading, profile.rectify, profile.resample):
        step.enabled = False            # radiance against the rendered truth, in the captured frame
    return profile


@pytest.fixture(scope="module")
def bracketed(tmp_path_factory):
    root = tmp_path_factory.mktemp("hdr") / "ds"
    plan = ScanPlan.centered(2, 1, (4.0, 6.0), RIG, settle_s=0.0)
    plan = ScanPlan(**{**plan.__dict__, "bracket": parse_bracket("-2,0,+2")})
    studio = VirtualStudio(width_px=192, view_region_mm=plan.extent_mm(), highlight_gain=3.0, seed=3)
    rig = InstantRig(RIG)
    rig.connect()
    rig.home()
    camera = SimulatedCamera(studio, rig.true_position_mm, exposure_s=0.5, time_scale=0.0, noise=0.0)
    camera.connect()
    ds = create_scan_dataset(root, plan, rig={"name": RIG.name}, camera={"name": "sim"}, lens={"name": "virtual"})
    engine = ScanEngine(ds, plan, rig, camera, time_scale=0.0)
    engine.start()
    assert engine.wait(60) is ScanState.FINISHED, engine.message
    return Dataset.open(root), studio


def test_merged_radiance_matches_the_truth_where_the_middle_exposure_clips(bracketed):
    ds, studio = bracketed
    report = merge_dataset(ds.root, MergeOptions(), linear_profile(), workers=0)
    assert report.merged == 2 and not report.failed, report.failed
    again = Dataset.open(ds.root)
    v = again.view(0, 1)
    hdr = v["hdr"]
    assert hdr["file"] == "hdr/r00_c001.exr" and hdr["exposures_s"] == pytest.approx([0.125, 0.5, 2.0])
    radiance = read_radiance(again.root / hdr["file"])
    truth = studio.render(*v["commanded_mm"])
    assert radiance.shape == truth.shape and radiance.dtype == np.float32
    middle = cv2.cvtColor(cv2.imread(str(again.root / v["file"]).replace(".dng", ".jpg")), cv2.COLOR_BGR2RGB)
    assert middle is not None
    hot = truth.max(axis=2) > 1.05             # the highlight: clipped at the middle exposure
    calm = (truth.max(axis=2) < 0.8) & (truth.min(axis=2) > 0.05)
    assert hot.mean() > 0.005
    rel = np.abs(radiance - truth) / np.maximum(truth, 1e-3)
    assert np.median(rel[hot]) < 0.05, np.median(rel[hot])
    assert np.median(rel[calm]) < 0.05, np.median(rel[calm])
    assert hdr["clipped_fraction"]["frames"][1] > 0.005          # the middle frame clips the highlight
    assert hdr["clipped_fraction"]["merged"] < hdr["clipped_fraction"]["frames"][1] / 10
    assert radiance[hot].max() > 2.0                             # beyond what one exposure records
    assert hdr["max_misalignment_px"] < 0.25                     # a still rig: the frames line up
    preview = cv2.imread(str(again.root / hdr["preview"]), cv2.IMREAD_UNCHANGED)
    assert preview.dtype == np.uint16 and preview.shape[:2] == radiance.shape[:2]
    assert again.manifest["hdr"]["weights"]["clip_fraction"] == 0.97


def test_half_float_tiff_and_resume_skips_merged_views(bracketed):
    ds, _ = bracketed
    options = MergeOptions(format="tiff", half=True, folder="hdr_tiff", preview=False)
    first = merge_dataset(ds.root, options, linear_profile(), workers=0)
    assert first.merged == 2
    import tifffile

    data = tifffile.imread(ds.root / "hdr_tiff" / "r00_c000.tif")
    assert data.dtype == np.float16 and data.shape[2] == 3
    again = merge_dataset(ds.root, options, linear_profile(), workers=0)
    assert again.merged == 0 and again.skipped == 2


def test_the_merge_runs_on_a_dask_cluster_like_the_other_processing_steps(bracketed):
    """`lfstudio process --cluster`: the cluster's worker processes read the frames and write the merged
    files (same bytes of radiance as merged in this process); the manifest is written here."""
    distributed = pytest.importorskip("distributed")
    ds, _ = bracketed
    here = MergeOptions(folder="hdr_here", preview=False)
    merge_dataset(ds.root, here, linear_profile(), workers=0)
    there = MergeOptions(folder="hdr_cluster", preview=False)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        report = merge_dataset(ds.root, there, linear_profile(), cluster=cluster.scheduler_address)
    assert report.merged == 2 and not report.failed, report.failed
    assert f"Dask cluster {cluster.scheduler_address}" in report.executor and "Dask cluster" in report.summary()
    records = {(v["row"], v["column"]): v["hdr"] for v in Dataset.open(ds.root).done_views()}
    for cell, hdr in records.items():
        assert hdr["file"] == f"hdr_cluster/r{cell[0]:02d}_c{cell[1]:03d}.exr" and hdr["status"] == "done"
        mine = read_radiance(ds.root / hdr["file"].replace("hdr_cluster", "hdr_here"))
        assert np.array_equal(read_radiance(ds.root / hdr["file"]), mine)


def test_weights_leave_out_clipped_and_noise_floor_pixels():
    truth = np.array([[[0.001, 0.001, 0.001], [0.3, 0.3, 0.3], [3.0, 3.0, 3.0]]], np.float32)
    exposures = [0.25, 1.0, 4.0]
    frames, clipped = [], []
    for t in exposures:
        z = np.minimum(truth * t, 1.0)
        frames.append(z)
        clipped.append((z >= 0.97).any(axis=2))
    merged = merge_frames(frames, clipped, [e * 0.5 for e in exposures], 1, noise_floor=0.002)
    assert merged.radiance[0, 2] == pytest.approx(truth[0, 2], rel=1e-5)     # from the short frame only
    assert merged.radiance[0, 1] == pytest.approx(truth[0, 1], rel=1e-5)
    assert merged.radiance[0, 0] == pytest.approx(truth[0, 0], rel=1e-5)     # from the long frame only
    assert merged.clipped_frames[2] == pytest.approx(2 / 3) and merged.clipped_merged == 0


def test_frame_misalignment_is_measured():
    rng = np.random.default_rng(1)
    big = cv2.GaussianBlur(rng.random((120, 160)).astype(np.float32), (0, 0), 1.5) * 0.4 + 0.05
    truth = np.repeat(big[10:106, 10:138, None], 3, axis=2)
    shifted = np.repeat(big[12:108, 7:135, None], 3, axis=2)   # the third frame 3 px right, 2 px up
    frames = [truth * 0.5, truth, shifted * 2.0]
    clipped = [(f >= 0.97).any(axis=2) for f in frames]
    merged = merge_frames(frames, clipped, [0.5, 1.0, 2.0], 1, noise_floor=0.002)
    assert merged.shifts_px[0] == pytest.approx([0.0, 0.0], abs=0.1)
    assert merged.shifts_px[2] == pytest.approx([3.0, -2.0], abs=0.3)


def test_a_pixel_made_from_one_saturated_site_is_saturated():
    """Half-size debayering makes a pixel of 2 x 2 sites; a 0/1 map shrunk with INTER_AREA as 8-bit
    rounded one saturated site in four to 0, so a clipped sample entered the merge."""
    from lfstudio.processing.hdr import saturated_pixels

    sites = np.zeros((8, 8), bool)
    sites[2, 3] = True                         # one site of the block (1, 1)
    sites[6:8, 6:8] = True                     # a whole block
    pixels = saturated_pixels(sites, (4, 4))
    assert pixels.shape == (4, 4) and pixels[1, 1] and pixels[3, 3] and pixels.sum() == 2
    assert (saturated_pixels(sites, (8, 8)) == sites).all()


@pytest.mark.parametrize("name, bad", [("clip_fraction", 0.3), ("noise_floor", 0.5), ("max_shift_px", -1.0),
                                       ("format", "png")])
def test_merge_settings_are_described_once_for_the_merge_and_the_command_line(name, bad, capsys):
    """lfstudio process's --hdr* options are made from MergeOptions's descriptions: the same names,
    defaults and ranges; the merge and the command line refuse the same value, naming the option."""
    import argparse

    from lfstudio.cli import process as process_cli
    from lfstudio.errors import InputError
    from lfstudio.processing.hdr import MERGE_PARAMS

    param = MERGE_PARAMS[name]
    with pytest.raises(InputError) as err:
        MergeOptions(**{name: bad})
    assert str(err.value).startswith(f"{param.option or name}: ")
    p = argparse.ArgumentParser(prog="lfstudio process")
    process_cli.add_arguments(p)
    args = p.parse_args(["ds"])
    assert (args.hdr, args.hdr_half, args.hdr_clip, args.hdr_noise_floor) == (None, False, MergeOptions().clip_fraction,
                                                                            MergeOptions().noise_floor)
    if param.option:
        with pytest.raises(SystemExit):
            p.parse_args(["ds", param.option, str(bad)])
        assert f"argument {param.option}" in capsys.readouterr().err
