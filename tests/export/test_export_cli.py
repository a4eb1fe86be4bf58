"""``lfstudio export`` and ``lfstudio import-hevc`` in a subprocess: outputs, exit codes, one-line errors."""

from __future__ import annotations

import json


def _one_error_line(proc, *words):
    lines = [ln for ln in proc.stderr.splitlines() if "error" in ln]
    assert len(lines) == 1, proc.stderr
    for w in words:
        assert w in lines[0], lines[0]
    assert "Traceback" not in proc.stderr


def test_export_png_then_refuses_to_overwrite(make_tiny_dataset, run_cli, tmp_path):
    ds = make_tiny_dataset("png", width_px=241)
    out = tmp_path / "exports" / "png"
    proc = run_cli("export", ds.root, "--format", "hevc", "--out", tmp_path / "x.mp4", "--estimate")
    assert proc.returncode == 0 and "15 views (raw), 242 x 160 px, about" in proc.stdout   # the output asked for
    assert not (tmp_path / "x.mp4").exists()
    proc = run_cli("export", ds.root, "--format", "png", "--out", out, "--views", "r0,c0-2")
    assert proc.returncode == 0, proc.stderr
    assert "exported 3 views" in proc.stdout
    doc = json.loads((out / "manifest.json").read_text())
    assert [v["file"] for v in doc["views"]] == ["r00_c000.png", "r00_c001.png", "r00_c002.png"]
    proc = run_cli("export", ds.root, "--format", "png", "--out", out)
    assert proc.returncode == 2
    _one_error_line(proc, "--out", "already exists", "--overwrite")
    (tmp_path / "a_file").write_text("x")          # a destination that cannot be created: one line, no traceback
    proc = run_cli("export", ds.root, "--format", "png", "--out", tmp_path / "a_file" / "png", "--views", "r0")
    assert proc.returncode == 1
    _one_error_line(proc, "a_file", "writable")


def test_export_bad_input_exit_2(make_tiny_dataset, run_cli, tmp_path):
    ds = make_tiny_dataset("png", width_px=241)
    for args, words in [
        (["--format", "tiff", "--out", tmp_path / "x"], ("--format", "'png', 'hevc', 'hci', 'colmap', 'nerfstudio'")),
        (["--format", "colmap", "--out", tmp_path / "x", "--image-bit-depth", "12"], ("--image-bit-depth", "8 (sRGB")),
        (["--format", "nerfstudio", "--out", tmp_path / "x", "--holdout", "every-1"], ("--holdout", "every-K")),
        (["--format", "nerfstudio", "--out", tmp_path / "x", "--holdout", "every-9"], ("--holdout", "no view")),
        (["--format", "hevc", "--out", tmp_path / "x.avi"], ("--out", ".mp4")),
        (["--format", "hevc", "--out", tmp_path / "x.mp4", "--bit-depth", "8"], ("--bit-depth", "10 or 12")),
        (["--format", "png", "--out", tmp_path / "x", "--views", "r0-9"], ("--views",)),
        (["--format", "png", "--out", tmp_path / "x", "--views", "rows1"], ("--views", "'rows1'", "r0-8,c10-18")),
        (["--format", "png", "--out", tmp_path / "x", "--source", "processed"], ("--source", "lfstudio process")),
        (["--format", "hci", "--out", tmp_path / "x", "--hci-size", "nine"], ("--hci-size",)),
        (["--format", "hci", "--out", tmp_path / "x", "--hci-bit-depth", "12"], ("--hci-bit-depth", "8 (sRGB")),
        (["--format", "hci", "--out", tmp_path / "x", "--hci-size", "3x3", "--hci-centre-view", "0,0"], ("--hci-centre-view",)),
    ]:
        proc = run_cli("export", ds.root, *args)
        assert proc.returncode == 2, (args, proc.stderr)
        _one_error_line(proc, *words)
    proc = run_cli("export", tmp_path / "nowhere", "--format", "png", "--out", tmp_path / "x")
    assert proc.returncode == 2
    _one_error_line(proc, "nowhere", "dataset.json")
    assert sorted(p.name for p in tmp_path.iterdir()) == [ds.root.name]


def test_export_hevc_and_import_back(make_tiny_dataset, run_cli, tmp_path):
    ds = make_tiny_dataset("png", width_px=241)
    video = tmp_path / "lf.mkv"
    proc = run_cli("export", ds.root, "--format", "hevc", "--out", video, "--views", "r1-2,c0-1")
    assert proc.returncode == 0, proc.stderr
    assert "smaller than 16-bit PNG" in proc.stdout and "PSNR" in proc.stdout
    proc = run_cli("import-hevc", video, "--out", tmp_path / "back")
    assert proc.returncode == 0, proc.stderr
    assert "restored 4 views" in proc.stdout
    assert sorted(p.name for p in (tmp_path / "back" / "raw").iterdir()) == \
        ["r01_c000.png", "r01_c001.png", "r02_c000.png", "r02_c001.png"]
    proc = run_cli("import-hevc", tmp_path / "missing.mp4", "--out", tmp_path / "b2")
    assert proc.returncode == 2
    _one_error_line(proc, "FILE", "missing.mp4")
    (tmp_path / "junk.mkv").write_bytes(b"not a video")       # FFmpeg's own log line stays in the log file
    (tmp_path / "junk.mkv.json").write_text((tmp_path / "lf.mkv.json").read_text())
    proc = run_cli("import-hevc", tmp_path / "junk.mkv", "--out", tmp_path / "b3")
    assert proc.returncode != 0 and "libav" not in proc.stderr, proc.stderr
    _one_error_line(proc, "junk.mkv", "cannot be opened")
    proc = run_cli("export", ds.root, "--format", "png", "--out", ds.root, "--overwrite")
    assert proc.returncode == 2 and (ds.root / "dataset.json").is_file()
    _one_error_line(proc, "--out", f"{ds.root} is the dataset being exported")
    assert proc.stderr.count(str(ds.root)) == 1                # each path named once
    proc = run_cli("export", ds.root, "--format", "png", "--out", ds.root / "raw", "--overwrite")
    assert proc.returncode == 2 and any((ds.root / "raw").iterdir())
    _one_error_line(proc, "--out", f"{ds.root / 'raw'} is part of the dataset being exported")
    assert proc.stderr.count(str(ds.root)) == 1
    proc = run_cli("export", ds.root, "--format", "png", "--out", ds.root.parent, "--overwrite")
    assert proc.returncode == 2 and ds.root.is_dir()
    _one_error_line(proc, "--out", f"{ds.root.parent} holds the dataset being exported ({ds.root})")


def test_report_summary_counts_views_in_words():
    from pathlib import Path

    from lfstudio.export import ExportReport

    assert ExportReport(Path("out"), 1, 2048, 0.5, "png", "raw").summary().startswith("exported 1 view (raw) as png")
    assert ExportReport(Path("out"), 3, 2048, 0.5, "png", "raw").summary().startswith("exported 3 views (raw)")


def test_export_colmap_and_nerfstudio(make_tiny_dataset, run_cli, tmp_path):
    ds = make_tiny_dataset("png", width_px=241)
    proc = run_cli("export", ds.root, "--format", "colmap", "--out", tmp_path / "c", "--views", "r1")
    assert proc.returncode == 0, proc.stderr
    assert "5 views (raw)" in proc.stderr and "no calibration" in proc.stderr and "as colmap" in proc.stdout
    assert sorted(p.name for p in (tmp_path / "c" / "sparse" / "0").iterdir()) == \
        ["cameras.txt", "images.txt", "points3D.ply", "points3D.txt"]
    images = (tmp_path / "c" / "sparse" / "0" / "images.txt").read_text().splitlines()
    records = [ln for ln in images if not ln.startswith("#")][0::2]     # each image's line, then its POINTS2D
    assert [ln.split()[-1] for ln in records] == [f"r01_c00{c}.png" for c in range(5)]
    proc = run_cli("export", ds.root, "--format", "NERFSTUDIO", "--out", tmp_path / "n", "--holdout", "centre")
    assert proc.returncode == 0, proc.stderr
    assert "1 view held out" in proc.stderr
    meta = json.loads((tmp_path / "n" / "transforms.json").read_text())
    assert meta["test_filenames"] == ["images/r01_c002.png"] and len(meta["frames"]) == 15


def test_hci_size_is_read_like_every_other_pair(make_tiny_dataset, run_cli, tmp_path):
    """--hci-size goes through numbers.parse_numbers (3x3, 3×3, 3,3); whole numbers ≥ 1."""
    ds = make_tiny_dataset("png")                              # 5 columns x 3 rows
    base = ["export", ds.root, "--format", "hci", "--estimate", "--out", tmp_path / "h"]
    for text in ("3x2", "3×2", "3,2"):
        proc = run_cli(*base, "--hci-size", text)
        assert proc.returncode == 0 and proc.stdout.startswith("6 views"), (text, proc.stderr)
    for text, words in (("0x3", ("--hci-size", "0 is out of range", "≥ 1")), ("3.5x3", ("--hci-size", "whole"))):
        proc = run_cli(*base, "--hci-size", text)
        assert proc.returncode == 2, proc.stderr
        _one_error_line(proc, *words)
    assert not (tmp_path / "h").exists()


def test_export_and_import_hevc_expand_a_quoted_tilde_and_variables(make_tiny_dataset, run_cli, tmp_path):
    """The library takes paths as given; the command line expands '~' and $VARIABLES
    (dataset.paths.expand_path) for the dataset, --out and the video, so nothing is lost for a user
    whose shell left them unexpanded, and no folder named '~' or '$HOME' appears."""
    ds = make_tiny_dataset("png", width_px=241)
    home, cwd = tmp_path / "home", tmp_path / "cwd"
    home.mkdir()
    cwd.mkdir()
    env = {"HOME": str(home), "LFS_DS": str(ds.root)}
    proc = run_cli("export", "$LFS_DS", "--format", "hevc", "--out", "~/exports/lf.mkv", "--views", "r1-2,c0-1",
                   env=env, cwd=cwd)
    assert proc.returncode == 0, proc.stderr
    assert (home / "exports" / "lf.mkv").is_file() and (home / "exports" / "lf.mkv.json").is_file()
    proc = run_cli("import-hevc", "~/exports/lf.mkv", "--out", "${HOME}/back", env=env, cwd=cwd)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in (home / "back" / "raw").iterdir()) == \
        ["r01_c000.png", "r01_c001.png", "r02_c000.png", "r02_c001.png"]
    proc = run_cli("export", ds.root, "--format", "png", "--out", "~/exports/png", "--views", "r0", env=env, cwd=cwd)
    assert proc.returncode == 0, proc.stderr
    assert (home / "exports" / "png" / "manifest.json").is_file()
    assert list(cwd.iterdir()) == []                # nothing named '~' or '$HOME' made here
