"""How fast the planner answers while the operator types: ScenePlan.derive() alone, one Planner-panel
update (read the fields, derive, show outputs and warnings, publish), one update of the plan plots
and one paint of them, against a 16.7 ms frame (60 Hz) budget.

    ./.venv/bin/python benchmarks/planner_update.py [--n 200]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("LFSTUDIO_CONFIG_DIR", tempfile.mkdtemp(prefix="lfstudio-bench-"))

FRAME_MS = 16.7


def timed_ms(fn, n: int) -> list[float]:
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t0) * 1000.0)
    return out


def report(name: str, samples: list[float]) -> None:
    med = statistics.median(samples)
    p95 = sorted(samples)[int(0.95 * (len(samples) - 1))]
    print(f"{name:<38} median {med:8.3f} ms   p95 {p95:8.3f} ms   frame budget / median {FRAME_MS / med:7.1f}x")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="repetitions per figure")
    args = ap.parse_args()

    from PySide6.QtWidgets import QApplication

    from lfstudio.gui.panels.planner import PlannerPanel, PlanPlotsPanel
    from lfstudio.gui.state import AppState
    from lfstudio.planning.presets import reference_plan

    plan = reference_plan()
    report("ScenePlan.derive()", timed_ms(plan.derive, args.n * 10))

    app = QApplication.instance() or QApplication([])
    state = AppState()
    plots = PlanPlotsPanel(state)
    panel = PlannerPanel(state)
    plots.resize(900, 450)
    panel.resize(430, 900)
    near = panel.rows["near_m"].spins[0]
    values = [1.77, 1.8]

    def panel_update() -> None:         # one keystroke: a new value, then the (debounced) update
        values.reverse()
        near.setValue(values[0])
        panel.evaluate()
        app.processEvents()

    report("Planner update (fields → outputs)", timed_ms(panel_update, args.n))

    other = plan.replace(near_m=1.8)
    plans = [plan, other]

    def plots_update() -> None:         # what a (coalesced) plan change costs the plots
        plans.reverse()
        plots.draw(plans[0])

    report("Plan plots update (items in place)", timed_ms(plots_update, args.n))
    report("Plan plots paint (900 × 450, antialiased)", timed_ms(plots.grab, max(args.n // 4, 10)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
