"""`lfstudio scan --bracket` (real subprocesses on the simulated studio): the frames of every view on
disk and in the manifest, bad brackets refused in one line naming the option before any folder is
made, a resume with another bracket refused naming both."""

from __future__ import annotations

import json


def test_scan_with_a_bracket_stores_every_frame(run_cli, tmp_path):
    out = run_cli("scan", "--port", "instant", "--grid", "2x1", "--time-scale", "0", "--sim-width-px", "64",
                  "--exposure-s", "0.25", "--bracket", "-2,0,+2", "--out", tmp_path / "ds")
    assert out.returncode == 0, out.stderr
    assert "exposure bracket -2, 0, +2 EV: 0.0625 s, 0.25 s, 1 s" in out.stderr
    manifest = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert manifest["bracket"]["frame_shutter_s"] == [0.0625, 0.25, 1.0]
    for v in manifest["views"]:
        assert v["status"] == "done" and len(v["frames"]) == 3
        assert [f["exposure_s"] for f in v["frames"]] == [0.0625, 0.25, 1.0]
        assert all((tmp_path / "ds" / f["file"]).is_file() for f in v["frames"])


def test_bad_brackets_are_one_line_naming_the_option(run_cli, tmp_path):
    for value, words in (("-2,0,x", "'x' is not an EV step"), ("-2,0,-2", "given twice"),
                         ("-12,0", "too far"), ("1/100,0", "mixes EV steps and shutter times"),
                         ("1/0s", "not a shutter time")):
        out = run_cli("scan", "--bracket", value, "--grid", "2x1", "--out", tmp_path / "ds")
        assert out.returncode == 2, (value, out.stderr)
        last = out.stderr.strip().splitlines()[-1]
        assert "--bracket" in last and words in last and "Traceback" not in out.stderr, (value, last)
        assert not (tmp_path / "ds").exists()


def test_resume_with_another_bracket_is_refused(run_cli, tmp_path):
    first = run_cli("scan", "--port", "instant", "--grid", "2x1", "--time-scale", "0", "--sim-width-px", "64",
                    "--bracket", "-1,0,+1", "--out", tmp_path / "ds")
    assert first.returncode == 0, first.stderr
    again = run_cli("scan", "--resume", "--bracket", "-2,0", "--time-scale", "0", "--out", tmp_path / "ds")
    assert again.returncode != 0
    assert "--bracket" in again.stderr and "-1, 0, +1 EV (3 frames)" in again.stderr and "Traceback" not in again.stderr


def test_process_merges_a_bracketed_scan(run_cli, tmp_path):
    scan = run_cli("scan", "--port", "instant", "--grid", "2x1", "--time-scale", "0", "--sim-width-px", "64",
                   "--bracket", "-2,0,+2", "--out", tmp_path / "ds")
    assert scan.returncode == 0, scan.stderr
    (tmp_path / "profile.toml").write_text("[rectify]\nenabled = false\n")
    out = run_cli("process", tmp_path / "ds", "--workers", "0", "--profile", tmp_path / "profile.toml",
                  "--hdr", "tiff", "--hdr-half")
    assert out.returncode == 0, out.stderr
    assert "HDR: 2 views merged" in out.stdout and "after the merge" in out.stdout
    import tifffile

    data = tifffile.imread(tmp_path / "ds" / "hdr" / "r00_c001.tif")
    assert str(data.dtype) == "float16" and data.ndim == 3
    assert (tmp_path / "ds" / "hdr" / "preview" / "r00_c001.png").is_file()
    manifest = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    assert manifest["hdr"]["options"]["format"] == "tiff"
    assert all(v["hdr"]["status"] == "done" for v in manifest["views"])


def test_process_hdr_on_a_dataset_without_a_bracket_is_refused(run_cli, tmp_path):
    scan = run_cli("scan", "--port", "instant", "--grid", "2x1", "--time-scale", "0", "--sim-width-px", "64",
                   "--out", tmp_path / "ds")
    assert scan.returncode == 0, scan.stderr
    out = run_cli("process", tmp_path / "ds", "--hdr", "exr")
    assert out.returncode == 2 or out.returncode == 1
    assert "--hdr" in out.stderr and "no exposure bracket" in out.stderr and "Traceback" not in out.stderr


def test_hevc_export_names_the_exposure_or_the_tone_map(run_cli, tmp_path):
    scan = run_cli("scan", "--port", "instant", "--grid", "2x1", "--time-scale", "0", "--sim-width-px", "64",
                   "--bracket", "-1,0,+1", "--out", tmp_path / "ds")
    assert scan.returncode == 0, scan.stderr
    refused = run_cli("export", tmp_path / "ds", "--format", "hevc", "--source", "tonemap",
                      "--out", tmp_path / "v.mkv")
    assert refused.returncode == 2 and "tone-mapped HDR views missing" in refused.stderr, refused.stderr
    (tmp_path / "profile.toml").write_text("[rectify]\nenabled = false\n")
    assert run_cli("process", tmp_path / "ds", "--workers", "0", "--profile", tmp_path / "profile.toml").returncode == 0
    for source, kind in (("tonemap", "tone map"), ("processed", "one exposure")):
        out = tmp_path / f"{source}.mkv"
        proc = run_cli("export", tmp_path / "ds", "--format", "hevc", "--source", source, "--out", out)
        assert proc.returncode == 0, proc.stderr
        side = json.loads(out.with_name(out.name + ".json").read_text())       # the video's sidecar
        assert side["source"] == source and side["exposure"]["kind"] == kind
        if source == "processed":
            assert side["exposure"]["frame"] == 1 and side["exposure"]["ev"] == 0.0
        else:
            assert side["exposure"]["operator"] == "reinhard-global" and side["color"].startswith("sRGB-encoded")


def test_plan_counts_every_frame(run_cli, tmp_path):
    single = json.loads(run_cli("plan", "--json").stdout)
    out = run_cli("plan", "--bracket", "-2,0,+2", "--json", "--save", tmp_path / "p.toml")
    assert out.returncode == 0, out.stderr
    r = json.loads(out.stdout)
    assert r["frames_per_view"] == 3 and r["frames"] == 3 * single["images"]
    assert r["storage_bytes"] == 3 * single["storage_bytes"]
    assert r["capture_time_s"] > single["capture_time_s"] + single["images"] * (0.125 + 2.0 + 2 * 2.5) * 0.999
    assert 'bracket = "-2,0,+2"' in (tmp_path / "p.toml").read_text()
    table = run_cli("plan", "--plan", tmp_path / "p.toml").stdout          # the saved plan keeps its bracket
    assert "exposure bracket        3 frames a view (0.125 s, 0.5 s, 2 s), 6363 pictures" in table
    bad = run_cli("plan", "--bracket", "-2,0,y")
    assert bad.returncode == 2 and bad.stderr.strip().splitlines()[-1].startswith("lfstudio plan: error: --bracket: ")


def test_colmap_and_nerfstudio_export_the_merged_float_radiance_with_source_hdr(run_cli, tmp_path):
    """--source hdr: the merge's OpenEXR files byte for byte under images/ (named in images.txt and
    transforms.json), the manifests saying what the pixels are; other formats refuse it by name; the
    default export stays on the processed 16-bit views."""
    scan = run_cli("scan", "--port", "instant", "--grid", "3x2", "--time-scale", "0", "--sim-width-px", "96",
                   "--bracket", "-2,0,+2", "--out", tmp_path / "ds")
    assert scan.returncode == 0, scan.stderr
    refused = run_cli("export", tmp_path / "ds", "--format", "colmap", "--source", "hdr", "--out", tmp_path / "c0")
    assert refused.returncode == 2 and "merged HDR views missing" in refused.stderr, refused.stderr
    (tmp_path / "profile.toml").write_text("[rectify]\nenabled = false\n")
    assert run_cli("process", tmp_path / "ds", "--workers", "0", "--profile", tmp_path / "profile.toml").returncode == 0
    ds = tmp_path / "ds"
    for fmt in ("colmap", "nerfstudio"):
        out = tmp_path / fmt
        proc = run_cli("export", ds, "--format", fmt, "--source", "hdr", "--out", out)
        assert proc.returncode == 0, proc.stderr
        for name in ("r00_c000", "r01_c002"):
            assert (out / "images" / f"{name}.exr").read_bytes() == (ds / "hdr" / f"{name}.exr").read_bytes()
        manifest = json.loads((out / "lfstudio_manifest.json").read_text())
        assert manifest["source"] == "hdr" and manifest["exposure"]["kind"] == "merged radiance"
        assert manifest["color"].startswith("linear RGB radiance, 32-bit float OpenEXR") and "bit_depth" not in manifest
    assert "r00_c000.exr" in (tmp_path / "colmap" / "sparse" / "0" / "images.txt").read_text()
    frames = json.loads((tmp_path / "nerfstudio" / "transforms.json").read_text())["frames"]
    assert {f["file_path"] for f in frames} == {f"images/r{r:02d}_c{c:03d}.exr" for r in range(2) for c in range(3)}
    video = run_cli("export", ds, "--format", "hevc", "--source", "hdr", "--out", tmp_path / "v.mkv")
    assert video.returncode == 2 and "--source: hdr (the merged float radiance) is not exported as hevc" in video.stderr
    default = run_cli("export", ds, "--format", "colmap", "--out", tmp_path / "plain")
    assert default.returncode == 0 and (tmp_path / "plain" / "images" / "r00_c000.png").is_file()
    assert json.loads((tmp_path / "plain" / "lfstudio_manifest.json").read_text())["source"] == "processed"


def test_a_bracket_on_a_camera_whose_shutter_lfstudio_cannot_set_is_refused_before_anything(run_cli, tmp_path):
    """A hot-folder camera took explicit bracket times through the checks; the rig moved, then every
    view's frame failed to set its shutter time, was retried and paused the scan."""
    incoming = tmp_path / "incoming"
    incoming.mkdir()
    out = run_cli("scan", "--port", "sim", "--camera", f"folder:{incoming}", "--grid", "2x1", "--time-scale", "0",
                  "--bracket", "1/500,1/125", "--out", tmp_path / "ds")
    assert out.returncode == 2, out.stderr
    last = out.stderr.strip().splitlines()[-1]
    assert "--bracket" in last and "no shutter time lfstudio can set" in last and "--camera gphoto2" in last
    assert "Traceback" not in out.stderr and not (tmp_path / "ds").exists()
