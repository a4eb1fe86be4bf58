"""Fault soak: N random kill -9 / fault trials of a scan; every view captured before a fault must be kept
exactly once and nothing outside the dataset touched.

Each trial runs ``lfstudio scan`` (instant rig, simulated camera, 5 x 3 views of 96 px, time scale 0.05)
in a subprocess and hits it with one fault at a random moment:

* ``kill``: kill -9 after a random number of journaled views and a random extra delay (inside a
  move, an exposure, a transfer or a store);
* ``kill-twice``: the same, then kill -9 of the resume too;
* ``disk-full`` (root only: a real tmpfs): the dataset on a disk sized to fill up after a random
  number of views (the scan stops on its free-space floor), then made larger;
* ``disk-fills`` (root only): another program takes all the free space of the dataset's tmpfs at a
  random moment (a real ENOSPC at whichever write comes next: capture, thumbnail, journal,
  manifest), then frees it again;
* ``status-flood``: the scan, in a process allowed 1024 file descriptors (``ulimit -n 1024``), serves
  its status page (``--status-http``) while 1150 to 2000 connections are held open half-sent (re-opened
  as the page closes them) and others reset theirs; it must finish by itself (no "Too many open
  files", no traceback);
* ``secret-kill``: the scan is given secret values (a ``--notify`` URL with user, password and webhook
  path, ``--status-token``, ``$LFSTUDIO_SMTP_PASSWORD``) and killed with kill -9 at a random moment (its
  ``dataset.lock`` and runtime lock files stay behind); no file under the dataset, the log folder or
  the runtime folder, and no output, may hold any of them;
* ``on-finish-escape``: ``--on-finish`` starts a ``setsid`` process that holds its output and prints
  a few MB, with a 1 s limit: the escaped process must be gone when the scan has exited;
* ``drive-stall``: the scan runs on two emulated CiA 402 drives (the dryve D1 pair on Modbus TCP,
  served by this process); at a random moment one drive's link stalls (it answers nothing) and
  the scan gets Ctrl+C. If the other drive was moving then, its quick stop must arrive (at its
  emulator) while the stalled link is still stalled (``stop missed`` otherwise; issue 42). The
  stall then ends and ``--resume --home`` completes the dataset on the same drives.

Then ``lfstudio scan --resume`` completes the dataset and the trial counts:

* lost: a view done before the fault that is not done after, or whose file or checksum changed;
* duplicated: a view done before the fault that was captured again (its capture time changed), or
  a second file for one view;
* outside: files beside the dataset that appeared, changed or vanished (a sentinel folder next to it);
* problems: a damaged file, a temporary file left; for status-flood, secret-kill and on-finish-escape
  also the scan stopped by the flood, a secret found (file or stream named), an escaped process alive;
* stop missed (drive-stall only): see above.

Usage (from the repository root): ``./.venv/bin/python benchmarks/fault_soak.py [--trials 50] [--seed 1]``.
Prints one line per trial and ``N trials, 0 lost, 0 duplicated, 0 outside``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _measure import Timer, load_text  # noqa: E402

from lfstudio.dataset import Dataset  # noqa: E402
from lfstudio.dataset.store import read_journal, temporary_files  # noqa: E402
from lfstudio.rig.profile import load_rig  # noqa: E402
from lfstudio.studio.simulated import start_drive_emulator  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
GRID = (5, 3)
SCAN = ["--port", "instant", "--camera", "sim", "--sim-width-px", "96"]


def cli(*args: object) -> list[str]:
    return [sys.executable, "-m", "lfstudio", *map(str, args)]


def env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def snapshot(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def captured(root: Path) -> dict[tuple[int, int], tuple]:
    if not (root / "dataset.json").is_file():
        return {}
    return {(v["row"], v["column"]): (v["file"], v["sha256"], v["captured_at"])
            for v in Dataset.open(root).done_views()}


def journaled(root: Path) -> int:
    try:
        return len(read_journal(root / "journal.jsonl")[0]) + sum(
            1 for v in json.loads((root / "dataset.json").read_text())["views"] if v.get("status") == "done")
    except (OSError, ValueError, KeyError):
        return 0


def kill_scan_at_random(out: Path, rnd: random.Random, resume: bool) -> None:
    args = cli("scan", "--resume", "--time-scale", "0.05", "--sim-width-px", "96", "--out", out) if resume else \
        cli("scan", *SCAN, "--time-scale", "0.05", "--grid", f"{GRID[0]}x{GRID[1]}", "--out", out)
    start = journaled(out)
    proc = subprocess.Popen(args, cwd=REPO, env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    target = start + rnd.randint(0, GRID[0] * GRID[1] - start)
    deadline = time.monotonic() + 120
    while proc.poll() is None and journaled(out) < target and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(rnd.uniform(0.0, 0.4))
    if proc.poll() is None:
        proc.send_signal(signal.SIGKILL)
    proc.wait(60)


DRIVES = "dryve D1 gantry 4 m x 0.5 m"


class QuickStopSeen(list):
    """A drive emulator's journal of writes; ``event`` is set when a quick stop (6040h = 0Bh) arrives."""

    def __init__(self):
        super().__init__()
        self.event = threading.Event()

    def append(self, item) -> None:
        super().append(item)
        if item[1] == 0x6040 and item[3] == 0x0B:
            self.event.set()


def stall_drive_at_random(out: Path, rnd: random.Random, emulator) -> tuple[int, int]:
    """The drive-stall trial's scan (see the module docstring): (1 if the other drive was moving at
    Ctrl+C, 1 if its quick stop was missed)."""
    seen = [QuickStopSeen(), QuickStopSeen()]
    for axis, journal in zip(emulator.pair.axes, seen):
        axis.journal = journal
    args = cli("scan", "--port", emulator.word, "--rig-profile", DRIVES, "--camera", "instant",
               "--time-scale", "0.05", "--home", "--grid", f"{GRID[0]}x{GRID[1]}", "--spacing-mm", "600x100",
               "--out", out)
    proc = subprocess.Popen(args, cwd=REPO, env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    target = rnd.randint(0, GRID[0] * GRID[1] - 1)
    deadline = time.monotonic() + 120
    while proc.poll() is None and journaled(out) < target and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(rnd.uniform(0.0, 0.4))
    missed = moving = 0
    if proc.poll() is None:
        stalled = rnd.randint(0, 1)
        other = emulator.pair.axes[1 - stalled]
        moving = int(other.read(0x606C, 0) != 0)
        seen[1 - stalled].event.clear()
        emulator.pair.axes[stalled].inject("lost_connection")
        proc.send_signal(signal.SIGINT)
        missed = int(moving and not seen[1 - stalled].event.wait(5) and emulator.pair.axes[stalled].answering is False)
        emulator.pair.axes[stalled].clear_faults()
    try:
        proc.wait(120)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    for axis in emulator.pair.axes:
        axis.journal = None
    return moving, missed


def can_mount() -> bool:
    if os.geteuid() != 0:
        return False
    probe = Path(tempfile.mkdtemp(prefix="lfstudio-soak-probe-"))
    ok = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(probe)], capture_output=True).returncode == 0
    if ok:
        subprocess.run(["umount", str(probe)], capture_output=True)
    probe.rmdir()
    return ok


def disk_full(work: Path, rnd: random.Random) -> Path:
    """The scan on a tmpfs that fills after a random number of views; the disk made larger afterwards."""
    disk = work / "disk"
    disk.mkdir()
    size = 8 * 2**20 + rnd.randint(0, 250 * 1024)         # the 8 MB floor plus room for some views (~20 kB each)
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(disk)], check=True)
    out = disk / "ds"
    (disk / "beside").mkdir()
    (disk / "beside" / "keep.txt").write_text("not the dataset's\n")
    subprocess.run(cli("scan", *SCAN, "--time-scale", "0", "--grid", f"{GRID[0]}x{GRID[1]}", "--out", out),
                   cwd=REPO, env=env(), capture_output=True, timeout=300)
    return out


def fill(folder: Path) -> Path:
    """Take every free byte of ``folder``'s disk with a filler file."""
    filler = folder / "filler.bin"
    try:
        with open(filler, "ab", buffering=0) as fh:
            while True:
                fh.write(b"\0" * 65536)
    except OSError:            # the disk is full (raised by a write or by the close)
        pass
    return filler


def disk_fills(work: Path, rnd: random.Random) -> Path:
    """The scan on a roomy tmpfs that another program fills up at a random moment (a real ENOSPC at
    whatever write comes next); the filler is removed afterwards."""
    disk = work / "disk"
    disk.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=32m", "tmpfs", str(disk)], check=True)
    out = disk / "ds"
    (disk / "beside").mkdir()
    (disk / "beside" / "keep.txt").write_text("not the dataset's\n")
    proc = subprocess.Popen(cli("scan", *SCAN, "--time-scale", "0.05", "--grid", f"{GRID[0]}x{GRID[1]}", "--out", out),
                            cwd=REPO, env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    target = rnd.randint(0, GRID[0] * GRID[1] - 1)
    deadline = time.monotonic() + 120
    while proc.poll() is None and journaled(out) < target and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(rnd.uniform(0.0, 0.3))
    filler = fill(disk)
    proc.wait(120)
    filler.unlink()
    return out


def held_open(port: int, count: int, stop: threading.Event, rnd: random.Random) -> None:
    """Keep ``count`` half-sent requests open to 127.0.0.1:``port`` (re-opened as the page closes them);
    every 20th connection is reset instead."""
    import selectors
    import socket
    import struct

    sel = selectors.DefaultSelector()

    def one() -> None:
        try:
            s = socket.create_connection(("127.0.0.1", port), timeout=5)
        except OSError:
            return
        if rnd.random() < 0.05:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            s.close()
            return
        s.sendall(b"GET /status.json HTTP/1.1\r\nHost: x\r\n")
        s.setblocking(False)
        sel.register(s, selectors.EVENT_READ)
    for _ in range(count):
        one()
    while not stop.is_set():
        for key, _ in sel.select(0.2):
            sock = key.fileobj
            sel.unregister(sock)
            sock.close()                         # closed by the page: open another one
            one()
    for key in list(sel.get_map().values()):
        key.fileobj.close()


def status_flood(work: Path, rnd: random.Random) -> tuple[Path, list[str]]:
    import resource
    import socket

    out = work / "ds"
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, 8192), hard))   # this process holds the clients
    proc = subprocess.Popen(cli("scan", *SCAN, "--time-scale", "0.05", "--grid", f"{GRID[0]}x{GRID[1]}", "--out", out,
                                "--status-http", f"127.0.0.1:{port}", "--status-linger-s", "0"),
                            cwd=REPO, env=env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_NOFILE, (1024, 1024)))
    while proc.poll() is None:                   # until the page listens
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                break
        time.sleep(0.01)
    stop = threading.Event()
    flood = threading.Thread(target=held_open, args=(port, rnd.randint(1150, 2000), stop, rnd), daemon=True)
    flood.start()
    try:
        _, stderr = proc.communicate(timeout=300)
    finally:
        stop.set()
        flood.join(30)
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
    problems = [f"scan exit {proc.returncode}"] if proc.returncode else []
    problems += [w for w in ("Too many open files", "Traceback") if w in stderr]
    return out, problems


SECRETS = ("Pa55-word-in-url", "W3bhookP4thSecret", "StatusT0ken-given-by-me", "SmtpPa55-from-env")


def secret_kill(work: Path, rnd: random.Random) -> tuple[Path, list[str]]:
    out, logs, runtime = work / "ds", work / "logs", work / "run"
    scan_env = {**env(), "LFSTUDIO_LOG_DIR": str(logs), "LFSTUDIO_RUNTIME_DIR": str(runtime),
                "LFSTUDIO_SMTP_PASSWORD": SECRETS[3]}
    proc = subprocess.Popen(cli("scan", "--port", "sim", "--camera", "sim", "--sim-width-px", "96", "--time-scale",
                                "0.05", "--grid", f"{GRID[0]}x{GRID[1]}", "--out", out,
                                "--notify", f"http://alice:{SECRETS[0]}@127.0.0.1:9/hooks/{SECRETS[1]}",
                                "--notify", "mailto:me@lab.example", "--smtp", "smtp://me@127.0.0.1:9",
                                "--status-http", "127.0.0.1:0", "--status-token", SECRETS[2], "--status-linger-s", "0"),
                            cwd=REPO, env=scan_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    target = rnd.randint(0, GRID[0] * GRID[1] - 1)
    deadline = time.monotonic() + 120
    while proc.poll() is None and journaled(out) < target and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(rnd.uniform(0.0, 0.4))
    if proc.poll() is None:
        proc.send_signal(signal.SIGKILL)
    streams = proc.communicate(timeout=60)
    found = {str(p): p.read_bytes() for folder in (out, logs, runtime) if folder.exists()
             for p in folder.rglob("*") if p.is_file()}
    found.update({"stdout": streams[0], "stderr": streams[1]})
    return out, [f"{secret} in {name}" for secret in SECRETS for name, data in found.items()
                 if secret.encode() in data]


def on_finish_escape(work: Path, rnd: random.Random) -> tuple[Path, list[str]]:
    out, pidfile = work / "ds", work / "escaped.pid"
    command = (f"setsid sh -c 'echo $$ > {pidfile}; head -c {rnd.randint(1, 8)}000000 /dev/zero | tr \"\\0\" x; "
               "exec sleep 600' &")
    done = subprocess.run(cli("scan", *SCAN, "--time-scale", "0", "--grid", f"{GRID[0]}x{GRID[1]}", "--out", out,
                              "--on-finish", command, "--on-finish-timeout-s", "1"),
                          cwd=REPO, env=env(), capture_output=True, text=True, timeout=300)
    problems = [f"scan exit {done.returncode}"] if done.returncode else []
    try:
        pid = int(pidfile.read_text())
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        if state not in ("Z", "X"):
            problems.append(f"escaped process {pid} still runs")
            os.kill(pid, signal.SIGKILL)
    except (OSError, ValueError):
        pass
    if "on-finish" not in done.stderr or "time limit" not in done.stderr:
        problems.append("the on-finish failure was not said")
    return out, problems


def trial(i: int, kind: str, rnd: random.Random, work: Path) -> dict:
    emulator = start_drive_emulator(load_rig(DRIVES), "modbus", time_scale=0.05) if kind == "drive-stall" else None
    try:
        return _trial(kind, rnd, work, emulator)
    finally:
        if emulator is not None:
            emulator.close()


def _trial(kind: str, rnd: random.Random, work: Path, emulator) -> dict:
    outside = work / "beside"
    outside.mkdir(parents=True)
    (outside / "keep.txt").write_text("not the dataset's\n")
    before_outside = snapshot(outside)
    stop_missed = stop_checked = 0
    extra: list[str] = []
    if emulator is not None:
        out = work / "ds"
        stop_checked, stop_missed = stall_drive_at_random(out, rnd, emulator)
    elif kind in ("status-flood", "secret-kill", "on-finish-escape"):
        out, extra = {"status-flood": status_flood, "secret-kill": secret_kill,
                      "on-finish-escape": on_finish_escape}[kind](work, rnd)
    elif kind in ("disk-full", "disk-fills"):
        out = disk_full(work, rnd) if kind == "disk-full" else disk_fills(work, rnd)
        outside = out.parent / "beside"
        before_outside = snapshot(outside)
    else:
        out = work / "ds"
        kill_scan_at_random(out, rnd, resume=False)
    before = captured(out)
    if kind == "kill-twice" and len(before) < GRID[0] * GRID[1]:
        kill_scan_at_random(out, rnd, resume=True)
        middle = captured(out)       # the views the killed resume added count too; the first ones keep their record
        before = {**{c: v for c, v in middle.items() if c not in before}, **before}
    if kind == "disk-full":
        subprocess.run(["mount", "-o", "remount,size=64m", str(out.parent)], check=True)
    if (out / "dataset.json").is_file():
        again = cli("scan", "--resume", "--time-scale", "0", "--sim-width-px", "96", "--out", out,
                    *(["--home"] if emulator is not None else []))
    elif emulator is not None:
        again = cli("scan", "--port", emulator.word, "--rig-profile", DRIVES, "--camera", "instant",
                    "--time-scale", "0", "--home", "--grid", f"{GRID[0]}x{GRID[1]}", "--spacing-mm", "600x100",
                    "--out", out)
    else:                               # killed before the dataset existed: the operator starts again
        again = cli("scan", *SCAN, "--time-scale", "0", "--grid", f"{GRID[0]}x{GRID[1]}", "--out", out)
    done = subprocess.run(again, cwd=REPO, env=env(), capture_output=True, text=True, timeout=300)
    after = captured(out)
    lost = [c for c, v in before.items() if c not in after or after[c][:2] != v[:2]]
    duplicated = [c for c, v in before.items() if c in after and after[c][:2] == v[:2] and after[c][2] != v[2]]
    stems = [p.name.split(".")[0] for p in (out / "raw").glob("*.dng")]
    duplicated += [s for s in set(stems) if stems.count(s) > 1]
    incomplete = GRID[0] * GRID[1] - len(after)
    problems = Dataset.open(out).verify_files() + [str(p) for p in temporary_files(out)] + extra
    outside_changed = snapshot(outside) != before_outside
    return {"kind": kind, "before": len(before), "lost": len(lost), "duplicated": len(duplicated),
            "stop_missed": stop_missed, "stop_checked": stop_checked,
            "outside": int(outside_changed), "incomplete": incomplete, "problems": problems,
            "resume_rc": done.returncode, "stderr": done.stderr.strip().splitlines()[-1:] if done.returncode else []}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=50)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--kinds", default="", help="comma-separated fault kinds to draw from (default: all)")
    args = parser.parse_args()
    rnd = random.Random(args.seed)
    kinds = ["kill", "kill", "kill-twice", "drive-stall", "status-flood", "secret-kill", "on-finish-escape"] + (
        ["disk-full", "disk-fills"] if can_mount() else [])
    if args.kinds:
        kinds = args.kinds.split(",")
    totals = {"lost": 0, "duplicated": 0, "outside": 0, "incomplete": 0, "problems": 0, "stop_missed": 0}
    counts: dict[str, int] = {}
    timer = Timer()
    span = timer.__enter__()
    for i in range(args.trials):
        kind = rnd.choice(kinds)
        counts[kind] = counts.get(kind, 0) + 1
        with tempfile.TemporaryDirectory(prefix="lfstudio-soak-", ignore_cleanup_errors=True) as tmp:
            try:
                result = trial(i, kind, rnd, Path(tmp))
            finally:
                if (Path(tmp) / "disk").is_mount():
                    subprocess.run(["umount", "-l", str(Path(tmp) / "disk")], capture_output=True)
        for key in ("lost", "duplicated", "outside", "incomplete", "stop_missed"):
            totals[key] += result[key]
        totals["problems"] += len(result["problems"])
        print(f"trial {i + 1:3d} {kind:<10} {result['before']:2d} views before the fault: lost {result['lost']}, "
              f"duplicated {result['duplicated']}, outside {result['outside']}, incomplete {result['incomplete']}"
              + ((f", other drive moving at Ctrl+C: stop missed {result['stop_missed']}" if result["stop_checked"]
                  else ", other drive at rest at Ctrl+C") if kind == "drive-stall" else "")
              + (f", problems {result['problems'][:2]}" if result["problems"] else "")
              + (f", resume exit {result['resume_rc']} {result['stderr']}" if result["resume_rc"] else ""), flush=True)
    timer.__exit__(None, None, None)
    print(f"fault kinds: {', '.join(f'{k} {n}' for k, n in sorted(counts.items()))}; {span.wall_s:.0f} s wall, "
          f"{span.cpu_s:.0f} s CPU (this process and its scans); {load_text()}")
    if totals["incomplete"] or totals["problems"]:
        print(f"{totals['incomplete']} views not completed by the resume, {totals['problems']} file problems")
    print(f"{args.trials} trials, {totals['lost']} lost, {totals['duplicated']} duplicated, {totals['outside']} outside, "
          f"{totals['stop_missed']} quick stops missed")
    return 0 if not any(totals.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
