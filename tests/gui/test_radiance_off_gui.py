"""HDR radiance of a view…: the picture at a slider position is made off the GUI thread, the latest
position winning (it was made on the GUI thread for up to 2000 px per step: 92–302 ms under load).
A real dialog in a real Qt loop, a real dataset; the radiance is a 2000 × 1200 float image handed to
the dialog as its loader would (the merge itself: tests/gui/test_hdr_and_fit_gui.py)."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np

from lfstudio.gui.imageutil import qimage_to_rgb
from lfstudio.gui.views import radiance as radiance_view
from lfstudio.gui.views.radiance import RadianceDialog

HANG_GUARD_S = 30.0


def _data() -> dict:
    import cv2

    rng = np.random.default_rng(3)
    radiance = (rng.random((1200, 2000, 3), dtype=np.float32) * 4.0).astype(np.float32)
    preview = cv2.resize(radiance, (400, 240), interpolation=cv2.INTER_AREA)
    return {"radiance": radiance, "preview": preview, "key": 1.0,
            "figures": {"file": "hdr/r00_c000.exr", "size": (2000, 1200), "min": 0.0, "median": 2.0, "max": 4.0,
                        "clipped_merged": None}}


def test_the_exposure_is_made_off_the_gui_thread_and_the_latest_position_wins(qtbot, make_dataset, monkeypatch):
    ds = make_dataset()
    calls: list[tuple[bool, float]] = []          # (on the GUI thread, ev) of each exposed() call
    gate = threading.Event()
    real = radiance_view.exposed

    def watched(radiance, key, ev):
        calls.append((threading.current_thread() is threading.main_thread(), float(ev)))
        if len(calls) == 1:
            gate.wait(HANG_GUARD_S)                # the first picture takes long: the slider moves on meanwhile
        return real(radiance, key, ev)

    monkeypatch.setattr(radiance_view, "exposed", watched)
    dialog = RadianceDialog(SimpleNamespace(dataset=ds), view=(0, 0))
    qtbot.addWidget(dialog)
    dialog.show()
    qtbot.waitUntil(lambda: "no merged radiance" in dialog.caption.text(), timeout=30000)   # nothing merged here
    try:
        dialog._loaded(_data())                     # what the loader hands over: the picture at 0 EV is asked for
        qtbot.waitUntil(lambda: len(calls) == 1, timeout=30000)
        for value in (10, 20, 30):                  # +1, +2, +3 EV while the first picture is being made
            dialog.slider.setValue(value)
            dialog._expose()
    finally:
        gate.set()
    qtbot.waitUntil(lambda: "+3.0 EV" in dialog.caption.text() and dialog.image.pixmap().width() == 2000,
                    timeout=30000)
    assert not [ev for on_gui, ev in calls if on_gui]                  # never on the GUI thread
    evs = {round(ev, 1) for _, ev in calls}
    assert evs <= {0.0, 3.0} and 3.0 in evs                            # +1 and +2 EV were never made
    assert (3.0, True) in [(round(ev, 1), final) for ev, final in dialog.exposer.made]
    shown = qimage_to_rgb(dialog.image.pixmap().toImage())
    assert shown.shape[:2] == (1200, 2000)                             # the refined picture, at the shown size
    expected = real(_data()["radiance"], 1.0, 3.0)
    assert np.array_equal(shown, expected)
    dialog.close()
