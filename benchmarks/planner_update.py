"""How fast the planner answers while the operator types, against a 16.7 ms frame (60 Hz) budget:
``ScenePlan.derive()`` alone; one Planner-panel update (read the fields, derive, show outputs and
warnings, publish); one update of the plan plots with the paint of both plots (target < 16.7 ms);
and one keystroke in the main window (1600 × 1000, Planner and Plan plots shown): the GUI thread's
CPU time from the new value until every widget has repainted.

    ./.venv/bin/python benchmarks/planner_update.py [--n 200]

Keystrokes alternate between two values of one field (``--field near_m`` changes the depth-of-field
plot, ``spacing_mm`` the disparity plot). Each figure is given as the GUI thread's CPU time
(``time.thread_time``: what the GUI itself computes, barely changed by other programs) and wall
time, with the load average: on a loaded machine compare the CPU figures.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("LFSTUDIO_CONFIG_DIR", tempfile.mkdtemp(prefix="lfstudio-bench-"))

from _measure import load_text  # noqa: E402

FRAME_MS = 16.7


def timed_ms(fn, n: int) -> tuple[list[float], list[float]]:
    """Wall and GUI-thread CPU milliseconds of ``n`` calls of ``fn``."""
    wall, cpu = [], []
    for _ in range(n):
        t0, c0 = time.perf_counter(), time.thread_time()
        fn()
        cpu.append((time.thread_time() - c0) * 1000.0)
        wall.append((time.perf_counter() - t0) * 1000.0)
    return wall, cpu


def report(name: str, samples: tuple[list[float], list[float]], target: bool = False) -> None:
    wall, cpu = samples
    med, p95 = statistics.median(cpu), sorted(cpu)[int(0.95 * (len(cpu) - 1))]
    verdict = f"  (target < {FRAME_MS} ms: {'OK' if med < FRAME_MS else 'MISSED'})" if target else ""
    print(f"{name:<52} CPU median {med:7.2f} ms  p95 {p95:7.2f} ms   wall median {statistics.median(wall):7.2f} ms"
          f"{verdict}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="repetitions per figure")
    ap.add_argument("--field", choices=("near_m", "spacing_mm"), default="near_m", help="the field typed into")
    args = ap.parse_args()
    print(load_text())

    from PySide6.QtWidgets import QApplication

    from lfstudio.gui.app import create_window
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
    plots.show()
    app.processEvents()
    spin = panel.rows[args.field].spins[0]
    values = [spin.value(), spin.value() * 1.02]

    def panel_update() -> None:         # one keystroke: a new value, then the (debounced) update
        values.reverse()
        spin.setValue(values[0])
        panel.evaluate()
        app.processEvents()

    report("Planner update (fields → outputs)", timed_ms(panel_update, args.n))

    other = plan.replace(near_m=1.8) if args.field == "near_m" else plan.replace(spacing_mm=(4.1, 6.0))
    plans = [plan, other]

    def plots_update() -> None:         # what a (coalesced) plan change costs the plots, painted
        plans.reverse()
        plots.draw(plans[0])
        for plot in (plots.dof_plot, plots.disparity_plot):
            plot.viewport().repaint()

    report("Plan plots update + paint (900 × 450)", timed_ms(plots_update, args.n), target=True)

    # the whole window: what one keystroke costs the GUI thread, every repaint included
    window = create_window(simulated=False)
    window.resize(1600, 1000)
    window.show()
    for name in ("plannerDock", "planPlotsDock"):
        window.docks[name].show()
        window.docks[name].raise_()
    for _ in range(5):
        app.processEvents()
    wpanel = window.findChild(PlannerPanel)
    wplots = window.findChild(PlanPlotsPanel)
    wspin = wpanel.rows[args.field].spins[0]
    wvalues = [wspin.value(), wspin.value() * 1.02]

    def keystroke() -> None:
        wvalues.reverse()
        wspin.setValue(wvalues[0])
        wpanel.evaluate()                  # what the debounce timer calls
        wplots.draw(window.state.plan)     # what the coalescing timer calls
        app.processEvents()                # layouts and paints

    report(f"One keystroke in the main window (plots {wplots.width()} × {wplots.height()})",
           timed_ms(keystroke, max(args.n // 2, 10)))
    window.close()
    print(load_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
