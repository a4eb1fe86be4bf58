"""Unattended scans: notification latency, the status page's cost and bounds, the end-of-day
command's memory.

    python benchmarks/unattended.py [--n 200] [--grid 101x21] [--poll-s 1] [--held 2000] [--nofile 1024]
                                    [--flood-grid 41x21] [--on-finish-mb 1000] [--only held,on-finish]

1. **Notification latency**: scan state events (pause / resume requests on a real instant scan, so
   each notice starts as an engine event) to the JSON POST received by a local HTTP receiver, and
   ``--n`` notices sent one at a time through ``Notifier.notify``: median and p95 in ms.
2. **Status page cost** over a ``--grid`` instant scan (2121 views by default): the scan without the
   page, then with it and a client fetching ``/`` and ``/status.json`` every ``--poll-s`` seconds
   (5x as often as the page reloads itself); CPU ms per view of both and their difference, the
   page's requests served, and the process's peak RSS growth (MB) during the scan with the page.
3. **Held-open connections**: ``lfstudio scan`` (instant rig, simulated camera of 96 px, ``--flood-grid``)
   in a process allowed ``--nofile`` file descriptors (``ulimit -n 1024``) with ``--status-http``: the
   time per view (from the journal's capture times) with no client, and with ``--held`` connections
   held open half-sent (re-opened as the page closes them, 5 % reset); whether the scan finished, and
   how often the clients had to reconnect.
4. **The end-of-day command's memory**: peak RSS of a fresh Python process running a command that
   prints ``--on-finish-mb`` MB (100-character lines) through ``run_contained`` (what ``--on-finish``
   uses), against the same process without it; and, for scale, the old way (``subprocess`` capturing the
   whole output) at a tenth of that.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import threading
import time
import urllib.request
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _datasets import instant_devices  # noqa: E402
from _measure import Timer, load_text  # noqa: E402
from lfstudio.rig.profile import load_rig  # noqa: E402
from lfstudio.scan.engine import ScanEngine  # noqa: E402
from lfstudio.scan.events import EventKind, ScanState  # noqa: E402
from lfstudio.scan.notify import Notifier  # noqa: E402
from lfstudio.scan.scan_plan import ScanPlan  # noqa: E402
from lfstudio.scan.status_http import StatusBoard, StatusServer  # noqa: E402
from lfstudio.studio.session import create_scan_dataset  # noqa: E402


class Receiver:
    """Records the time each POST arrived, with the event it carries."""

    def __init__(self):
        self.got: list[tuple[float, dict]] = []
        self.cond = threading.Condition()
        receiver = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self):  # noqa: N802
                body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                t = time.time()
                self.send_response(200)
                self.send_header("Content-Length", "0")
                self.end_headers()
                with receiver.cond:
                    receiver.got.append((t, json.loads(body)))
                    receiver.cond.notify_all()

            def log_message(self, *args):
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        threading.Thread(target=self.server.serve_forever, daemon=True).start()
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/hook"

    def wait_count(self, n: int, timeout_s: float = 60) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: len(self.got) >= n, timeout_s)


def percentile(values: list[float], q: float) -> float:
    values = sorted(values)
    return values[min(len(values) - 1, int(round(q * (len(values) - 1))))]


def make_scan(columns: int, rows: int, rig_cfg, root: Path) -> tuple[ScanEngine, object]:
    plan = ScanPlan.centered(columns, rows, (4.0, 6.0), rig_cfg, settle_s=0.0)
    ds = create_scan_dataset(root, plan, rig={"name": rig_cfg.name}, camera={"name": "instant"},
                             lens={"name": "none"})
    rig, cam = instant_devices(rig_cfg)
    return ScanEngine(ds, plan, rig, cam, time_scale=0.0), ds


def latency(n: int, rig_cfg, tmp: Path) -> None:
    receiver = Receiver()
    notifier = Notifier([receiver.url], dataset="bench")
    # a) engine events: pause and resume a real scan; each state event's time to its POST's arrival
    engine, ds = make_scan(20, 10, rig_cfg, tmp / "latency")
    sent: dict[str, list[float]] = {}

    def on(ev):
        if ev.kind is EventKind.STATE and ev.state in (ScanState.RUNNING, ScanState.PAUSED, ScanState.FINISHED):
            sent.setdefault(ev.state.value, []).append(ev.time)
    engine.subscribe(on)
    engine.subscribe(notifier.on_scan_event)
    pauses = max(1, min(n // 2, 40))
    done = threading.Semaphore(0)
    engine.subscribe(lambda ev: ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED and done.release())
    engine.start()
    for _ in range(pauses):
        engine.pause()
        done.acquire(timeout=60)
        engine.resume().result(60)
    engine.wait(300)
    expected = 2 + 2 * pauses
    receiver.wait_count(expected)
    event_times = sorted(t for ts in sent.values() for t in ts)
    arrived = sorted(t for t, _ in receiver.got[:expected])
    lat = [1000 * (a - s) for a, s in zip(arrived, event_times)]
    print(f"engine state event -> POST received: {len(lat)} notices, median {percentile(lat, 0.5):.2f} ms, "
          f"p95 {percentile(lat, 0.95):.2f} ms", flush=True)
    # b) notify() one at a time
    start = len(receiver.got)
    lat = []
    for i in range(n):
        t0 = time.time()
        notifier.notify("flagged", f"view {i}")
        receiver.wait_count(start + i + 1)
        lat.append(1000 * (receiver.got[start + i][0] - t0))
    print(f"Notifier.notify -> POST received: {n} notices, median {percentile(lat, 0.5):.2f} ms, "
          f"p95 {percentile(lat, 0.95):.2f} ms", flush=True)
    notifier.close(10)
    receiver.server.shutdown()


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def status_cost(columns: int, rows: int, poll_s: float, rig_cfg, tmp: Path) -> None:
    engine, ds = make_scan(columns, rows, rig_cfg, tmp / "plain")
    with Timer() as plain:
        engine.start()
        engine.wait()
    n = len(ds.views)
    engine, ds = make_scan(columns, rows, rig_cfg, tmp / "page")
    board = StatusBoard(ds.root, total=n)
    engine.subscribe(board.on_scan_event)
    server = StatusServer("127.0.0.1:0")
    server.start(board)
    stop = threading.Event()
    sizes: list[int] = []

    def client() -> None:
        while not stop.is_set():
            for path in ("", "status.json"):
                with urllib.request.urlopen(server.url + path, timeout=30) as reply:
                    sizes.append(len(reply.read()))
            stop.wait(poll_s)
    rss0 = rss_mb()
    fetcher = threading.Thread(target=client, daemon=True)
    with Timer() as paged:
        fetcher.start()
        engine.start()
        engine.wait()
        stop.set()
        fetcher.join(30)
    server.close()
    per_plain, per_page = plain.cpu_s / n * 1000, paged.cpu_s / n * 1000
    print(f"{columns} x {rows} = {n} views, instant: without the page {per_plain:.3f} ms CPU per view "
          f"({plain.wall_s:.1f} s wall); with the page and a client every {poll_s:g} s {per_page:.3f} ms CPU per view "
          f"({paged.wall_s:.1f} s wall): +{per_page - per_plain:.3f} ms per view ({100 * (per_page / per_plain - 1):+.1f} %, "
          f"client included), {server.requests} requests served (page up to {max(sizes[0::2], default=0)} B, "
          f"status.json up to {max(sizes[1::2], default=0)} B); peak RSS {rss0:.0f} -> {rss_mb():.0f} MB", flush=True)


def journal_period_s(root: Path) -> tuple[int, float]:
    """Views done and the mean time between their capture times (s)."""
    from datetime import datetime

    from lfstudio.dataset import Dataset

    times = sorted(datetime.fromisoformat(v["captured_at"]).timestamp() for v in Dataset.open(root).done_views())
    return len(times), (times[-1] - times[0]) / max(1, len(times) - 1)


def held_connections(grid: str, held: int, nofile: int, tmp: Path) -> None:
    import os
    import random
    import resource
    import socket
    import subprocess

    from fault_soak import held_open

    repo = Path(__file__).resolve().parent.parent
    env = {**os.environ, "PYTHONPATH": str(repo) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, held + 4096), hard))
    try:
        for clients in (0, held):
            with socket.socket() as probe:
                probe.bind(("127.0.0.1", 0))
                port = probe.getsockname()[1]
            out = tmp / f"flood{clients}"
            proc = subprocess.Popen([sys.executable, "-m", "lfstudio", "scan", "--port", "instant", "--camera", "sim",
                                     "--sim-width-px", "96", "--time-scale", "0", "--grid", grid, "--out", str(out),
                                     "--status-http", f"127.0.0.1:{port}", "--status-linger-s", "0"], cwd=repo, env=env,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                    preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile)))
            while proc.poll() is None:                 # until the page listens
                with socket.socket() as s:
                    if s.connect_ex(("127.0.0.1", port)) == 0:
                        break
                time.sleep(0.01)
            stop = threading.Event()
            flood = threading.Thread(target=held_open, args=(port, clients, stop, random.Random(1)), daemon=True)
            if clients:
                flood.start()
            _, stderr = proc.communicate(timeout=1800)
            stop.set()
            if clients:
                flood.join(60)
            n, period = journal_period_s(out)
            trouble = [w for w in ("Too many open files", "Traceback") if w in stderr]
            print(f"scan of {grid} at ulimit -n {nofile} with {clients} connections held open to its status page: "
                  f"exit {proc.returncode}, {n} views, {1000 * period:.1f} ms per view"
                  + (f"; {', '.join(trouble)}" if trouble else ""), flush=True)
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


def on_finish_memory(megabytes: int) -> None:
    import subprocess

    lines = megabytes * 10_000                   # 100-character lines
    command = f"yes {'x' * 99} | head -n {lines}"
    probe = ("import resource, subprocess, sys, time\n"
             "from lfstudio.support.children import run_contained\n"
             "mode, command = sys.argv[1], sys.argv[2]\n"
             "t = time.monotonic()\n"
             "if mode == 'contained':\n"
             "    r = run_contained(command, limit_s=3600)\n"
             "    said = (r.output_bytes, r.lines, len(r.output))\n"
             "elif mode == 'whole':\n"
             "    out = subprocess.run(command, shell=True, capture_output=True).stdout\n"
             "    said = (len(out), out.count(b'\\n'), len(out))\n"
             "else:\n"
             "    said = (0, 0, 0)\n"
             "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, *said, time.monotonic() - t)\n")
    repo = Path(__file__).resolve().parent.parent
    import os

    env = {**os.environ, "PYTHONPATH": str(repo) + os.pathsep + os.environ.get("PYTHONPATH", "")}

    def run(mode: str, cmd: str) -> list[float]:
        done = subprocess.run([sys.executable, "-c", probe, mode, cmd], capture_output=True, text=True, env=env,
                              cwd=repo, timeout=3600)
        return [float(v) for v in done.stdout.split()]
    base = run("none", command)[0]
    rss, total, n, kept, wall = run("contained", command)
    print(f"--on-finish printing {total / 1e6:.0f} MB ({n:.0f} lines) through run_contained: peak RSS {rss:.0f} MB "
          f"(the same process without it: {base:.0f} MB; +{rss - base:.1f} MB), {kept / 1024:.0f} KiB kept, "
          f"{wall:.1f} s", flush=True)
    small = f"yes {'x' * 99} | head -n {lines // 10}"
    rss, total, n, kept, wall = run("whole", small)
    print(f"  for scale, the old way (the whole output captured) at {total / 1e6:.0f} MB: peak RSS {rss:.0f} MB "
          f"(+{rss - base:.0f} MB)", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="notices for the latency")
    ap.add_argument("--grid", default="101x21", help="COLUMNSxROWS of the status-page scan")
    ap.add_argument("--poll-s", type=float, default=1.0, help="the status client's interval")
    ap.add_argument("--held", type=int, default=2000, help="connections held open to the status page")
    ap.add_argument("--nofile", type=int, default=1024, help="the scan process's file descriptor limit")
    ap.add_argument("--flood-grid", default="41x21", help="COLUMNSxROWS of the held-open connections' scan")
    ap.add_argument("--on-finish-mb", type=int, default=1000, help="the end-of-day command's output (MB)")
    ap.add_argument("--only", default="", help="comma-separated parts: latency, status, held, on-finish")
    args = ap.parse_args()
    parts = set(args.only.split(",")) if args.only else {"latency", "status", "held", "on-finish"}
    columns, rows = (int(v) for v in args.grid.lower().split("x"))
    rig_cfg = load_rig()
    print(load_text(), flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        if "latency" in parts:
            latency(args.n, rig_cfg, Path(tmp))
        if "status" in parts:
            status_cost(columns, rows, args.poll_s, rig_cfg, Path(tmp))
        if "held" in parts:
            held_connections(args.flood_grid, args.held, args.nofile, Path(tmp))
        if "on-finish" in parts:
            on_finish_memory(args.on_finish_mb)
    print(load_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
