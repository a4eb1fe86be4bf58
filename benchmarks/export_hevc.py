"""HEVC export on a virtual-studio dataset: encode speed (frames/s at 2000 px width), size against
16-bit PNG (written for real, not estimated) and PSNR on the 16-bit scale; also x265's default
psycho-visual tuning (psy-rd on) against ours (psy-rd=0) at the same CRF.

    ./.venv/bin/python benchmarks/export_hevc.py [--width 2000] [--columns 8 --rows 3] [--noise 0.002]
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from lfstudio.dataset import Dataset  # noqa: E402
from lfstudio.export import ExportOptions, estimate_export, export_dataset, hevc  # noqa: E402
from lfstudio.sim.virtual_dataset import make_virtual_dataset  # noqa: E402


def _cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=2000, help="view width in px (default 2000)")
    ap.add_argument("--columns", type=int, default=8)
    ap.add_argument("--rows", type=int, default=3)
    ap.add_argument("--noise", type=float, default=0.002,
                    help="sensor read noise, fraction of white (default 0.002; 0 = noiseless render)")
    ap.add_argument("--crf", type=int, default=8)
    ap.add_argument("--no-psy-compare", action="store_true", help="skip the x265-default (psy-rd on) run")
    ap.add_argument("--keep", metavar="DIR", help="render the dataset into DIR and keep it (reused next time)")
    args = ap.parse_args()

    work = Path(tempfile.mkdtemp(prefix="lfstudio-bench-export-"))
    root = Path(args.keep) if args.keep else work / "dataset"
    try:
        n = args.columns * args.rows
        if not (root / "dataset.json").is_file():
            t = time.monotonic()
            make_virtual_dataset(root, args.columns, args.rows, width_px=args.width, fmt="png", noise=args.noise,
                                 workers=2, seed=3)
            print(f"rendered {n} views at {args.width} px in {time.monotonic() - t:.1f} s")
        ds = Dataset.open(root)
        w, h = estimate_export(ds, ExportOptions("png", work / "png")).image_size_px

        t = time.monotonic()
        png = export_dataset(ds, ExportOptions("png", work / "png"))
        png_view_bytes = png.bytes_written - (work / "png" / "manifest.json").stat().st_size
        print(f"16-bit PNG export: {n} views {w} x {h} px, {png_view_bytes / 1e6:.1f} MB "
              f"({png_view_bytes / n / (w * h * 6):.2f} of uncompressed), {n / (time.monotonic() - t):.2f} views/s")

        est = estimate_export(ds, ExportOptions("hevc", work / "lf.mp4", crf=args.crf))
        cpu0 = _cpu_s()
        rep = export_dataset(ds, ExportOptions("hevc", work / "lf.mp4", crf=args.crf))
        cpu = _cpu_s() - cpu0
        d = rep.details
        video = d["video_bytes"]
        fps = n / d["encode_s"]
        print(f"HEVC 12-bit 4:4:4 CRF {args.crf} ({hevc.X265_PARAMS}):")
        print(f"  encode speed        {fps:.2f} frames/s at {w} px ({d['encode_s']:.1f} s for {n} frames, "
              f"incl. reading the PNGs); verify {d['verify_s']:.1f} s")
        print(f"  CPU time            {cpu / n:.2f} CPU-s per frame (encode + verify; machine load "
              f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores: an idle 2-core machine would reach "
              f"~{2 * n / cpu:.2f} frames/s)")
        print(f"  size                {video / 1e6:.2f} MB = {video / n / (w * h):.4f} bytes/px "
              f"(estimate before export {est.bytes_estimate / 1e6:.2f} MB, ratio {est.bytes_estimate / video:.2f})")
        print(f"  vs 16-bit PNG       {png_view_bytes / video:.1f}x smaller (written PNGs); "
              f"export's own figure {rep.compression_ratio_vs_png:.1f}x")
        print(f"  PSNR                {rep.psnr_db:.2f} dB on the 16-bit scale ({d['psnr_frames']} frames)")
        full = 7952 * 5304 * 2121
        print(f"  projected           101 x 21 views at {w} px: {2121 / fps / 60:.1f} min encode on this machine; "
              f"at 7952 px ~{2121 * (7952 * 5304) / (w * h) / fps / 3600:.1f} h, ~{full * video / n / (w * h) / 1e9:.1f} GB")

        if not args.no_psy_compare:
            saved = hevc.X265_PARAMS
            hevc.X265_PARAMS = "log-level=error"
            try:
                rep2 = export_dataset(ds, ExportOptions("hevc", work / "psy.mp4", crf=args.crf))
            finally:
                hevc.X265_PARAMS = saved
            v2 = rep2.details["video_bytes"]
            print(f"x265 defaults (psy-rd on): {v2 / 1e6:.2f} MB ({png_view_bytes / v2:.1f}x vs PNG), PSNR "
                  f"{rep2.psnr_db:.2f} dB -> psy-rd=0 costs {video / v2:.2f}x the bytes for "
                  f"{rep.psnr_db - rep2.psnr_db:+.2f} dB")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
