"""The whole chain on small real DNG datasets: outputs, manifest records, resume, failures, executors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from lfstudio.dataset import Dataset
from lfstudio.errors import InputError
from lfstudio.jobs import Cancelled, CancelToken
from lfstudio.processing.pipeline import process_dataset
from lfstudio.dataset.profile import PROFILE_NAME, Profile


def read_rgb(path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None and img.dtype == np.uint16, path
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def plain_profile(**changes) -> Profile:
    p = Profile()
    p.rectify.enabled = False
    p.color.enabled = False
    p.deflicker.enabled = False
    for key, value in changes.items():
        step, _, name = key.partition("__")
        setattr(getattr(p, step), name, value)
    return p


def test_chain_writes_16bit_views_and_records_them(make_dataset):
    H = [[1.0, 0.01, 1.5], [-0.01, 1.0, -1.0], [0.0, 0.0, 1.0]]
    ds = make_dataset(rows=2, cols=2, gains={(0, 1): 1.1, (1, 0): 0.92}, H=H)
    report = process_dataset(ds.root, Profile(), workers=0)
    assert report.ok and report.processed == 4 and report.skipped == 0
    ds = Dataset.open(ds.root)
    assert (ds.root / PROFILE_NAME).is_file()
    assert Profile.load(ds.root / PROFILE_NAME) == Profile()
    assert ds.manifest["processing"]["profile_sha256"] == report.profile_sha256
    assert ds.manifest["processing"]["rectified"] is True
    outs = {}
    for v in ds.views:
        rec = v["processed"]
        assert rec["status"] == "done" and rec["profile_sha256"] == report.profile_sha256
        steps = rec["timings_s"]               # each view's own CPU beside the wall time of its steps
        assert 0 < steps["cpu"] and set(steps) >= {"decode", "process", "encode", "cpu"}
        img = read_rgb(ds.root / rec["file"])
        assert img.shape == (32, 48, 3)  # half resolution
        outs[(v["row"], v["column"])] = img.astype(np.float64)
    # de-flicker: the gain undoes the flicker; all views come out alike
    assert ds.view(0, 1)["processed"]["gain"] == pytest.approx(1 / 1.1, rel=0.01)
    assert ds.view(1, 0)["processed"]["gain"] == pytest.approx(1 / 0.92, rel=0.01)
    ref = outs[(1, 1)]
    inner = (slice(4, -4), slice(4, -4))
    for key, img in outs.items():
        rel = np.abs(img[inner] - ref[inner]).mean() / ref[inner].mean()
        assert rel < 0.01, (key, rel)


def test_captures_where_the_output_goes_are_not_overwritten(make_dataset):
    """import-hevc of processed views restores them as processed/rRR_cCCC.png captures: processing
    must refuse instead of overwriting its own input (here the same clash via [output] folder)."""
    ds = make_dataset(rows=1, cols=2, fmt="png")
    before = (ds.root / "raw" / "r00_c000.png").read_bytes()
    with pytest.raises(InputError) as exc:
        process_dataset(ds.root, plain_profile(output__folder="raw"), workers=0)
    assert "[output] folder" in exc.value.field and "raw/r00_c000.png" in str(exc.value)
    assert (ds.root / "raw" / "r00_c000.png").read_bytes() == before


def test_resume_skips_views_done_with_the_same_profile(make_dataset):
    ds = make_dataset(rows=1, cols=3)
    profile = plain_profile()
    first = process_dataset(ds.root, profile, workers=0)
    assert first.processed == 3
    out = Dataset.open(ds.root).view(0, 2)["processed"]["file"]
    (ds.root / out).unlink()  # lost output: redone
    again = process_dataset(ds.root, profile, workers=0)
    assert (again.processed, again.skipped) == (1, 2)
    changed = plain_profile(resample__scale=0.25)
    third = process_dataset(ds.root, changed, workers=0)
    assert (third.processed, third.skipped) == (3, 0)
    # a parameter of a disabled step does not change the identity of the profile
    same = plain_profile(resample__scale=0.25, color__white_output=0.5)
    assert process_dataset(ds.root, same, workers=0).skipped == 3


def test_failing_view_is_reported_and_the_others_finish(make_dataset, run_cli):
    ds = make_dataset(rows=1, cols=4)
    (ds.root / ds.view(0, 2)["file"]).write_bytes(b"not a raw file")
    report = process_dataset(ds.root, plain_profile(), workers=0)
    assert report.processed == 3
    assert [(r, c) for r, c, _ in report.failed] == [(0, 2)]
    assert "r00_c002" in report.failed[0][2]
    ds = Dataset.open(ds.root)
    assert ds.view(0, 2)["processed"]["status"] == "failed"
    assert ds.view(0, 3)["processed"]["status"] == "done"


def test_cancel_stops_early_and_a_rerun_resumes(make_dataset):
    ds = make_dataset(rows=1, cols=5)
    cancel = CancelToken()
    seen = []

    def on_view(result):
        seen.append(result)
        cancel.cancel()

    with pytest.raises(Cancelled):
        process_dataset(ds.root, plain_profile(), workers=0, cancel=cancel, on_view=on_view)
    ds = Dataset.open(ds.root)
    done = [v for v in ds.views if v.get("processed", {}).get("status") == "done"]
    assert 1 <= len(done) < 5
    report = process_dataset(ds.root, plain_profile(), workers=0)
    assert report.skipped == len(done) and report.processed == 5 - len(done)


def test_views_processed_so_far_survive_a_crash_through_the_journal(make_dataset, monkeypatch):
    """Every few seconds (here: after every view) the views finished so far are made durable in
    the journal; what an open of the folder sees mid-run is what a crash would leave."""
    from lfstudio.processing import pipeline

    monkeypatch.setattr(pipeline, "SAVE_EVERY_S", -1.0)
    ds = make_dataset(rows=1, cols=4)
    durable = []

    def on_view(result):                     # called before the checkpoint of this view
        durable.append(sum(v.get("processed", {}).get("status") == "done" for v in Dataset.open(ds.root).views))

    process_dataset(ds.root, plain_profile(), workers=0, on_view=on_view)
    assert durable == [0, 1, 2, 3]           # each earlier view is on disk, none lost
    journal = ds.root / "journal.jsonl"     # processing merges into dataset.json; the journal is the scan's
    assert not journal.exists() or journal.stat().st_size == 0


def test_local_process_pool(make_dataset):
    ds = make_dataset(rows=1, cols=3, gains={(0, 0): 1.05})
    report = process_dataset(ds.root, plain_profile(deflicker__enabled=True), workers=2)
    assert report.ok and report.processed == 3
    assert "process pool (2 workers)" in report.executor
    assert report.gains[(0, 0)] == pytest.approx(1 / 1.05, rel=0.01)


def test_cli_process_summary_exit_codes_and_errors(make_dataset, run_cli, tmp_path):
    ds = make_dataset(rows=1, cols=3)
    profile = tmp_path / "p.toml"
    plain_profile().save(profile)
    done = run_cli("process", ds.root, "--profile", profile, "--workers", "0")
    assert done.returncode == 0, done.stderr
    assert "3 processed, 0 already done" in done.stdout
    assert "process [" in done.stderr  # the progress bar
    (ds.root / ds.view(0, 0)["file"]).write_bytes(b"garbage")
    again = run_cli("process", ds.root, "--workers", "0", "--force")
    assert again.returncode == 1 and "FAILED row 0, column 0" in again.stderr
    assert "2 processed" in again.stdout
    missing = run_cli("process", ds.root, "--workers", "0", "--force", "--profile", tmp_path / "nope.toml")
    assert missing.returncode == 2 and "nope.toml" in missing.stderr
    # rectification needs a calibration: the default profile says how to get one
    (ds.root / "processing.toml").unlink()
    uncal = run_cli("process", ds.root, "--workers", "0")
    assert uncal.returncode == 2 and "calibration.json not found" in uncal.stderr


def test_dask_local_cluster(make_dataset):
    distributed = pytest.importorskip("distributed")
    ds = make_dataset(rows=1, cols=3, gains={(0, 2): 0.95})
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        report = process_dataset(ds.root, plain_profile(deflicker__enabled=True),
                                 cluster=cluster.scheduler_address)
    assert report.ok and report.processed == 3
    assert "Dask cluster" in report.executor
    assert report.gains[(0, 2)] == pytest.approx(1 / 0.95, rel=0.01)
    assert all((ds.root / f"processed/r00_c00{c}.png").is_file() for c in range(3))


def test_real_camera_dng_through_the_chain(shared_data, tmp_path):
    import shutil

    src = shared_data / "raw" / "colorchart.dng"
    if not src.is_file():
        pytest.skip("colorchart.dng not present")
    ds = Dataset.create(tmp_path / "real", camera={"name": "Canon EOS"}, lens={"name": "unknown"},
                        grid={"columns": 2, "rows": 1, "spacing_mm": [4.0, 6.0]})
    for v in ds.views:
        rel = ds.raw_name(v["row"], v["column"], ".dng")
        shutil.copyfile(src, ds.root / rel)
        v.update(file=rel, status="done")
    ds.save()
    profile = Profile()
    profile.rectify.enabled = False
    profile.debayer.half_size = True
    report = process_dataset(ds.root, profile, workers=0)
    assert report.ok and report.processed == 2
    assert report.gains[(0, 0)] == pytest.approx(1.0, abs=1e-6)  # identical views
    img = read_rgb(ds.root / "processed" / "r00_c000.png")
    assert img.shape[:2] == (578, 867)   # half of 1156 x 1734
    stats = Dataset.open(ds.root).view(0, 0)["processed"]["stats"]
    assert stats["clipped_fraction"] < 0.01 and 1000 < np.mean(stats["mean_rgb"]) < 50000


def test_a_calibration_that_turns_the_views_black_fails_them_by_name(make_dataset, run_cli):
    # it passes the loader (angles 0, corners moved by 46 % of the diagonal) but the captured image
    # fills only 45 % of the rectified frame: every view would come out mostly black
    w = 96
    ds = make_dataset(rows=1, cols=2, w=w, h=64, H=[[1.0, 0.0, 0.55 * w], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    proc = run_cli("process", ds.root)
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr.count("FAILED row") == 2 and "55 % black" in proc.stderr
    assert "calibration.json" in proc.stderr and "lfstudio calibrate" in proc.stderr
    ds = Dataset.open(ds.root)
    assert all(v["processed"]["status"] == "failed" for v in ds.views)
    assert not list((ds.root / "processed").glob("*.png"))
    # a mild calibration of the same size still processes (the guard is not a blanket refusal)
    ok = make_dataset(rows=1, cols=2, w=w, h=64, H=[[1.0, 0.0, 0.2 * w], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], name="ok")
    assert run_cli("process", ok.root).returncode == 0
