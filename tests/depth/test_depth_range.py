"""Where ``depth`` takes its disparity range from (issue 37): a stated range, the format's own (an
HCI folder's disp_min/disp_max), the plan, the check's or the import's tracks; printed with its
origin, never measured from one pair of views."""

from __future__ import annotations

import pytest

from lfstudio.cli import main
from lfstudio.dataset import Dataset
from lfstudio.depth.run import estimate_depth, parse_disparity_range, read_disparity
from lfstudio.errors import InputError
from lfstudio.export.import_images import ImportOptions, import_images


def _hci_folder(tmp_path, disp=(-1.25, 2.5)):
    """A small HCI folder (a virtual capture exported as HCI) whose parameters.cfg states ``disp``."""
    import configparser

    from lfstudio.export import ExportOptions, export_dataset
    from lfstudio.sim.virtual_dataset import make_virtual_dataset

    make_virtual_dataset(tmp_path / "v", columns=5, rows=3, spacing_mm=(4.0, 4.0), width_px=320, fmt="png", seed=3)
    export_dataset(Dataset.open(tmp_path / "v"), ExportOptions(format="hci", out=tmp_path / "hci", hci_size=(5, 3)))
    cfg = configparser.ConfigParser()
    cfg.read(tmp_path / "hci" / "parameters.cfg")
    cfg["meta"]["disp_min"], cfg["meta"]["disp_max"] = str(disp[0]), str(disp[1])
    with open(tmp_path / "hci" / "parameters.cfg", "w") as f:
        cfg.write(f)
    return tmp_path / "hci"


def test_the_hci_folders_declared_range_is_searched_and_printed(tmp_path, capsys):
    folder = _hci_folder(tmp_path)
    ds_root = import_images(ImportOptions(folder=folder, out=tmp_path / "ds", grid=None, spacing_mm=None))
    ds = Dataset.open(ds_root)
    ds.manifest["plan"] = {k: v for k, v in (ds.manifest.get("plan") or {}).items() if k not in ("near_m", "far_m")}
    ds.save()
    assert main(["depth", str(ds_root), "--views", "r01_c002", "--workers", "0"]) == 0
    printed = capsys.readouterr().out
    assert "disparity range -1.25 … +2.50 px from parameters.cfg" in printed
    _, _, record = read_disparity(Dataset.open(ds_root), (1, 2))
    lo, hi = record["d_range_px"]
    assert -1.5 < lo <= -1.25 and 2.5 <= hi < 2.8
    assert record["d_range_source"].startswith("parameters.cfg")


def test_a_stated_range_wins_and_is_printed(tmp_path, capsys):
    folder = _hci_folder(tmp_path)
    ds_root = import_images(ImportOptions(folder=folder, out=tmp_path / "ds", grid=None, spacing_mm=None))
    assert main(["depth", str(ds_root), "--views", "r01_c002", "--workers", "0", "--disparity-range=-0.5,3"]) == 0
    printed = capsys.readouterr().out
    assert "disparity range -0.50 … +3.00 px from --disparity-range" in printed
    _, _, record = read_disparity(Dataset.open(ds_root), (1, 2))
    assert record["d_range_px"] == pytest.approx([-0.5, 3.0])


@pytest.mark.parametrize("text, says", [("3", "cannot read '3'"), ("a,b", "cannot read 'a,b' as two numbers"),
                                        ("2,1", "the minimum 2 is not below the maximum 1"),
                                        ("nan,1", "not a finite range"), ("0,5000", "spans more than 2000 px")])
def test_bad_ranges_are_refused_by_name(text, says):
    with pytest.raises(InputError, match="--disparity-range") as err:
        parse_disparity_range("--disparity-range", text)
    assert says in str(err.value)


def test_the_cli_refuses_a_bad_range_in_one_line_before_any_work(tmp_path, run_cli):
    folder = _hci_folder(tmp_path)
    ds_root = import_images(ImportOptions(folder=folder, out=tmp_path / "ds", grid=None, spacing_mm=None))
    done = run_cli("depth", str(ds_root), "--disparity-range=3,1")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "--disparity-range" in lines[0] and "not below" in lines[0], done.stderr
    assert not (ds_root / "depth").exists()


def test_without_a_plan_the_range_comes_from_matches_of_several_pairs_not_one(calibrated):
    """No plan, no check, no import record: matches pooled over the pairs of a star of views around
    the chosen one (near and far, both axes), never one pair's matches."""
    ds = calibrated
    ds.manifest["plan"] = {k: v for k, v in ds.manifest["plan"].items() if k not in ("near_m", "far_m")}
    ds.save()
    ds = Dataset.open(ds.root)
    report = estimate_depth(ds, "r01_c002")
    assert report.computed == 1 and "from feature matches of 6 pairs around r01_c002" in report.range_text, \
        report.range_text
    _, _, record = read_disparity(ds, (1, 2))
    from lfstudio.sim.virtual_dataset import read_truth_map

    truth = read_truth_map(ds.root, "disparity_rectified", 1, 2)
    lo, hi = record["d_range_px"]
    assert lo < float(truth.min()) + 0.1 and hi > float(truth.max()) - 0.1, (lo, hi, truth.min(), truth.max())
