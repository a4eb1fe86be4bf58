"""One definition of "disparity" in every view (issue 41, item 10): the import summary, the check on
the command line, its HTML report, the Disparity window and the depth map each name the reference
(from infinity, or relative to the zero-disparity plane) and the statistic; numbers meaning the same
thing are written by one function, so they agree; the repeatability's source is told alike by the
command line and the report, and truly. The Stanford "Chess" capture (sheared, its plane not stated)
runs when ../shared/data holds it."""

from __future__ import annotations

import html
import re
import shutil
from pathlib import Path

import pytest

from lfstudio.cli import main
from lfstudio.cli.check import format_report
from lfstudio.dataset import Dataset
from lfstudio.dataset.zero_plane import ZeroPlane
from lfstudio.quality import check_dataset

STANFORD = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "lightfield" / "stanford_chess_5x5"
NEIGHBOURS = "between horizontal neighbours, "


def _text_of(report_html: Path) -> str:
    return " ".join(html.unescape(re.sub("<[^>]+>", " ", report_html.read_text(encoding="utf-8"))).split())


def test_the_reference_of_a_disparity_in_words():
    assert ZeroPlane(0.0, None).disparity_reference() == "from infinity"
    assert ZeroPlane(1.1667, 1.2, "--zero-disparity-depth-m").disparity_reference() == \
        "relative to the zero-disparity plane at 1.20 m"
    assert ZeroPlane(None, None, "measured-sheared").disparity_reference() == \
        "relative to the zero-disparity plane (its depth not stated)"
    assert ZeroPlane(0.0, None).disparity_words() == "between horizontal neighbours, from infinity"


def test_a_parallel_scan_s_disparities_are_from_infinity_in_the_check_and_its_report(tiny_dataset, qtbot):
    from lfstudio.gui.views.quality import DisparityDialog
    from lfstudio.quality.summaries import disparity_map_summary, disparity_summary

    report = check_dataset(tiny_dataset)
    doc = report.document
    printed = format_report(doc)
    line = next(ln for ln in printed.splitlines() if ln.startswith("disparity     "))
    assert NEIGHBOURS + "from infinity (tracked points)" in line, line
    page = _text_of(tiny_dataset.root / "quality" / "report.html")
    assert disparity_summary(doc["depth_range"]) in page                    # the same numbers and words
    assert disparity_summary(doc["depth_range"]) in printed
    assert disparity_map_summary(doc["disparity_map"], doc["depth_range"]) in page
    assert "1st–99th percentile of the map" in page and NEIGHBOURS + "from infinity" in page
    assert "repeatability_um" in tiny_dataset.manifest.get("plan", {}) or doc["repeatability"]["planned_from"] != "logged"
    dialog = DisparityDialog(tiny_dataset.root / doc["pictures"]["disparity"], doc["disparity_map"],
                             depth=doc["depth_range"])
    qtbot.addWidget(dialog)
    assert disparity_map_summary(doc["disparity_map"], doc["depth_range"]) in dialog.caption.text()


def test_the_repeatability_s_source_is_told_alike_and_truly(tiny_dataset):
    from lfstudio.quality.summaries import REPEATABILITY_SOURCES, repeatability_summary

    doc = check_dataset(tiny_dataset).document
    rep = doc["repeatability"]
    has_plan = (tiny_dataset.manifest.get("plan") or {}).get("repeatability_um") is not None
    assert rep["planned_from"] == ("plan" if has_plan else "default")      # a scan logs no positions of its own
    words = REPEATABILITY_SOURCES[rep["planned_from"]]
    assert words in format_report(doc) and words in _text_of(tiny_dataset.root / "quality" / "report.html")
    assert repeatability_summary(rep) in _text_of(tiny_dataset.root / "quality" / "report.html")


@pytest.mark.skipif(not STANFORD.is_dir(), reason="../shared/data/lightfield/stanford_chess_5x5 not present")
def test_stanford_chess_every_view_names_the_zero_plane(tmp_path, capsys):
    """Five different ranges, all 'between horizontal neighbours', none saying from where; the report
    said 'planned' where the command line said 'logged by the rig'."""
    out = tmp_path / "chess"
    assert main(["import-images", str(STANFORD), "--grid", "5x5", "--positions", "names", "--focal-length-px", "1400",
                 "--out", str(out)]) == 0
    imported = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("disparity"))
    plane = "relative to the zero-disparity plane (its depth not stated)"
    assert NEIGHBOURS + plane in imported, imported
    ds = Dataset.open(out)
    assert main(["check", str(out)]) == 0
    printed = capsys.readouterr().out
    page = _text_of(out / "quality" / "report.html")
    for text in (printed, page):
        assert "logged by the rig" in text and "planned 247" not in text
        assert f"{NEIGHBOURS}{plane} (tracked points)" in text
        assert "from infinity" not in text.replace("0 px is infinitely far", "")   # nothing claims it
    ours = next(ln for ln in printed.splitlines() if ln.startswith("disparity     ")).split("disparity", 1)[1].strip()
    assert ours in page                                                   # the same numbers in both
    ds.close()
    shutil.rmtree(out / "quality")
