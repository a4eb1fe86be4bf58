"""The README says what the software does in a few minutes' reading: its library lists, its links into
the documentation; the tutorial's walk-through numbers follow from the image width it sets."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: Qt's xcb platform plugin needs these on a real X11 screen (checked under Xvfb, see FACTS)
XCB_LIBS = ("libxcb-cursor0", "libxcb-icccm4", "libxcb-image0", "libxcb-keysyms1", "libxcb-render-util0",
            "libxcb-shape0", "libxkbcommon-x11-0")
#: the tutorial's walk-through (it was the README's "A day in the studio")
DAY = ROOT / "docs" / "tutorial" / "day-in-the-studio.md"


def _readme() -> str:
    return (ROOT / "README.md").read_text(encoding="utf-8")


def _section(text: str, heading: str) -> str:
    start = text.index(heading)
    level = heading.split(" ", 1)[0]
    end = re.search(rf"^{level} ", text[start + len(heading):], re.M)
    return text[start:start + len(heading) + (end.start() if end else len(text))]


def test_quick_start_lists_the_libraries_the_rest_of_the_readme_refers_to():
    text = _readme()
    quick = " ".join(_section(text, "## Quick start").split())
    setup = (ROOT / "tools" / "setup-env.sh").read_text()
    checked = re.findall(r"lib[\w.+-]*\.so\.\d+:([\w.+-]+)", setup)
    assert len(checked) == 6 and all(pkg in quick for pkg in checked), checked
    if "X11 ones listed in the Quick start" in " ".join(text.split()):
        missing = [lib for lib in XCB_LIBS if lib not in quick]
        assert not missing, f"the README refers to X11 libraries listed in the Quick start: {missing}"


def test_the_readme_is_short_keeps_the_two_commands_and_its_links_lead_to_files():
    text = _readme()
    assert len(text.splitlines()) <= 150
    assert "./run.sh " in text and "./test.sh " in text and "./test.sh -m fast" in text
    targets = [t for t in re.findall(r"\]\(([^)\s]+)\)", text) if "://" not in t]
    assert len(targets) >= 20
    missing = [t for t in targets if not (ROOT / t.split("#")[0]).exists()]
    assert not missing, missing


def test_walk_through_image_sizes_follow_from_the_image_width_it_sets():
    from lfstudio.dataset.profile import Profile
    from lfstudio.processing.steps.resample import output_size
    from lfstudio.sim.studio import VirtualStudio

    day = " ".join(DAY.read_text(encoding="utf-8").split())
    width = int(re.search(r"\*Image width\* (\d+) px", day).group(1))
    estimate = re.search(r"estimate line \(27 views · (\d+) × (\d+) px", day)
    assert estimate, "the export step quotes the estimate line"
    studio = VirtualStudio(width_px=width)
    scale = Profile().resample.scale
    assert tuple(map(int, estimate.groups())) == output_size((studio.width_px, studio.height_px), scale)
    default = VirtualStudio()                          # what the Camera panel starts with
    w2, h2 = output_size((default.width_px, default.height_px), scale)
    assert f"{w2} × {h2} px from {default.width_px} px images" in day
