"""Engine cost per view: scans with the instant rig and camera (no device time at all), so the
duration is the engine's own work per view (queues, device-worker hops, checksum, thumbnail,
fsync'd journal line, events, checkpoints and manifest rewrites) plus the instant camera writing its
small PNG.

    python benchmarks/scan_overhead.py [--grids 101x21,201x41]
    python benchmarks/scan_overhead.py --notify-dead [--grids 101x21] [--repeat 3]

``--notify-dead``: the first grid scanned ``--repeat`` times without notifications and as often
with ``--notify`` to a dead endpoint (a local port that accepts and never answers), alternately;
per view CPU and wall ms of each, and the ratio of the medians (target: no measurable change, the
ratio within the runs' own spread).

One scan per grid in this invocation. Per scan: wall and CPU milliseconds per view (nothing is
subtracted: the instant camera's own capture time, measured alone, is printed beside it), the
checkpoints (count, median) and the manifest rewrites among them (count, longest, CPU on its thread), the time to the first finished view
as a share of the scan (start-up, target < 5 %) and the load average. Targets: <= 5 ms per view
(wall, on a quiet machine), and per view at the largest grid within 10 % of the smallest (CPU,
which other programs do not inflate; wall printed too).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _datasets import instant_devices  # noqa: E402
from _measure import Timer, load_text  # noqa: E402
from lfstudio.rig.profile import load_rig  # noqa: E402
from lfstudio.scan.engine import ScanEngine  # noqa: E402
from lfstudio.scan.events import EventKind, ScanState  # noqa: E402
from lfstudio.scan.scan_plan import ScanPlan  # noqa: E402
from lfstudio.studio.session import create_scan_dataset  # noqa: E402

TARGET_MS = 5.0


def scan(columns: int, rows: int, rig_cfg, tmp: Path, notifier=None, name: str = "") -> dict | None:
    plan = ScanPlan.centered(columns, rows, (4.0, 6.0), rig_cfg, settle_s=0.0)
    ds = create_scan_dataset(tmp / f"ds{columns}x{rows}{name}", plan, rig={"name": rig_cfg.name},
                             camera={"name": "instant"}, lens={"name": "none"})
    saves: list[tuple[float, float]] = []
    checkpoints: list[tuple[float, float]] = []

    def timed(fn, out):
        def call() -> None:
            t, c = time.perf_counter(), time.thread_time()
            fn()
            out.append((time.perf_counter() - t, time.thread_time() - c))
        return call
    ds.save = timed(ds.save, saves)                  # a checkpoint's own rewrites are counted here too
    ds.checkpoint = timed(ds.checkpoint, checkpoints)
    rig, cam = instant_devices(rig_cfg)
    engine = ScanEngine(ds, plan, rig, cam, time_scale=0.0)
    if notifier is not None:
        engine.subscribe(notifier.on_scan_event)
    first: dict[str, float] = {}
    engine.subscribe(lambda ev: first.setdefault("t", time.perf_counter()) if ev.kind is EventKind.VIEW_DONE else None)
    with Timer() as span:
        t0 = time.perf_counter()
        engine.start()
        state = engine.wait()
    if state is not ScanState.FINISHED:
        print(f"{columns} x {rows}: the scan did not finish: {engine.message}")
        return None
    n = len(plan)
    return {"grid": f"{columns} x {rows}", "views": n, "wall_ms": span.wall_s / n * 1000,
            "cpu_ms": span.cpu_s / n * 1000, "start_share": (first["t"] - t0) / span.wall_s,
            "saves": saves, "checkpoints": checkpoints, "cores": span.cores_used, "load": span.load_1min, "manifest_views": len(ds.views)}


def dead_endpoint() -> tuple[str, object]:
    """A local port that accepts connections and never answers: its URL and its socket."""
    import socket
    import threading

    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(64)
    held: list = []

    def accept() -> None:
        while True:
            try:
                held.append(sock.accept()[0])
            except OSError:
                return
    threading.Thread(target=accept, daemon=True).start()
    return f"http://127.0.0.1:{sock.getsockname()[1]}/hook", sock


def notify_dead(columns: int, rows: int, repeat: int, rig_cfg) -> int:
    from lfstudio.scan.notify import Notifier

    url, sock = dead_endpoint()
    runs: dict[str, list[dict]] = {"none": [], "dead endpoint": []}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(repeat):
            for kind in runs:
                notifier = Notifier([url], dataset="bench", timeout_s=600) if kind != "none" else None
                r = scan(columns, rows, rig_cfg, Path(tmp), notifier, name=f"{kind[0]}{i}")
                if r is None:
                    return 1
                if notifier is not None:
                    r["dropped"] = sum(notifier.dropped.values())
                    notifier.close(0.1)
                runs[kind].append(r)
                print(f"{kind:>13} run {i + 1}: {r['wall_ms']:5.2f} ms wall, {r['cpu_ms']:5.2f} ms CPU per view "
                      f"({r['views']} views; load {r['load']:.1f})", flush=True)
    sock.close()

    def median(values):
        values = sorted(values)
        return values[len(values) // 2]
    base, dead = runs["none"], runs["dead endpoint"]
    for what in ("cpu_ms", "wall_ms"):
        b, d = median([r[what] for r in base]), median([r[what] for r in dead])
        spread = (max(r[what] for r in base) - min(r[what] for r in base)) / b
        print(f"per view {what[:-3].upper():>4}: none {b:.3f} ms, dead endpoint {d:.3f} ms: ratio {d / b:.3f} "
              f"(the runs without notifications spread {100 * spread:.1f} %)")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grids", default="101x21,201x41", help="comma-separated COLUMNSxROWS")
    ap.add_argument("--notify-dead", action="store_true", help="with and without --notify to a dead endpoint")
    ap.add_argument("--repeat", type=int, default=3, help="--notify-dead: scans of each kind")
    args = ap.parse_args()
    grids = [tuple(int(v) for v in g.lower().split("x")) for g in args.grids.split(",")]
    rig_cfg = load_rig()
    print(load_text(), flush=True)
    if args.notify_dead:
        status = notify_dead(*grids[0], args.repeat, rig_cfg)
        print(load_text())
        return status
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        rig, cam = instant_devices(rig_cfg)
        with Timer() as cam_span:       # the camera's own work, for reference (not subtracted)
            for i in range(200):
                cam.capture(Path(tmp) / f"probe{i % 4}")
        print(f"instant camera alone: {cam_span.wall_s / 200 * 1000:.2f} ms wall, {cam_span.cpu_s / 200 * 1000:.2f} ms "
              "CPU per capture (PNG encode + atomic write; part of every figure below)", flush=True)
        for columns, rows in grids:
            r = scan(columns, rows, rig_cfg, Path(tmp))
            if r is None:
                return 1
            results.append(r)
            longest = max((w for w, _ in r["saves"]), default=0.0) * 1000
            save_cpu = max((c for _, c in r["saves"]), default=0.0) * 1000
            cp = sorted(w for w, _ in r["checkpoints"])
            cp_text = f"{len(cp)} checkpoints, median {cp[len(cp) // 2] * 1000:.1f} ms wall; " if cp else ""
            print(f"{r['grid']:>9} = {r['views']:5d} views: {r['wall_ms']:5.2f} ms wall, {r['cpu_ms']:5.2f} ms CPU per view "
                  f"(target <= {TARGET_MS:g} ms wall: {'OK' if r['wall_ms'] <= TARGET_MS else 'MISSED'}); "
                  f"{cp_text}{len(r['saves'])} manifest rewrites, longest {longest:.1f} ms wall / {save_cpu:.1f} ms CPU; "
                  f"first view after {100 * r['start_share']:.1f} % of the scan; cores used {r['cores']:.2f}, "
                  f"load {r['load']:.1f}", flush=True)
    if len(results) > 1:
        small, large = results[0], results[-1]
        print(f"per view, {large['grid']} / {small['grid']}: CPU {large['cpu_ms'] / small['cpu_ms']:.3f}x, "
              f"wall {large['wall_ms'] / small['wall_ms']:.3f}x   (target <= 1.10)")
    print(load_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
