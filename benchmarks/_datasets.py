"""Helpers shared by the scan benchmarks: instant devices, a timed engine run, a captured dataset."""

from __future__ import annotations

import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from lfstudio.rig.profile import load_rig  # noqa: E402
from lfstudio.scan.engine import ScanEngine  # noqa: E402
from lfstudio.scan.events import ScanState  # noqa: E402
from lfstudio.scan.scan_plan import ScanPlan  # noqa: E402
from lfstudio.sim.instant import InstantCamera, InstantRig  # noqa: E402
from lfstudio.studio.devices import open_studio  # noqa: E402
from lfstudio.studio.session import create_scan_dataset  # noqa: E402


def instant_devices(rig_cfg, render=None):
    """A connected :class:`InstantRig` and an :class:`InstantCamera` that photographs from its position."""
    rig = InstantRig(rig_cfg)
    rig.connect()
    cam = InstantCamera(rig.true_position_mm, render=render)
    cam.connect()
    return rig, cam


@contextmanager
def studio_scan(rig_word: str, plan: ScanPlan, rig_cfg, *, scale: float, exposure_s: float, transfer_s: float,
                width_px: int):
    """``(engine, dataset, trigger_s)``: the simulated studio (camera ``sim``, rig ``rig_word``) with
    the rig already at the plan's first view (the approach from home is not part of a scan), a new
    dataset in a temporary folder and an engine on them; all closed and removed afterwards."""
    with tempfile.TemporaryDirectory() as tmp, \
            open_studio(rig_word, "sim", rig_cfg, time_scale=scale, exposure_s=exposure_s, transfer_s=transfer_s,
                        view_region_mm=plan.extent_mm(), sim_width_px=width_px) as sim:
        first = plan.views()[0]
        sim.rig.move_to(first.x_mm, first.y_mm)
        ds = create_scan_dataset(Path(tmp) / "ds", plan, rig={"name": rig_cfg.name}, camera={"name": "sim"},
                                 lens={"name": "virtual"})
        yield ScanEngine(ds, plan, sim.rig, sim.camera, time_scale=scale), ds, sim.camera.trigger_s


def view_periods(engine: ScanEngine) -> list:
    """The list every finished view's period (s, the engine's own timing) is appended to."""
    from lfstudio.scan.events import EventKind

    periods = []
    engine.subscribe(lambda ev: periods.append(ev.timings_s.get("period")) if ev.kind is EventKind.VIEW_DONE else None)
    return periods


def timed_scan(engine: ScanEngine) -> float | None:
    """Run ``engine`` to its end: the wall time in seconds, or None (after printing why) when the
    scan did not finish."""
    t = time.perf_counter()
    engine.start()
    state = engine.wait()
    total_s = time.perf_counter() - t
    if state is not ScanState.FINISHED:
        print(f"scan did not finish: {engine.message}")
        return None
    return total_s


def studio_renderer(plan: ScanPlan, width_px: int = 192):
    """Render the virtual studio (small) from a position of ``plan``'s grid."""
    from lfstudio.sim.studio import VirtualStudio

    studio = VirtualStudio(width_px=width_px, view_region_mm=(0.0, max((plan.columns - 1) * plan.spacing_mm[0], 1.0),
                                                               0.0, max((plan.rows - 1) * plan.spacing_mm[1], 1.0)))
    x0, y0 = plan.origin_mm

    def render(x_mm: float, y_mm: float) -> np.ndarray:
        rgb = studio.render(x_mm - x0, y_mm - y0)
        return (np.clip(rgb, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)
    return render


def captured_dataset(root: Path, columns: int = 101, rows: int = 21, studio: bool = True):
    """A fully captured ``columns`` x ``rows`` dataset at ``root`` (reused when it is already there)."""
    from lfstudio.dataset import Dataset

    if (root / "dataset.json").is_file():
        ds = Dataset.open(root)
        if ds.status_counts()["done"] == columns * rows:
            return ds
    rig_cfg = load_rig()
    plan = ScanPlan.centered(columns, rows, (4.0, 6.0), rig_cfg, settle_s=0.0)
    ds = create_scan_dataset(root, plan, rig={"name": rig_cfg.name}, camera={"name": "instant"},
                             lens={"name": "virtual 50 mm", "focal_length_mm": 50.0}) \
        if not (root / "dataset.json").is_file() else Dataset.open(root)
    rig, cam = instant_devices(rig_cfg, render=studio_renderer(plan) if studio else None)
    engine = ScanEngine(ds, plan, rig, cam, time_scale=0.0)
    engine.start()
    if engine.wait() is not ScanState.FINISHED:
        raise RuntimeError(engine.message)
    return ds
