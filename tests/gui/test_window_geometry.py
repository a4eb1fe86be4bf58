"""A window geometry remembered on one screen, opened on another (issue 41, item 7): after a session on
1920 x 1080 the next start on a 1366 x 768 laptop opened a 1500 x 950 window, the Scan panel and the
bottom rows off-screen. Each start runs in a process of its own on an offscreen screen of that size,
with the same settings folder."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from tests.conftest import REPO_ROOT

SESSION = """
import json, sys
from PySide6.QtWidgets import QApplication
app = QApplication([])
from lfstudio.gui.app import create_window
window = create_window(simulated=False)
window.show()
for _ in range(40):                 # the first layout (and a restored one's check) run from zero-time timers
    app.processEvents()
if len(sys.argv) > 1:                                   # the operator makes it large, then quits
    x, y, w, h = map(int, sys.argv[1].split(","))
    window.setGeometry(x, y, w, h)
    for _ in range(10):
        app.processEvents()
free = window.screen().availableGeometry()
print(json.dumps({"free": free.getRect(), "frame": window.frameGeometry().getRect(),
                  "geometry": window.geometry().getRect()}))
window.close()
"""


def _start(tmp_path, screen, *args):
    config = tmp_path / f"screen-{screen[0]}.json"
    config.write_text(json.dumps({"screens": [{"name": "s", "x": 0, "y": 0, "width": screen[0], "height": screen[1],
                                               "logicalDpi": 96, "logicalBaseDpi": 96, "dpr": 1}]}))
    env = {**os.environ, "QT_QPA_PLATFORM": f"offscreen:configfile={config}",
           "PYTHONPATH": str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    out = subprocess.run([sys.executable, "-c", SESSION, *args], capture_output=True, text=True, env=env,
                         timeout=120, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("saved", ["40,60,1800,1000", "300,200,1500,950"])
def test_a_geometry_from_a_large_screen_fits_the_small_one(tmp_path, saved):
    big = _start(tmp_path, (1920, 1080), saved)
    assert big["geometry"][2:] == [int(v) for v in saved.split(",")[2:]]        # the large screen kept it
    small = _start(tmp_path, (1366, 768))
    sx, sy, sw, sh = small["free"]
    x, y, w, h = small["frame"]
    assert (sw, sh) == (1366, 768)
    assert sx <= x and sy <= y and x + w <= sx + sw and y + h <= sy + sh, small
    again = _start(tmp_path, (1920, 1080))          # back on the large screen: the size it was given there
    assert again["geometry"][2] <= 1920 and again["geometry"][3] <= 1080


def test_a_geometry_that_fits_is_kept(tmp_path):
    first = _start(tmp_path, (1920, 1080), "100,80,1200,800")
    second = _start(tmp_path, (1920, 1080))
    assert second["geometry"] == first["geometry"]
