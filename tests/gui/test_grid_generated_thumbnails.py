"""The grid shows a dataset without stored thumbnails (imported, rendered) from its view files and
keeps the thumbnails it made in the dataset, so the next opening reads them from there."""

from __future__ import annotations

import cv2
import numpy as np

from lfstudio.dataset import Dataset
from lfstudio.gui.state import AppState
from lfstudio.gui.views.grid_view import GridView
from lfstudio.dataset import thumbs


def imported(root, columns=4, rows=2) -> Dataset:
    ds = Dataset.create(root, camera={"name": "other rig"}, lens={"name": "l"},
                        grid={"columns": columns, "rows": rows, "spacing_mm": [4.0, 6.0]})
    for v in ds.views:
        rel = ds.raw_name(v["row"], v["column"], ".png")
        img = np.zeros((300, 400, 3), np.uint16)
        img[:, :200, 2] = 30000 + 3000 * v["column"]      # 16-bit linear: red left half
        img[:, 200:, 1] = 20000
        cv2.imwrite(str(ds.root / rel), img)
        v.update(file=rel, status="done")
    ds.save()
    return Dataset.open(root)


def test_grid_fills_from_view_files_and_caches_what_it_made(qtbot, tmp_path):
    ds = imported(tmp_path / "ds")
    state = AppState()
    view = GridView(state)
    qtbot.addWidget(view)
    view.resize(700, 400)
    view.show()
    state.set_dataset(ds)
    canvas = view.canvas
    qtbot.waitUntil(lambda: canvas._mosaic_has.all(), timeout=10000)
    thumbs._filler.wait()
    cached = sorted((ds.root / "thumbs" / "generated").iterdir())
    assert len(cached) == 8 and all(p.stat().st_size > 0 for p in cached)
    img = canvas.viewport().grab().toImage()
    r = canvas._cell_rect(1, 0)
    left = img.pixelColor(r.left() + r.width() // 4, r.center().y())
    assert left.red() > 150 and left.green() < 80, left.name()    # the view's own colours
