"""Rig command latency and status rate through the pseudo-terminal (driver <-> simulated GRBL).

    ./.venv/bin/python benchmarks/rig_latency.py [--n 500] [--seconds 2]

Prints median / p95 round-trip times of a G-code line (send, wait for ``ok``), of a ``?`` status
query (send, wait for the report), and of a complete ``move_to`` on an instant simulator
(time_scale 0: protocol overhead only), plus the sustained status-report rate and its headroom over
the driver's 20 Hz polling while waiting for a move.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
import sys

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from lfstudio.rig.profile import load_rig  # noqa: E402
from lfstudio.studio.devices import open_rig  # noqa: E402


def stats_ms(samples: list[float]) -> tuple[float, float]:
    s = sorted(samples)
    return statistics.median(s) * 1e3, s[min(len(s) - 1, int(0.95 * len(s)))] * 1e3


def timed(fn, n: int) -> list[float]:
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=500, help="round trips per figure (default 500)")
    ap.add_argument("--seconds", type=float, default=2.0, help="duration of the status-rate run (default 2)")
    args = ap.parse_args()

    link = open_rig("sim", load_rig(), time_scale=0.0)
    controller, sim = link.controller, link.simulator
    try:
        controller.home()
        line = stats_ms(timed(lambda: controller._command("G90"), args.n))
        query = stats_ms(timed(controller._query_status, args.n))
        targets = iter([(10.0 + (i % 2) * 5.0, 10.0) for i in range(args.n)])
        move = stats_ms(timed(lambda: controller.move_to(*next(targets)), args.n))
        count, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < args.seconds:
            controller._query_status()
            count += 1
        rate_hz = count / (time.perf_counter() - t0)
    finally:
        link.close()

    poll_hz = 1.0 / controller.poll_period_s
    print(f"GRBL driver <-> simulator over a pty, {args.n} round trips each")
    print(f"  G-code line (send, wait ok):   median {line[0]:.3f} ms   p95 {line[1]:.3f} ms")
    print(f"  status query ('?' -> report):  median {query[0]:.3f} ms   p95 {query[1]:.3f} ms")
    print(f"  move_to, instant simulator:    median {move[0]:.3f} ms   p95 {move[1]:.3f} ms")
    print(f"  sustained status rate:         {rate_hz:.0f} reports/s = {rate_hz / poll_hz:.0f}x the driver's "
          f"{poll_hz:.0f} Hz polling, {rate_hz / 5:.0f}x GRBL's recommended 5 Hz")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
