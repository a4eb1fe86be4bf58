"""How much the log grows per captured view, for sizing its rotation (lfstudio.support.logs).

Runs ``lfstudio scan`` on the simulated GRBL rig and on the emulated CiA 402 drives (time scale 0:
no waiting; the drives' Modbus traffic is real) with a fresh log folder, and prints the lines and bytes
the log gained per view, and how many hours of an unattended scan at one view every 3 s the
rotating files keep. Figures are printed, never asserted.

    PYTHONPATH=. python benchmarks/log_lines_per_view.py [COLUMNSxROWS]
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from lfstudio.support.logs import BACKUP_COUNT, MAX_BYTES  # noqa: E402

SECONDS_PER_VIEW = 3.0


def measure(port: str, grid: str) -> tuple[int, int, int]:
    """(views, log lines, log bytes) of one scan with the rig ``port``."""
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "LFSTUDIO_LOG_DIR": f"{tmp}/log", "LFSTUDIO_CONFIG_DIR": f"{tmp}/config"}
        args = [sys.executable, "-m", "lfstudio", "scan", "--port", port, "--camera", "sim", "--grid", grid,
                "--time-scale", "0", "--out", f"{tmp}/d"]
        out = subprocess.run(args, capture_output=True, text=True, env=env, timeout=1800)
        if out.returncode != 0:
            raise SystemExit(f"{' '.join(args)} failed:\n{out.stderr}")
        files = list(Path(tmp, "log").glob("lfstudio.log*"))
        lines = sum(len(f.read_text(encoding="utf-8").splitlines()) for f in files)
        size = sum(f.stat().st_size for f in files)
    columns, rows = (int(n) for n in grid.lower().split("x"))
    return columns * rows, lines, size


def main() -> None:
    grid = sys.argv[1] if len(sys.argv) > 1 else "10x4"
    kept_bytes = MAX_BYTES * (BACKUP_COUNT + 1)
    for port in ("sim", "sim-dryve"):
        views, lines, size = measure(port, grid)
        per_view = size / views
        hours = kept_bytes / per_view * SECONDS_PER_VIEW / 3600
        print(f"{port:10s} {views} views: {lines} lines, {size / 1e3:.0f} kB in the log: {lines / views:.1f} lines "
              f"and {per_view:.0f} bytes a view; {kept_bytes / 1e6:.0f} MB of rotating files keep {hours:.0f} h "
              f"at one view every {SECONDS_PER_VIEW:g} s")


if __name__ == "__main__":
    main()
