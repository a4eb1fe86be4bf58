"""The thumbnail grid with the reference 101 x 21 = 2121 views: time to open the dataset to a painted
grid (target < 1 s), time until every thumbnail tile is in, process memory (target < 500 MB), and the
GUI thread's longest stall during a running scan (``lfstudio.gui.heartbeat.Heartbeat``, target < 50 ms).

    python benchmarks/grid_gui.py [--dataset DIR] [--scan-views 2121] [--grid 101x21]

A scan that does not start or finish, or a grid that never paints, ends the run with exit status 1 and
the window's own message (what the operator would read), never with figures of an idle window.

The dataset (virtual-studio thumbnails) is built once in a temporary folder unless --dataset is given.
The running scan uses the instant rig and camera through the Scan panel: the heaviest event rate the
GUI can get (hundreds of views per second), a worst case for the GUI thread.
"""

from __future__ import annotations

import argparse
import collections
import gc
import multiprocessing
import os
import re
import sys
import threading
import tempfile
import time
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _datasets import captured_dataset  # noqa: E402
from _measure import Timer, load_text  # noqa: E402
from _qt import spin_until  # noqa: E402


class ThreadCpu:
    """CPU seconds of each thread of this process by name, sampled from /proc every 0.2 s (threads that
    end in between lose their last 0.2 s): who in this one process competes with the GUI thread for
    the GIL and the cores."""

    def __init__(self) -> None:
        self._seen: dict[tuple[int, str], float] = {}       # (native id, name) -> CPU s
        self._base: dict[tuple[int, str], float] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bench-thread-cpu", daemon=True)
        self._tick_s = 1.0 / os.sysconf("SC_CLK_TCK")

    def _cpu_s(self, native_id: int, task: bool = True) -> float | None:
        try:
            with open(f"/proc/self/task/{native_id}/stat" if task else f"/proc/{native_id}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except OSError:
            return None
        return (int(fields[11]) + int(fields[12])) * self._tick_s      # utime, stime

    def _sample(self) -> None:
        for t in threading.enumerate():
            cpu = self._cpu_s(t.native_id) if t.native_id is not None else None
            if cpu is not None:
                self._seen[(t.native_id, t.name)] = cpu

    def _run(self) -> None:
        while not self._stop.wait(0.2):
            self._sample()

    def start(self) -> None:
        self._sample()                     # threads alive now count from here on
        self._base, self._seen = dict(self._seen), {}
        self._thread.start()

    def stop(self) -> dict[str, float]:
        """CPU seconds per thread name since start() (unnamed threads together), most first; child
        processes still running (the live quality check) as "process NAME"."""
        self._sample()
        self._stop.set()
        self._thread.join(2)
        by_name: collections.Counter = collections.Counter()
        for key, cpu in self._seen.items():
            name = re.sub(r"^Thread-\d+.*", "unnamed threads (threading.Timer, ...)", key[1])
            by_name[name] += cpu - self._base.get(key, 0.0)
        for child in multiprocessing.active_children():
            cpu = self._cpu_s(child.pid, task=False)
            if cpu is not None:
                by_name[f"process {child.name}"] += cpu
        return dict(by_name.most_common())


def fail(what: str, errors: list[str]) -> int:
    """Say loudly why there are no figures (with the window's messages) and give exit status 1."""
    print(f"FAILED: {what}", file=sys.stderr)
    for message in errors:
        print(f"    the window said: {message}", file=sys.stderr)
    if not errors:
        print("    the window showed no message", file=sys.stderr)
    return 1


def done_views(root: Path) -> int:
    from lfstudio.dataset import Dataset

    try:
        return sum(1 for v in Dataset.open(root).views if v.get("status") == "done")
    except Exception:  # noqa: BLE001 - no dataset: none done
        return 0


def rss_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", help="an existing 2121-view dataset to open")
    ap.add_argument("--scan-views", type=int, default=2121, help="views of the scan run under the heartbeat")
    ap.add_argument("--warn-ms", type=float, default=30.0, help="list GUI stalls longer than this (ms)")
    ap.add_argument("--events", action="store_true",
                    help="also name the Qt event of each stall (a Python event filter: slows the GUI itself)")
    ap.add_argument("--show", type=int, default=8, help="how many of the worst stalls to list")
    ap.add_argument("--grid", default="101x21", help="COLUMNSxROWS of the dataset built to open (default 101x21)")
    ap.add_argument("--scan-timeout-s", type=float, default=600.0, help="give up on the scan after this long")
    args = ap.parse_args()
    grid_cols, grid_rows = (int(v) for v in args.grid.lower().split("x"))
    print(load_text(), flush=True)
    tmp = tempfile.mkdtemp(prefix="lfstudio-grid-bench-")
    os.environ["LFSTUDIO_CONFIG_DIR"] = str(Path(tmp) / "config")
    root = Path(args.dataset) if args.dataset else Path(tmp) / f"ref{grid_cols}x{grid_rows}"
    if not args.dataset:
        print(f"building a {grid_cols} x {grid_rows} dataset with virtual-studio thumbnails…", flush=True)
        captured_dataset(root, grid_cols, grid_rows)

    from PySide6.QtWidgets import QApplication

    from lfstudio.dataset import Dataset
    from lfstudio.gui.app import create_window
    from lfstudio.gui.devices import QtDevice
    from lfstudio.gui.heartbeat import Heartbeat
    from lfstudio.rig.profile import load_rig
    from lfstudio.rig.worker import DeviceWorker
    from lfstudio.sim.instant import InstantCamera, InstantRig

    app = QApplication.instance() or QApplication([])
    window = create_window(simulated=True)
    window.resize(1600, 1000)
    window.show()
    app.processEvents()
    canvas = window.central.canvas
    painted = {"t": None}
    orig_paint = canvas.paintEvent

    def paint(event):
        orig_paint(event)
        if painted["t"] is None and canvas.rows:
            painted["t"] = time.perf_counter()
    canvas.paintEvent = paint

    rss0 = rss_mb()
    t0 = time.perf_counter()
    errors: list[str] = []          # what the window told the operator (its message boxes)
    window.state.errorOccurred.connect(lambda title, message: errors.append(f"{title}: {message}"))
    opened = Dataset.open(root)
    n_open = len(opened.views)
    window.state.set_dataset(opened)
    canvas.viewport().repaint()
    if not spin_until(lambda: painted["t"] is not None, 10):
        return fail("the grid was never painted", errors)
    t_painted = painted["t"] - t0
    if not spin_until(lambda: canvas._mosaic_has.all(), 60):
        return fail("not every thumbnail tile came in within 60 s", errors)
    t_all = time.perf_counter() - t0
    window.grab().save(str(Path(tmp) / "grid.png"))
    canvas.set_zoom(160)
    spin_until(lambda: len(canvas._cache) >= 12, 10)
    canvas.fit()
    rss1 = rss_mb()
    print(f"open {n_open}-view dataset to a painted grid   {t_painted * 1000:.0f} ms   (target < 1000 ms: "
          f"{'OK' if t_painted < 1.0 else 'MISSED'})")
    print(f"all {n_open} thumbnail tiles loaded            {t_all * 1000:.0f} ms")
    print(f"memory (RSS) after open                    {rss1:.0f} MB (before: {rss0:.0f} MB; target < 500 MB: "
          f"{'OK' if rss1 < 500 else 'MISSED'})")

    # a running scan under the heartbeat
    rig_cfg = load_rig()
    rig = InstantRig(rig_cfg)
    rig.connect()
    # describe_size: the disk pre-flight counts its small PNGs, not the plan's 84 MB images (which
    # refused the 2121 views: "Disk too small for this scan: 2121 views need about 179.2 GB ...")
    cam = InstantCamera(rig.true_position_mm, describe_size=True)
    cam.connect()
    state = window.state
    state.devices["rig"] = QtDevice(DeviceWorker(rig, name="rig"))
    state.devices["camera"] = QtDevice(DeviceWorker(cam, name="camera", status_method=None))
    panel = window.panels["scanPanel"]
    cols = min(101, args.scan_views)
    rows = max(1, args.scan_views // cols)
    panel.columns.setValue(cols)
    panel.rows.setValue(rows)
    panel.settle.setValue(0.0)
    panel.time_scale.setValue(0.0)
    panel.folder.setText(str(Path(tmp) / "scan"))
    heart = Heartbeat(interval_ms=10, warn_ms=args.warn_ms, watch=True, events=args.events, record=True,
                      gc_watch=True)
    first_done = {}
    state.scanEvents.connect(lambda events: first_done.setdefault("t", time.perf_counter())
                             if any(ev.kind.value == "view-done" for ev in events) else None)
    load_before = os.getloadavg()[0]
    threads = ThreadCpu()
    threads.start()
    heart.start()
    t = time.perf_counter()
    ended = ("Finished", "Could not start", "Not started", "Failed", "Aborted", "Stopped", "Paused")
    with Timer() as scan_span:
        panel.start()
        spin_until(lambda: any(w in panel.state_label.text() for w in ended) or errors, args.scan_timeout_s)
    heart.stop()
    thread_cpu = threads.stop()
    if "Finished" not in panel.state_label.text():
        return fail(f"the scan of {cols * rows} views did not finish (the Scan panel says "
                    f"{panel.state_label.text()!r} after {scan_span.wall_s:.1f} s)", errors)
    if done_views(Path(tmp) / "scan") != cols * rows:
        return fail(f"the scan finished with {done_views(Path(tmp) / 'scan')} of {cols * rows} views done", errors)
    scan_s = scan_span.wall_s
    views = cols * rows
    print(f"scan through the GUI                       {views} views in {scan_s:.1f} s "
          f"({views / scan_s:.0f} views/s, instant devices; CPU {scan_span.cpu_s:.1f} s, "
          f"load {load_before:.2f} at the start, {scan_span.load_1min:.2f} at the end)")
    t_run = first_done.get("t", t) - t
    running = [tick for tick in heart.tick_log if tick.at_s >= t_run]
    starting = [tick for tick in heart.tick_log if tick.at_s < t_run]
    stalls = sorted(tick.stall_ms for tick in running)
    max_run = stalls[-1] if stalls else 0.0
    print(f"GUI thread max stall while the scan runs   {max_run:.1f} ms   (target < 50 ms at load <= 2: "
          f"{'OK' if max_run < 50 else 'MISSED'}; p99 {stalls[int(0.99 * (len(stalls) - 1))] if stalls else 0:.1f} ms, "
          f"ticks > 50 ms: {sum(1 for ms in stalls if ms > 50)} of {len(stalls)}; {load_text()})")
    worst = max(running, key=lambda tick: tick.stall_ms, default=None)
    if worst is not None:
        blocked = max(0.0, worst.stall_ms + heart.interval_ms - worst.cpu_ms - worst.queued_ms)
        print(f"    the worst tick interval, {worst.stall_ms + heart.interval_ms:.1f} ms at {worst.at_s:.2f} s: own CPU "
              f"{worst.cpu_ms:.1f} ms, ready but waiting for a core {worst.queued_ms:.1f} ms (the computer's load), "
              f"the rest {blocked:.1f} ms idle or waiting for the GIL; over all ticks: "
              f"{sum(t.queued_ms for t in running):.0f} ms waiting for a core")
    busy = heart.cpu_ms / (scan_s * 1000)
    cpu_ticks = sorted(tick.cpu_ms for tick in running)
    p99 = cpu_ticks[int(0.99 * (len(cpu_ticks) - 1))] if cpu_ticks else 0.0
    print(f"GUI thread CPU while the scan runs         {max(cpu_ticks, default=0.0):.1f} ms at most between two "
          f"ticks (load-independent; aim < 15 ms; p99 {p99:.1f} ms, ticks over 15 ms: "
          f"{sum(1 for ms in cpu_ticks if ms > 15)}), {heart.cpu_ms / views:.2f} ms per view, "
          f"busy {100 * busy:.0f} % of the scan's wall time")
    print(f"GUI thread max stall while it starts       {max((tick.stall_ms for tick in starting), default=0.0):.1f} ms "
          f"(Start click to first view, {t_run * 1000:.0f} ms: devices, dataset and engine are prepared off the "
          "GUI thread)")
    gcw = heart.gc
    full = [g for g in gcw.log if g.generation == 2]
    print(f"garbage collection during the scan         {gcw.counts[0]} / {gcw.counts[1]} / {gcw.counts[2]} "
          f"collections of generation 0 / 1 / 2 taking {gcw.total_ms[0]:.0f} / {gcw.total_ms[1]:.0f} / "
          f"{gcw.total_ms[2]:.0f} ms; longest {max((g.duration_ms for g in gcw.log), default=0.0):.1f} ms; full "
          f"ones: " + (", ".join(f"{g.duration_ms:.1f} ms at {g.at_s:.2f} s ({'GUI' if g.on_gui_thread else 'other'}"
                                 " thread)" for g in full[:6]) or "none")
          + f"; at the end {len(gc.get_objects())} objects tracked, {gc.get_freeze_count()} frozen")
    total_cpu = sum(thread_cpu.values())
    print(f"CPU by thread during the scan              {total_cpu:.1f} s (child processes' own CPU included): " + ", ".join(
        f"{name} {cpu:.1f}" for name, cpu in thread_cpu.items() if cpu >= 0.05))
    print("GUI thread's busiest tick intervals (own CPU; gc: GUI-thread / other threads' collections"
          + ("; the event that used most):" if args.events else "; --events names the Qt event):"))
    for tick in sorted(running, key=lambda tick: -tick.cpu_ms)[:args.show]:
        print(f"    {tick.cpu_ms:5.1f} ms CPU, stall {tick.stall_ms:5.1f} ms (waiting for a core {tick.queued_ms:.1f} ms), "
              f"gc {tick.gc_ms:.1f} / {tick.gc_other_ms:.1f} ms"
              f" at {tick.at_s:.2f} s" + (f": {tick.event} {tick.event_cpu_ms:.1f} ms" if tick.event else ""))
    if heart.delivered:
        print("events delivered to the GUI thread during the scan, most frequent first (--events):")
        for text, count in heart.delivered[:args.show + 6]:
            print(f"    {count:6d}  {text}")
    print(f"GUI thread stalls over {args.warn_ms:.0f} ms, worst first (where the watchdog saw the GUI thread):")
    for stall in heart.worst(args.show):
        print(f"    {stall}")
    if not heart.stalls:
        print("    none")
    print(f"memory (RSS) after the scan                {rss_mb():.0f} MB")
    print(f"screenshot                                 {Path(tmp) / 'grid.png'}")
    for d in state.devices.values():
        d.close(disconnect=False)
    window.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
