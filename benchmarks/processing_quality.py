"""Processing quality against the virtual studio's ground truth, for each demosaic/resample path.

Renders a 4000 px virtual-studio DNG dataset (noise, flicker, vignetting, a rotated camera; cached
in /tmp), processes it once per candidate path with the colour levels off (so the output stays
linear and comparable), and compares every view with the truth: the studio's ideal camera rendered
at full resolution, area-averaged to the output size, times the reference view's illumination
(de-flicker matches every view to the reference). PSNR on the 16-bit scale over the inner 90 %
(the rectified borders are empty), one line per candidate, against the truth and never against
each other; and the CPU seconds per view of each run (inline, one thread, start-up included).

    ./.venv/bin/python benchmarks/processing_quality.py [--views 4] [--width 4000]

The default profile's path must score at least the former default's (AHD) PSNR.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from _measure import Timer, load_text  # noqa: E402
from _processing import default_profile, rendered  # noqa: E402


def candidates():
    """(label, profile or None, note): None marks the path no profile selects (computed here)."""
    def with_(**changes):
        p = default_profile()
        p.color.enabled = False
        for key, value in changes.items():
            step, _, name = key.partition("__")
            setattr(getattr(p, step), name, value)
        return p
    return [
        ("auto (default): luminance at full size, colour differences at half", with_(), ""),
        ("AHD at full size, warp, then area (the former default)", with_(debayer__demosaic="AHD"), ""),
        ("AHD at full size, area, then warp at half size", None, "(warp after downsampling; no PNG written)"),
        ("PPG at full size, warp, then area", with_(debayer__demosaic="PPG"), ""),
        ("DHT at full size, warp, then area", with_(debayer__demosaic="DHT"), ""),
        ("LibRaw half_size (2x2 blocks), warp at half size", with_(debayer__half_size=True), ""),
    ]


def area_first(ds, profile, views) -> dict:
    """AHD at full size, area-averaged to the output size, warped there; shading and the
    pipeline's own de-flicker gains of the AHD run."""
    from lfstudio.processing.pipeline import make_plan
    from lfstudio.dataset import images
    from lfstudio.processing.steps import rectify, resample, shading

    p = profile.copy()
    p.debayer.demosaic = "AHD"
    plan = make_plan(ds, p)
    out_w, out_h = plan.output_size_wh
    H = np.asarray(plan.homography, float)
    warp = rectify.build_maps((out_w, out_h), out_w / plan.full_size_wh[0], H, None)
    factor = shading.correction_from_model((out_w, out_h), plan.shading_coefficients or p.shading.coefficients)
    outs = {}
    for v, gain in views:
        img = resample.apply(images.develop(ds.path_of(v), p.debayer), (out_w, out_h))
        img = rectify.apply_maps(img, warp).astype(np.float32) * factor * gain
        outs[(v["row"], v["column"])] = img
    return outs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--width", type=int, default=4000)
    ap.add_argument("--root", default="/tmp/lfstudio-bench-quality")
    args = ap.parse_args()

    from lfstudio.dataset import Dataset
    from lfstudio.processing.pipeline import process_dataset, reference_view
    from lfstudio.processing.worker import _single_thread
    from lfstudio.sim.studio import VirtualStudio
    from lfstudio.sim.virtual_dataset import load_ground_truth

    _single_thread()
    cv2.setNumThreads(1)
    root = Path(args.root)
    ds = rendered(root, args.views, args.width)
    truth = load_ground_truth(root)
    w, h = truth["image_size_px"]
    print(f"{args.views} DNG views of {w} x {h} px (noise 0.002, flicker 3 %, vignetting 20 %, camera rotated "
          f"{truth['rotation_deg']} deg); {load_text()}", flush=True)
    studio = VirtualStudio(width_px=w, height_px=h, rotation_deg=tuple(truth["rotation_deg"]),
                           pp_offset_px=tuple(truth["pp_offset_px"]), view_region_mm=tuple(truth["view_region_mm"]),
                           seed=truth["seed"], near_m=truth["near_m"], far_m=truth["far_m"])
    gains = {(v["row"], v["column"]): v["gain"] for v in truth["views"]}
    ref = reference_view(ds, default_profile())
    ref_gain = gains[(ref["row"], ref["column"])]
    true_mm = {(v["row"], v["column"]): v["true_mm"] for v in truth["views"]}
    ideal = {}

    def truth_at(key, size_wh):
        if key not in ideal:
            img = studio.render(*true_mm[key], ideal=True)
            ideal[key] = cv2.resize(img, size_wh, interpolation=cv2.INTER_AREA).astype(np.float64) * 65535 * ref_gain
        return ideal[key]

    def psnr(outs: dict) -> tuple[float, list[float]]:
        mse, per_view = [], []
        for key, out in outs.items():
            t = truth_at(key, (out.shape[1], out.shape[0]))
            oh, ow = out.shape[:2]
            inner = (slice(oh // 20, oh - oh // 20), slice(ow // 20, ow - ow // 20))
            e = float(np.mean((out[inner].astype(np.float64) - t[inner]) ** 2))
            mse.append(e)
            per_view.append(10 * np.log10(65535.0 ** 2 / e))
        return 10 * np.log10(65535.0 ** 2 / np.mean(mse)), per_view

    results = []
    ahd_gains = None
    for label, profile, note in candidates():
        with Timer() as span:
            if profile is None:
                outs = area_first(ds, default_profile(), [(v, ahd_gains[(v["row"], v["column"])]) for v in ds.views])
            else:
                report = process_dataset(ds.root, profile, workers=0, force=True)
                assert report.ok, report.failed
                if profile.debayer.demosaic == "AHD" and not profile.debayer.half_size:
                    ahd_gains = report.gains
        if profile is not None:
            outs = {(v["row"], v["column"]): cv2.cvtColor(cv2.imread(str(ds.root / v["processed"]["file"]),
                                                                    cv2.IMREAD_UNCHANGED), cv2.COLOR_BGR2RGB)
                    for v in Dataset.open(ds.root).views}
        total, per_view = psnr(outs)
        results.append((label, total, span.cpu_s / len(outs)))
        print(f"{label:66s} PSNR {total:6.2f} dB  (views {' '.join(f'{p:.2f}' for p in per_view)})  "
              f"{span.cpu_s / len(outs):5.2f} CPU-s/view {note}", flush=True)
    auto, ahd = results[0], results[1]
    print()
    print(f"default path vs the former default: {auto[1] - ahd[1]:+.2f} dB against the truth (target >= 0), "
          f"{ahd[2] / auto[2]:.2f}x less CPU per view (start-up included; benchmarks/processing_throughput.py "
          "measures throughput)")
    print(load_text())
    return 0 if auto[1] >= ahd[1] else 1


if __name__ == "__main__":
    raise SystemExit(main())
