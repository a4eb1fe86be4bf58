"""Fault matrix, paths: every stage refuses a dataset whose names or symlinks lead outside its folder,
with one line naming the path, and touches nothing outside (nothing written, deleted or read there).

One parametrised test per stage; each case sets up one hostile path (a symlinked folder or file,
``..`` in a manifest entry or in ``processing.toml``) and runs the real command."""

from __future__ import annotations

import os
import shutil

import pytest

from tests.faults.conftest import assert_one_line_error, manifest_of, set_pending, write_manifest


def _link_folder(root, name, outside):
    """Move ``root/name`` (if any) outside and leave a symlink to it in its place."""
    target = outside.path / name
    if (root / name).exists():
        shutil.move(str(root / name), str(target))
    else:
        target.mkdir()
    os.symlink(target, root / name)


def _link_file(root, name, outside, text="{}"):
    target = outside.path / name
    if (root / name).exists():
        shutil.move(str(root / name), str(target))
    else:
        target.write_text(text)
    os.symlink(target, root / name)


def _manifest_entry(root, key, value):
    m = manifest_of(root)
    view = next(v for v in m["views"] if v["status"] == "done")
    if key == "processed.file":
        view["processed"] = {"status": "done", "file": value, "profile_sha256": "0" * 64}
    else:
        view[key] = value
    write_manifest(root, m)


def _profile(root, folder):
    (root / "processing.toml").write_text(f'[output]\nfolder = "{folder}"\n')


# -- scan --resume --------------------------------------------------------------------------------------
SCAN_CASES = {
    # the case: raw/ a symlink and views pending -> the resume's clean-up must not delete there
    "raw folder symlink": (lambda root, out: _link_folder(root, "raw", out), 1, "'raw' points outside"),
    "thumbs folder symlink": (lambda root, out: _link_folder(root, "thumbs", out), 1, "'thumbs' points outside"),
    "journal symlink": (lambda root, out: _link_file(root, "journal.jsonl", out, ""), 1,
                        "'journal.jsonl' points outside"),
    "manifest file ..": (lambda root, out: _manifest_entry(root, "file", "../outside/keep.txt"), 1,
                         "../outside/keep.txt"),
    "manifest thumb ..": (lambda root, out: _manifest_entry(root, "thumb", "../outside/keep.txt"), 1,
                          "../outside/keep.txt"),
}


@pytest.mark.parametrize("case", list(SCAN_CASES))
def test_scan_resume_refuses_paths_leading_outside(case, scanned, outside, run_cli):
    root = scanned(3, 2)
    set_pending(root, {(1, 0), (1, 1), (1, 2)})        # an interrupted scan: its files are still there
    setup, status, needle = SCAN_CASES[case]
    setup(root, outside)
    outside.mark()
    proc = run_cli("scan", "--resume", "--out", root)
    assert_one_line_error(proc, status, needle)
    assert outside.unchanged(), "something outside the dataset changed"
    if (outside.path / "raw").is_dir():                 # the pending views' old files were not deleted there
        assert len(list((outside.path / "raw").iterdir())) == 6


# -- process ----------------------------------------------------------------------------------------------
PROCESS_CASES = {
    "output folder ..": (lambda root, out: _profile(root, "../outside"), 2, "[output] folder"),
    "output folder absolute": (lambda root, out: _profile(root, str(out.path)), 2, "[output] folder"),
    "output folder symlink": (lambda root, out: (_profile(root, "mine"), _link_folder(root, "mine", out)), 1,
                              "'mine' points outside"),
    "processed folder symlink": (lambda root, out: _link_folder(root, "processed", out), 1,
                                 "'processed' points outside"),
    "calibration.json symlink": (lambda root, out: _link_file(root, "calibration.json", out), 1,
                                 "'calibration.json' points outside"),
    "processing.toml symlink": (lambda root, out: _link_file(root, "processing.toml", out, "[output]\n"), 1,
                                "'processing.toml' points outside"),
    "manifest processed.file ..": (lambda root, out: _manifest_entry(root, "processed.file",
                                                                     "../outside/r00_c000.png"), 1,
                                   "processed.file"),
    "manifest symlink": (lambda root, out: _link_file(root, "dataset.json", out), 1,
                         "'dataset.json' points outside"),
}


@pytest.mark.parametrize("case", list(PROCESS_CASES))
def test_process_refuses_paths_leading_outside(case, tiny_dataset, outside, run_cli):
    root = tiny_dataset.root
    setup, status, needle = PROCESS_CASES[case]
    setup(root, outside)
    outside.mark()
    proc = run_cli("process", root, "--workers", "0")
    assert_one_line_error(proc, status, needle)
    assert outside.unchanged(), "something outside the dataset changed"


# -- calibrate, export, info ------------------------------------------------------------------------------
OTHER_CASES = {
    "calibrate cache symlink": ("calibrate", lambda root, out: _link_folder(root, "cache", out), 1,
                                "'cache' points outside"),
    "calibrate calibration.json symlink": ("calibrate", lambda root, out: _link_file(root, "calibration.json", out),
                                           1, "'calibration.json' points outside"),
    "export manifest file ..": ("export", lambda root, out: _manifest_entry(root, "file", "../outside/keep.txt"),
                                1, "../outside/keep.txt"),
    "export raw file symlink": ("export", lambda root, out: _link_file(root, "raw/r00_c000.png", out), 1,
                                "points outside"),
    "info raw folder symlink": ("info", lambda root, out: _link_folder(root, "raw", out), 1,
                                "'raw' points outside"),
    "check quality folder symlink": ("check", lambda root, out: _link_folder(root, "quality", out), 1,
                                     "'quality' points outside"),
    "check quality.json symlink": ("check", lambda root, out: _link_file(root, "quality.json", out), 1,
                                   "'quality.json' points outside"),
    "check a folder no stage knows yet": ("check", lambda root, out: _link_folder(root, "notes", out), 1,
                                          "'notes' points outside"),
}


@pytest.mark.parametrize("case", list(OTHER_CASES))
def test_calibrate_export_info_refuse_paths_leading_outside(case, tiny_dataset, outside, run_cli, tmp_path):
    root = tiny_dataset.root
    command, setup, status, needle = OTHER_CASES[case]
    (outside.path / "raw").mkdir() if "raw file" in case else None
    setup(root, outside)
    outside.mark()
    args = {"calibrate": ("calibrate", root), "export": ("export", root, "--format", "png", "--out", tmp_path / "ex"),
            "info": ("info", root, "--verify"), "check": ("check", root)}[command]
    proc = run_cli(*args)
    assert_one_line_error(proc, status, needle)
    assert outside.unchanged(), "something outside the dataset changed"
    assert not (tmp_path / "ex").exists()


def test_every_file_a_scan_process_and_export_write_gets_the_users_umask(run_cli, tmp_path):
    """Dataset and export files are shared (Dask workers, another account on a studio share): they get
    the permissions of any file the user creates (0666 minus the umask), never 0600."""
    umask = lambda: os.umask(0o002)            # noqa: E731 - group-writable, as on a shared workstation
    out, export = tmp_path / "ds", tmp_path / "export"
    profile = tmp_path / "profile.toml"
    profile.write_text("[rectify]\nenabled = false\n[deflicker]\nsize_px = 16\n")    # not calibrated
    for args in (("scan", "--port", "instant", "--camera", "instant", "--grid", "3x2", "--out", out),
                 ("process", out, "--workers", "0", "--profile", profile),
                 ("export", out, "--format", "png", "--out", export)):
        proc = run_cli(*args, preexec_fn=umask)
        assert proc.returncode == 0, proc.stderr
    profile.chmod(0o664)                          # written by the test, not by lfstudio
    assert len(list((out / "processed").iterdir())) == 6 and len(list(export.rglob("*.png"))) == 6
    modes = {str(p.relative_to(tmp_path)): p.stat().st_mode & 0o777 for p in tmp_path.rglob("*")
             if p.is_file() and p.name != "dataset.lock"}
    assert modes and all(mode == 0o664 for mode in modes.values()), {k: oct(v) for k, v in modes.items() if v != 0o664}


def test_a_scan_refuses_a_dataset_lock_that_is_a_symlink_and_empties_nothing(scanned, outside, run_cli):
    root = scanned(3, 2)
    set_pending(root, {(1, 2)})
    (root / "dataset.lock").unlink(missing_ok=True)
    os.symlink(outside.path / "keep.txt", root / "dataset.lock")     # a link the path guard would let by...
    proc = run_cli("scan", "--resume", "--out", root, "--port", "instant", "--camera", "instant")
    assert_one_line_error(proc, 1, "dataset.lock", "not an ordinary file")
    assert outside.unchanged(), "the lock emptied the file its symlink points to"


def test_export_overwrite_never_deletes_a_folder_of_other_files(tiny_dataset, tmp_path, run_cli):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("years of work\n")
    proc = run_cli("export", tiny_dataset.root, "--format", "png", "--out", out, "--overwrite")
    assert_one_line_error(proc, 2, str(out), "thesis.tex", "--overwrite replaces only an earlier export")
    assert (out / "thesis.tex").read_text() == "years of work\n" and [p.name for p in out.iterdir()] == ["thesis.tex"]
    again = run_cli("export", tiny_dataset.root, "--format", "png", "--out", tmp_path / "ex")
    assert again.returncode == 0, again.stderr
    replaced = run_cli("export", tiny_dataset.root, "--format", "png", "--out", tmp_path / "ex", "--overwrite")
    assert replaced.returncode == 0, replaced.stderr                     # an earlier export is replaced


NOT_UTF8 = os.fsdecode(b"d\xe9j\xe0")          # Latin-1 'déjà': surrogate escapes in Python, crashed OpenCV


@pytest.mark.parametrize("command", ["info", "check", "process", "export", "export --out", "scan --out"])
def test_a_folder_name_that_is_not_utf8_is_refused_by_name_not_a_crash(command, scanned, tmp_path, run_cli):
    root = tmp_path / NOT_UTF8
    shutil.copytree(scanned(3, 2), root, symlinks=True)
    args = {"info": ("info", root), "check": ("check", root), "process": ("process", root),
            "export": ("export", root, "--format", "png", "--out", tmp_path / "ex"),
            "export --out": ("export", scanned(3, 2), "--format", "png", "--out", tmp_path / NOT_UTF8 / "ex"),
            "scan --out": ("scan", "--port", "instant", "--camera", "instant", "--grid", "2x1",
                           "--out", tmp_path / NOT_UTF8 / "new")}[command]
    proc = run_cli(*args)
    assert proc.returncode == 2, (proc.returncode, proc.stderr)            # not -11 (SIGSEGV)
    assert "UnicodeEncodeError" not in proc.stderr
    assert_one_line_error(proc, 2, "d\\xe9j\\xe0", "not valid UTF-8", "rename")
    assert not (tmp_path / "ex").exists() and not (root / "new").exists()
