"""The dock panels of the main window. Add a panel by appending a :class:`PanelSpec` to :data:`PANELS`.

A panel class is constructed as ``Panel(state: AppState)`` and is a ``QWidget``. It may define
``install_menus(window)`` to add its actions to the window's menus (``window.menu("Rig")``), and
``shutdown()`` to stop its threads when the window closes.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PanelSpec:
    title: str
    object_name: str      # stable name: dock geometry is saved under it
    target: str           # "module:ClassName"
    area: str = "left"    # left | right | bottom | top
    visible: bool = True  # shown on first start
    tab_with: str = ""    # object_name of an earlier panel to share a tabbed dock with (same area)


PANELS: list[PanelSpec] = [
    PanelSpec("Planner", "plannerDock", "lfstudio.gui.panels.planner:PlannerPanel", "left"),
    PanelSpec("Plan plots", "planPlotsDock", "lfstudio.gui.panels.planner:PlanPlotsPanel", "bottom"),
    PanelSpec("Scan", "scanPanel", "lfstudio.gui.panels.scan:ScanPanel", "right"),
    PanelSpec("Processing", "processingPanel", "lfstudio.gui.panels.processing:ProcessingPanel", "right",
              tab_with="scanPanel"),
    PanelSpec("Rig", "rigDock", "lfstudio.gui.panels.rig:RigPanel", "left", tab_with="plannerDock"),
    PanelSpec("Calibration", "calibrationPanel", "lfstudio.gui.panels.calibration:CalibrationPanel", "right",
              tab_with="processingPanel"),
    PanelSpec("Camera", "cameraDock", "lfstudio.gui.panels.camera:CameraPanel", "left", tab_with="rigDock"),
    PanelSpec("Live view", "liveViewDock", "lfstudio.gui.views.live_view:LiveView", "bottom",
              tab_with="planPlotsDock"),
]

#: the central widget, "module:ClassName" constructed as ``Cls(state)``
CENTRAL = "lfstudio.gui.views.grid_view:GridView"
