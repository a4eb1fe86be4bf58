"""HCI benchmark folders are read as the format defines them (issue 37): the rows run top-down from
``input_Cam000`` whatever the image content suggests, and the folder's own disparity range
(``disp_min``/``disp_max``) is what ``depth`` searches."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from lfstudio.cli import main
from lfstudio.dataset import Dataset
from lfstudio.export.import_images import ImportOptions, import_images, import_summary
from lfstudio.quality.shear import measure_shear

ANTINOUS = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "lightfield" / "hci_antinous"


def _hci_upside_down(_virtual, tmp_path) -> Path:
    """An HCI folder whose files hold the rows bottom-up: the content says "reversed", the format
    says input_Cam000 is the top-left view."""
    from lfstudio.export import ExportOptions, export_dataset

    export_dataset(Dataset.open(_virtual), ExportOptions(format="hci", out=tmp_path / "hci", hci_size=(5, 5)))
    flipped = tmp_path / "flipped"
    flipped.mkdir()
    for r in range(5):
        for c in range(5):
            shutil.copy(tmp_path / "hci" / f"input_Cam{(4 - r) * 5 + c:03d}.png", flipped / f"input_Cam{r * 5 + c:03d}.png")
    shutil.copy(tmp_path / "hci" / "parameters.cfg", flipped / "parameters.cfg")
    return flipped


def test_hci_rows_come_from_the_format_not_from_the_image_content(tmp_path):
    from lfstudio.sim.virtual_dataset import make_virtual_dataset
    from tests.export.test_sheared_import import GRID

    virtual = tmp_path / "virtual"
    make_virtual_dataset(virtual, **GRID)
    folder = _hci_upside_down(virtual, tmp_path)
    ds = Dataset.open(import_images(ImportOptions(folder=folder, out=tmp_path / "ds", grid=None, spacing_mm=None,
                                                  measure=measure_shear)))
    measured = ds.manifest["zero_disparity"]["measured"]
    assert measured["rows_reversed"] is False and measured["rows_order"] == "format"
    # the content does suggest the other order (so a content guess would have turned the rows)
    assert measured.get("rows_content_suggested_reversed") is True
    for r in range(5):
        assert ds.view(r, 2)["source_file"] == f"input_Cam{r * 5 + 2:03d}.png"
    assert "rows          : as the HCI format defines them" in import_summary(ds)


def test_a_plain_folder_says_what_the_content_decided_about_the_rows(tmp_path):
    from lfstudio.sim.virtual_dataset import make_virtual_dataset
    from tests.export.test_sheared_import import GRID

    virtual = tmp_path / "virtual"
    make_virtual_dataset(virtual, **GRID)
    ds = Dataset.open(import_images(ImportOptions(folder=virtual / "raw", out=tmp_path / "ds", grid=(5, 5),
                                                  spacing_mm=(4.0, 6.0), measure=measure_shear)))
    assert ds.manifest["zero_disparity"]["measured"]["rows_order"] == "as numbered"
    assert "rows          : as numbered" in import_summary(ds)


needs_antinous = pytest.mark.skipif(not ANTINOUS.is_dir(), reason="../shared/data/lightfield/hci_antinous not present")


@needs_antinous
def test_antinous_imports_top_down_with_its_declared_disparity_range(tmp_path, capsys):
    assert main(["import-images", str(ANTINOUS), "--out", str(tmp_path / "antinous")]) == 0
    printed = capsys.readouterr().out
    assert "rows          : reversed" not in printed
    ds = Dataset.open(tmp_path / "antinous")
    assert ds.view(0, 0)["source_file"] == "input_Cam000.png" and ds.view(8, 0)["source_file"] == "input_Cam072.png"
    assert ds.manifest["import"]["hci"]["disparity_px"] == [-3.3, 2.8]
