"""Light fields from other rigs and archives (issue 27): sheared views, recorded positions, HCI folders.

1. A virtual-studio capture (known depths) sheared to zero planes at 2.5, 3.0 and 4.0 m, imported
   (a) with the zero plane stated: the recorded zero-plane depth, check's depth range against the
   truth, views failing on position; (b) without it: sheared recognised?, the measured signed
   disparity range against the truth and the bound on the zero plane the negative disparities prove.
2. The real Stanford "Chess" 5 × 5 (../shared/data, skipped when absent) with the positions its file
   names record: views failing on position, the signed disparity range (zero inside it?), per-view
   position errors against the recorded positions (RMS per axis) and against a regular grid.
3. HCI round trip (parallel and sheared): geometry of the export, of the folder imported back and
   exported again (grid, baseline, focal length, focus distance, disparity range), largest difference.

    ./.venv/bin/python benchmarks/sheared_import.py [--width 640] [--zero-planes 2.5,3.0,4.0]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lfstudio.dataset import Dataset  # noqa: E402
from lfstudio.dataset.zero_plane import zero_plane  # noqa: E402
from lfstudio.export import ExportOptions, export_dataset  # noqa: E402
from lfstudio.export.import_images import ImportOptions, import_images  # noqa: E402
from lfstudio.quality import check_dataset  # noqa: E402
from lfstudio.quality.positions import position_errors  # noqa: E402
from lfstudio.quality.shear import measure_shear  # noqa: E402
from lfstudio.sim.virtual_dataset import load_ground_truth, make_virtual_dataset  # noqa: E402
from tests.export.test_sheared_import import STANFORD, _hci_geometry, shear_views  # noqa: E402


def position_fails(doc) -> int:
    return sum(1 for v in doc["views"] if v["checks"].get("position", {}).get("verdict") == "fail")


def virtual(base: Path, width: int, planes: list[float]) -> None:
    root = base / "virtual"
    make_virtual_dataset(root, 5, 5, spacing_mm=(4.0, 6.0), width_px=width, fmt="png", seed=7)
    truth = load_ground_truth(root)
    print(f"virtual capture 5 x 5, {width} px, depths {truth['near_m']:.3f} – {truth['far_m']:.3f} m")
    for z0 in planes:
        f_px, _ = shear_views(root, base / f"sheared_{z0}", z0)
        k = f_px * 4.0 / 1000.0
        want = (k * (1 / truth["far_m"] - 1 / z0), k * (1 / truth["near_m"] - 1 / z0))
        for stated in (True, False):
            t0 = time.perf_counter()
            ds = Dataset.open(import_images(ImportOptions(
                folder=base / f"sheared_{z0}", out=base / f"ds_{z0}_{stated}", grid=(5, 5), spacing_mm=(4.0, 6.0),
                focal_length_px=f_px, zero_disparity_depth_m=z0 if stated else None, measure=measure_shear)))
            t_import = time.perf_counter() - t0
            zp = zero_plane(ds)
            doc = check_dataset(ds, write=False).document
            depth = doc["depth_range"]
            if stated:
                near, far = depth.get("near_m"), depth.get("far_m")
                print(f"  zero plane {z0:.1f} m stated: recorded {zp.depth_m:.4f} m ({(zp.depth_m / z0 - 1) * 100:+.2f} %), "
                      f"check depth {near:.3f} – {far:.3f} m (near {(near / truth['near_m'] - 1) * 100:+.2f} %, "
                      f"far {(far / truth['far_m'] - 1) * 100:+.2f} %), zero plane inside: "
                      f"{depth['zero_disparity'].get('inside_range')}, views failing on position: {position_fails(doc)}"
                      f" (import {t_import:.1f} s)")
            else:
                m = zp.measured
                print(f"  zero plane {z0:.1f} m not stated: sheared recognised {m['sheared']}, measured signed "
                      f"disparity {m['step_disparity_px'][0]:+.3f} … {m['step_disparity_px'][1]:+.3f} px per step "
                      f"(truth {want[0]:+.3f} … {want[1]:+.3f}), zero plane nearer than {m['depth_max_m']:.2f} m "
                      f"(true {z0:.1f} m; depth itself not observable), check depth: {depth['verdict']}, "
                      f"views failing on position: {position_fails(doc)}")


def stanford(base: Path) -> None:
    if not STANFORD.is_dir():
        print("Stanford Chess: ../shared/data not present, skipped")
        return
    ds = Dataset.open(import_images(ImportOptions(folder=STANFORD, out=base / "chess", grid=(5, 5), spacing_mm=None,
                                                  positions="names", focal_length_px=1400.0, measure=measure_shear)))
    zp = zero_plane(ds)
    doc = check_dataset(ds, write=False).document
    depth = doc["depth_range"]
    views = doc["views"]
    cells = [(v["row"], v["column"]) for v in views]
    measured = np.array([v["checks"]["position"]["measured_mm"] for v in views])
    rec = {(v["row"], v["column"]): v for v in ds.views}
    print(f"Stanford Chess 5 x 5 (positions from the file names): {zp.describe()}")
    print(f"  rows reversed: {zp.measured['rows_reversed']}, signed disparity {depth['views_disparity_min_px']:+.3f} … "
          f"{depth['views_disparity_max_px']:+.3f} px per step (zero inside: "
          f"{depth['views_disparity_min_px'] < 0 < depth['views_disparity_max_px']}), views failing on position: "
          f"{position_fails(doc)} of {len(views)}, logged repeatability "
          f"{ds.manifest['import']['positions']['logged_repeatability_um']} µm")
    for name, key in (("recorded positions", "reported_mm"), ("regular grid", "commanded_mm")):
        ref = np.array([rec[c][key] for c in cells], float)
        err, _, _ = position_errors(ref, measured)
        rms = np.sqrt((err ** 2).mean(axis=0))
        print(f"  measured against the {name}: RMS x {rms[0] * 1000:.0f} µm, y {rms[1] * 1000:.0f} µm, "
              f"largest {np.hypot(*err.T).max() * 1000:.0f} µm")


def hci_round_trip(base: Path, width: int) -> None:
    from lfstudio.cli import main

    root = base / "virtual"
    for label, z0 in (("parallel", None), ("sheared 3.0 m", 3.0)):
        if z0 is None:
            ds = Dataset.open(root)
        else:
            f_px, _ = shear_views(root, base / "hci_sheared", z0)
            ds = Dataset.open(import_images(ImportOptions(folder=base / "hci_sheared", out=base / "hci_ds",
                                                          grid=(5, 5), spacing_mm=(4.0, 6.0), focal_length_px=f_px,
                                                          zero_disparity_depth_m=z0, measure=measure_shear)))
        a, b, c = base / f"hci_a_{z0}", base / f"hci_back_{z0}", base / f"hci_c_{z0}"
        export_dataset(ds, ExportOptions(format="hci", out=a, hci_size=(5, 5)))
        main(["import-images", str(a), "--out", str(b)])
        export_dataset(Dataset.open(b), ExportOptions(format="hci", out=c, hci_size=(5, 5)))
        g1, g2 = _hci_geometry(a), _hci_geometry(c)
        diffs = {k: abs(g2[k] / g1[k] - 1) * 100 for k in ("baseline_mm", "focal_px", "focus_m")}
        diffs["disp_min"] = abs(g2["disp"][0] - g1["disp"][0]) / max(abs(g1["disp"][0]), 1e-9) * 100
        diffs["disp_max"] = abs(g2["disp"][1] - g1["disp"][1]) / max(abs(g1["disp"][1]), 1e-9) * 100
        print(f"HCI round trip ({label}): grid {g1['grid']} → {g2['grid']}, focus {g1['focus_m']:g} → {g2['focus_m']:g} m, "
              f"disp {g1['disp'][0]:+.4f} … {g1['disp'][1]:+.4f} → {g2['disp'][0]:+.4f} … {g2['disp'][1]:+.4f} px; "
              "largest difference " + ", ".join(f"{k} {v:.3f} %" for k, v in diffs.items()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--zero-planes", default="2.5,3.0,4.0")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp)
        virtual(base, args.width, [float(v) for v in args.zero_planes.split(",")])
        stanford(base)
        hci_round_trip(base, args.width)


if __name__ == "__main__":
    main()
