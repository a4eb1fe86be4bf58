"""Every command that creates a dataset follows one folder rule (lfstudio.dataset.paths.check_new_dataset_folder),
run as the operator runs it (``python -m lfstudio`` in a subprocess):

- a missing or empty folder takes the new dataset;
- an existing dataset is refused unless the command's own option replaces it (``--overwrite``);
  ``virtual-dataset`` has none;
- a folder holding other files is refused (exit 2, one line naming the folder and a new sub-folder),
  ``--overwrite`` included, and nothing in it is changed.

Before this rule ``virtual-dataset`` wrote into such a folder (overwriting ``raw/r00_c000.png`` of the
operator's), and ``import-images``/``import-hevc --overwrite`` deleted the whole folder.
"""

from __future__ import annotations

import shutil

import pytest

from lfstudio.dataset import Dataset
from lfstudio.export import ExportOptions, export_dataset
from lfstudio.sim.virtual_dataset import make_virtual_dataset


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    """A 3 x 2 rendered dataset, its views as another rig's images, and its HEVC export."""
    base = tmp_path_factory.mktemp("sources")
    ds = make_virtual_dataset(base / "render", 3, 2, width_px=64, fmt="png")
    images = base / "images"
    images.mkdir()
    for i, v in enumerate(ds.views):
        shutil.copy(ds.path_of(v), images / f"shot{i + 1}.png")
    video = base / "lf.mkv"
    export_dataset(ds, ExportOptions("hevc", video))
    return {"images": images, "video": video}


def _command(kind: str, sources, out) -> list:
    if kind == "import-images":
        return ["import-images", sources["images"], "--grid", "3x2", "--spacing-mm", "4x6", "--out", out]
    return ["import-hevc", sources["video"], "--out", out]


def _operator_folder(path):
    """A folder of the operator's: a note and a file named like a view."""
    (path / "raw").mkdir(parents=True)
    (path / "notes.txt").write_text("precious")
    (path / "raw" / "r00_c000.png").write_bytes(b"not a view of ours")
    return path


def _untouched(path) -> bool:
    return (sorted(p.relative_to(path).as_posix() for p in path.rglob("*")) == ["notes.txt", "raw", "raw/r00_c000.png"]
            and (path / "notes.txt").read_text() == "precious"
            and (path / "raw" / "r00_c000.png").read_bytes() == b"not a view of ours")


def _refused(proc, *words) -> str:
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


@pytest.mark.parametrize("kind", ["import-images", "import-hevc"])
def test_import_follows_the_new_dataset_folder_rule(kind, sources, run_cli, tmp_path):
    mine = _operator_folder(tmp_path / "mine")
    for extra in ([], ["--overwrite"]):            # --overwrite used to delete the whole folder
        proc = run_cli(*_command(kind, sources, mine), *extra)
        _refused(proc, "--out", f"{mine} is not empty (notes.txt, raw)", f"e.g. {mine / 'lfstudio-import'}")
        assert _untouched(mine)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]           # no temporary folder left

    empty = tmp_path / "empty"
    empty.mkdir()
    proc = run_cli(*_command(kind, sources, empty))                          # used to need --overwrite
    assert proc.returncode == 0, proc.stderr
    assert Dataset.open(empty).status_counts()["done"] == 6
    _refused(run_cli(*_command(kind, sources, empty)), "--out", f"{empty} already holds a dataset", "--overwrite")
    (empty / "dataset.json").touch()                                          # replaced as a whole, not patched
    proc = run_cli(*_command(kind, sources, empty), "--overwrite")
    assert proc.returncode == 0, proc.stderr
    assert Dataset.open(empty).status_counts()["done"] == 6


def test_virtual_dataset_follows_the_new_dataset_folder_rule(run_cli, tmp_path):
    args = ["--grid", "2x1", "--width", "64", "--format", "png"]
    mine = _operator_folder(tmp_path / "mine")
    _refused(run_cli("virtual-dataset", mine, *args), "folder", f"{mine} is not empty (notes.txt, raw)",
             f"e.g. {mine / 'lfstudio-virtual'}")
    assert _untouched(mine)
    empty = tmp_path / "empty"
    empty.mkdir()
    proc = run_cli("virtual-dataset", empty, *args)
    assert proc.returncode == 0, proc.stderr
    assert Dataset.open(empty).status_counts()["done"] == 2
    _refused(run_cli("virtual-dataset", empty, *args), "folder", f"{empty} already holds a dataset")


def _dataset_files(path) -> dict:
    return {p.relative_to(path).as_posix(): p.read_bytes() for p in sorted(path.rglob("*"))
            if p.is_file() and p.name != "dataset.lock"}


@pytest.mark.parametrize("kind", ["import-images", "import-hevc"])
def test_import_never_replaces_a_dataset_a_running_scan_holds(kind, sources, run_cli, tmp_path):
    """A dataset whose dataset.lock another process holds (a running scan) is refused, --overwrite included:
    one line naming the folder, the holder's pid and what it does, and the fix; nothing in it changes.
    Once that process is gone (killed: its holder line stays in the file), its stale lock blocks nothing."""
    from tests.support.test_locks import hold_in_child

    ds = tmp_path / "ds"
    ds.mkdir()
    assert run_cli(*_command(kind, sources, ds)).returncode == 0
    (ds / "dataset.json").write_text((ds / "dataset.json").read_text() + "\n")   # to tell it from a new import
    before = _dataset_files(ds)
    starting = tmp_path / "starting"              # a scan that holds its new folder's lock, nothing else yet
    starting.mkdir()
    child = hold_in_child("dataset_lock", ds)
    second = hold_in_child("dataset_lock", starting)
    try:
        for out, extra in ((ds, ["--overwrite"]), (starting, [])):
            proc = run_cli(*_command(kind, sources, out), *extra)
            assert proc.returncode == 1, proc.stderr
            lines = proc.stderr.strip().splitlines()
            assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
            holder = child if out == ds else second
            for words in (f"dataset {out} is in use by", f"pid {holder.pid}", "testing the lock",
                          "stop that scan", "choose another folder"):
                assert words in lines[0], lines[0]
        assert _dataset_files(ds) == before and sorted(p.name for p in starting.iterdir()) == ["dataset.lock"]
    finally:
        for proc in (child, second):
            proc.kill()                    # kill -9: the holder line stays in dataset.lock
            proc.wait(10)
            proc.stdin.close()
            proc.stdout.close()
    assert f'"pid": {child.pid}' in (ds / "dataset.lock").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "starting"]       # no temporary folder left

    proc = run_cli(*_command(kind, sources, ds), "--overwrite")      # a stale lock: replaced
    assert proc.returncode == 0, proc.stderr
    assert _dataset_files(ds) != before and Dataset.open(ds).status_counts()["done"] == 6
    proc = run_cli(*_command(kind, sources, starting))               # a stale lock alone: an empty folder
    assert proc.returncode == 0, proc.stderr
    assert "meanwhile" not in proc.stderr and Dataset.open(starting).status_counts()["done"] == 6
