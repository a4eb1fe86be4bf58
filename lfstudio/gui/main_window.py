"""The main window: dock panels around a central view, menus, status bar, and an always-visible STOP.

The STOP toolbar cannot be moved, hidden or closed, so STOP (Esc) is in sight with every panel
layout; it triggers the Rig panel's STOP. It also says when a scan owns the rig. Quitting while a
scan is active asks first (non-blocking dialog): stopping the scan lets the current view finish,
then the window closes; Cancel keeps the scan running.

Every panel sits in its dock inside a :class:`PanelScrollArea`: a dock given less room than the
panel needs (a small screen, docks stacked above each other) scrolls the panel instead of squeezing
its rows over each other or under the dock's tab bar; the panel is always laid out at least at its
minimum size (the dock asks for its preferred size; sideways too when the window is narrower than
the panels and the central view together).
"""

from __future__ import annotations

import importlib
import logging
from typing import Any

from PySide6.QtCore import QEvent, QSize, Qt, QTimer, QUrl
from PySide6.QtGui import QAction, QDesktopServices, QGuiApplication, QKeySequence
from PySide6.QtWidgets import (QApplication, QDockWidget, QFrame, QLabel, QMainWindow, QMenu, QMessageBox, QScrollArea,
                               QTabBar, QToolBar,
                               QWidget)

from lfstudio.errors import LfError, window_message
from lfstudio.gui.panels import CENTRAL, PANELS, PanelSpec
from lfstudio.gui.settings import settings
from lfstudio.gui.state import AppState
from lfstudio.scan.events import ScanState

log = logging.getLogger(__name__)

MENU_ORDER = ("File", "View", "Rig", "Dataset", "Help")
_AREAS = {"left": Qt.DockWidgetArea.LeftDockWidgetArea, "right": Qt.DockWidgetArea.RightDockWidgetArea,
          "bottom": Qt.DockWidgetArea.BottomDockWidgetArea, "top": Qt.DockWidgetArea.TopDockWidgetArea}


#: the first window's size, when the screen has room for it (else the screen's free room)
DEFAULT_SIZE = QSize(1500, 950)
#: room left for the window manager's frame and title bar around the first window
WINDOW_FRAME_PX = QSize(8, 40)
BOTTOM_SHARE = 0.5          # of the centre column's height, at most, for the docks under the central view
#: the panels in front at first start and after View → Reset layout
FIRST_STEPS = ("plannerDock", "planPlotsDock", "scanPanel")


def _screen_room(window: QWidget) -> QSize:
    """The largest window (without its frame) the window's screen has free room for."""
    screen = window.screen() or QGuiApplication.primaryScreen()
    if screen is None:
        return QSize(16777215, 16777215)
    free = screen.availableGeometry()
    return QSize(free.width() - WINDOW_FRAME_PX.width(), free.height() - WINDOW_FRAME_PX.height())


def load_target(target: str) -> Any:
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


class PanelScrollArea(QScrollArea):
    """A dock's panel, scrolled when the dock is smaller than the panel's minimum size.

    The panel fills the area but is never laid out below its own minimum size (then the area
    scrolls; a panel whose body scrolls by itself, the Planner, may say ``height_when_scrolled()``:
    the height that shows its whole body, so only one scroll bar is left). Not ``widgetResizable``: that lays out a panel holding a word-wrapped label at its
    preferred height for the width (a plot panel: twice the dock's height, always scrolled). The
    area asks for the panel's preferred size and minimum width (with room for the scroll bar), but
    only a few rows of height, so docks may be stacked or the window made low without squeezing
    any panel.
    """

    MIN_WIDTH_PX, MIN_HEIGHT_PX = 240, 120

    def __init__(self, panel: QWidget, parent: QWidget | None = None):
        super().__init__(parent)
        self.setObjectName(f"{panel.objectName() or type(panel).__name__}Scroll")
        self.setFrameShape(QFrame.Shape.NoFrame)
        self.setWidgetResizable(False)
        self.setWidget(panel)
        panel.installEventFilter(self)          # its minimum size may change (rows shown or hidden)

    def _need(self) -> QSize:
        panel = self.widget()
        if panel is None:           # its panel already deleted (the window closing)
            return QSize(0, 0)
        return panel.minimumSizeHint().expandedTo(panel.minimumSize())

    def need_width(self) -> int:
        """The width at which the panel needs no sideways scrolling (with room for the vertical bar)."""
        return self._need().width() + self._extra().width()

    def _extra(self) -> QSize:
        return QSize(self.verticalScrollBar().sizeHint().width() + 2 * self.frameWidth(), 2 * self.frameWidth())

    def fit_panel(self) -> None:
        """Lay the panel out at the area's size, but at least at its minimum size."""
        panel = self.widget()
        if panel is None:
            return
        need, room = self._need(), self.maximumViewportSize()
        bar = self.verticalScrollBar().sizeHint().width()
        down = need.height() > room.height()                               # scrolls up and down
        across = need.width() > room.width() - (bar if down else 0)        # scrolls sideways
        down = down or need.height() > room.height() - (bar if across else 0)
        height = max(room.height() - (bar if across else 0), need.height())
        width = max(room.width() - (bar if down else 0), need.width())
        wrapped = self._wrapped_height(width)   # word-wrapped lines (an error, a state) need more than the minimum
        if wrapped > height:
            if not down:                       # now it scrolls: narrower by the bar, perhaps a line more
                down = True
                width = max(room.width() - bar, need.width())
                wrapped = max(wrapped, self._wrapped_height(width))
            height = wrapped
        scrolled = getattr(panel, "height_when_scrolled", None)
        if down and scrolled is not None:      # a panel with a scrolled body of its own: one scroll bar, this one
            height = max(height, scrolled())
        panel.resize(width, height)

    def _wrapped_height(self, width: int) -> int:
        """The least height at which the panel's layout shows its word-wrapped labels whole at
        ``width`` (0: nothing wraps). A panel's minimum size counts a wrapped label's lines at its own
        width, so a long message in a narrow dock was cut to its first lines."""
        panel = self.widget()
        layout = panel.layout() if panel is not None else None
        if layout is None or not layout.hasHeightForWidth():
            return 0
        return layout.minimumHeightForWidth(width)

    def resizeEvent(self, event) -> None:
        super().resizeEvent(event)
        self.fit_panel()

    def eventFilter(self, obj, event) -> bool:
        if obj is self.widget() and event.type() == QEvent.Type.LayoutRequest:
            QTimer.singleShot(0, self.fit_panel)   # after the panel's layout has its new minimum
        return super().eventFilter(obj, event)

    def sizeHint(self) -> QSize:       # the panel's own (QScrollArea's is capped at 36 x 24 lines)
        panel = self.widget()
        return panel.sizeHint().expandedTo(self._need()) if panel is not None else super().sizeHint()

    def minimumSizeHint(self) -> QSize:
        if self.widget() is None:
            return super().minimumSizeHint()
        need = self._need() + self._extra()
        return QSize(min(need.width(), self.MIN_WIDTH_PX), min(need.height(), self.MIN_HEIGHT_PX))


class MainWindow(QMainWindow):
    def __init__(self, state: AppState, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.setWindowTitle("lfstudio — simulated studio" if state.simulated else "lfstudio")
        self.setObjectName("MainWindow")
        self.setDockNestingEnabled(True)
        # side panels run the full height; a bottom dock (plots) sits under the central view only
        self.setCorner(Qt.Corner.BottomLeftCorner, Qt.DockWidgetArea.LeftDockWidgetArea)
        self.setCorner(Qt.Corner.BottomRightCorner, Qt.DockWidgetArea.RightDockWidgetArea)
        self.resize(DEFAULT_SIZE)
        self._fit_on_show = False
        self._check_restored_on_show = False
        self.docks_fitted = 0         # how many times fit_docks ran (first show, Reset layout)
        self._menus: dict[str, QMenu] = {}
        for name in MENU_ORDER:
            self.menu(name)
        self.panels: dict[str, QWidget] = {}
        self.docks: dict[str, QDockWidget] = {}

        self.central = load_target(CENTRAL)(state)
        self.setCentralWidget(self.central)
        for spec in PANELS:
            self._add_panel(spec)
        for widget in [self.central, *self.panels.values()]:
            install = getattr(widget, "install_menus", None)
            if install is not None:
                install(self)
        from lfstudio.gui.dialogs import import_dialog
        import_dialog.install_menus(self)
        from lfstudio.gui.views import depth as depth_view
        depth_view.install_menus(self)
        from lfstudio.gui.views import radiance as radiance_view
        radiance_view.install_menus(self)
        self._install_base_menus()
        self._quit_box: QMessageBox | None = None
        self._quit_after_scan = False
        self._install_stop_toolbar()
        state.scanStateChanged.connect(self._on_scan_state)
        state.scanEvents.connect(self._refresh_quit_box)

        state.statusMessage.connect(lambda text, ms: self.statusBar().showMessage(text, ms))
        state.errorOccurred.connect(self.show_error)
        self.statusBar().showMessage("Ready — simulated studio" if state.simulated else "Ready")
        self._default_state = self.saveState()     # the first-start layout, for View → Reset layout
        self._restore_geometry()

    # -- structure ---------------------------------------------------------------------------------
    def menu(self, name: str) -> QMenu:
        """The top-level menu ``name`` (created on first use, in MENU_ORDER where listed)."""
        if name not in self._menus:
            menu = QMenu(f"&{name}", self)
            menu.setObjectName(f"menu{name}")
            help_menu = self._menus.get("Help")
            if help_menu is not None and name not in MENU_ORDER:
                self.menuBar().insertMenu(help_menu.menuAction(), menu)
            else:
                self.menuBar().addMenu(menu)
            self._menus[name] = menu
        return self._menus[name]

    def _add_panel(self, spec: PanelSpec) -> None:
        try:
            widget = load_target(spec.target)(self.state)
        except Exception as exc:  # a broken panel must not take the whole window down
            log.exception("panel %s failed to load", spec.title)
            self.state.report_error(f"{spec.title} panel", f"The {spec.title} panel could not start: {exc}")
            return
        dock = QDockWidget(spec.title, self)
        dock.setObjectName(spec.object_name)
        dock.setWidget(PanelScrollArea(widget))
        dock.setFeatures(QDockWidget.DockWidgetFeature.DockWidgetMovable | QDockWidget.DockWidgetFeature.DockWidgetFloatable
                         | QDockWidget.DockWidgetFeature.DockWidgetClosable)
        self.panels[spec.object_name] = widget
        self.docks[spec.object_name] = dock
        self._place_dock(spec, dock)
        self.menu("View").addAction(dock.toggleViewAction())

    def _place_dock(self, spec: PanelSpec, dock: QDockWidget) -> None:
        """Put ``dock`` where the default layout has it (its area, a tab behind ``spec.tab_with``)."""
        dock.setFloating(False)
        self.addDockWidget(_AREAS.get(spec.area, Qt.DockWidgetArea.LeftDockWidgetArea), dock)
        first = self.docks.get(spec.tab_with)
        if first is not None:           # a tab behind an earlier panel: both keep the full height
            self.tabifyDockWidget(first, dock)
            first.raise_()
        dock.setVisible(spec.visible)

    def _raise_first_steps(self) -> None:
        for name in FIRST_STEPS:
            if name in self.docks:
                self.docks[name].raise_()

    def reset_layout(self) -> None:
        """View → Reset layout: every panel back in its first-start place, tab and width (floating
        ones docked, closed ones shown as at first start); the window fitted to its screen."""
        self.restoreState(self._default_state)
        for spec in PANELS:
            dock = self.docks.get(spec.object_name)
            if dock is not None:
                dock.setVisible(spec.visible)
        self.stop_toolbar.setVisible(True)
        self._raise_first_steps()
        if not self.isMaximized() and not self.isFullScreen():
            room = _screen_room(self)
            if self.width() > room.width() or self.height() > room.height():
                self.resize(self.size().boundedTo(room))
        QTimer.singleShot(0, self.fit_docks)
        self.statusBar().showMessage("Layout reset: every panel in its first-start place", 5000)

    def fit_docks(self) -> None:
        """Give the side docks the width their panels need (no sideways scrolling) and the central
        view the rest; when the window is too narrow for all three, the docks share what is left
        after the central view's minimum in proportion to their needs."""
        widths: dict[Qt.DockWidgetArea, tuple[int, list[QDockWidget]]] = {}
        for dock, scroll in self._side_panels():
            area = self.dockWidgetArea(dock)
            frame = max(0, dock.width() - scroll.width())
            need = scroll.need_width() + frame
            most, docks = widths.get(area, (0, []))
            widths[area] = (max(most, need), docks + [dock])
        if not widths:
            return
        separator = self.style().pixelMetric(self.style().PixelMetric.PM_DockWidgetSeparatorExtent, None, self)
        room = self.width() - self.central.minimumSizeHint().width() - separator * (len(widths) + 1)
        total = sum(need for need, _ in widths.values())
        scale = min(1.0, room / total) if total > 0 else 1.0
        docks, sizes = [], []
        for need, area_docks in widths.values():
            for dock in area_docks:
                docks.append(dock)
                sizes.append(max(PanelScrollArea.MIN_WIDTH_PX, int(need * scale)))
        self.resizeDocks(docks, sizes, Qt.Orientation.Horizontal)
        self._fit_bottom_docks()
        self.hide_stale_tab_bars()
        self.docks_fitted += 1

    def _fit_bottom_docks(self) -> None:
        """The docks under the central view (Plan plots, Live view) take at most
        :data:`BOTTOM_SHARE` of the centre column's height: at 1366 x 768 they took three quarters and
        the grid of a 5 x 5 dataset showed 20 px thumbnails (their panels scroll instead)."""
        bottom = [d for d in self.docks.values() if not d.isFloating() and d.isVisible()
                  and not d.visibleRegion().isEmpty()        # a tab behind another has a stale size
                  and self.dockWidgetArea(d) == Qt.DockWidgetArea.BottomDockWidgetArea]
        if not bottom:
            return
        column = self.central.height() + max(d.height() for d in bottom)
        most = int(column * BOTTOM_SHARE)
        if max(d.height() for d in bottom) > most:
            self.resizeDocks(bottom, [most] * len(bottom), Qt.Orientation.Vertical)

    def dock_tab_bars(self) -> list[QTabBar]:
        """The tab bars of tabbed docks (the main window's own children; a panel's tabs are not)."""
        return self.findChildren(QTabBar, options=Qt.FindChildOption.FindDirectChildrenOnly)

    def tab_bar_in_place(self, bar: QTabBar) -> bool:
        """Whether ``bar`` sits against the dock whose tab is current (below it, or above it), as wide."""
        dock = next((d for d in self.docks.values() if d.windowTitle() == bar.tabText(bar.currentIndex())), None)
        if dock is None or dock.isFloating() or not dock.isVisible():
            return False
        b, d = bar.geometry(), dock.geometry()
        return (abs(b.left() - d.left()) <= 2 and abs(b.width() - d.width()) <= 2
                and (abs(b.top() - d.bottom() - 1) <= 2 or abs(d.top() - b.bottom() - 1) <= 2))

    def hide_stale_tab_bars(self) -> None:
        """Hide dock tab bars Qt left behind: tabifying docks before the window is first shown leaves
        a second, unused copy of a group's tab bar (Qt 6.11) that is painted where the group's bar was
        first laid out (over the status bar at 1600 x 1000, "Planner Rig" under "Planner Rig Camera")."""
        for bar in self.dock_tab_bars():
            if bar.isVisible() and not self.tab_bar_in_place(bar):
                bar.hide()

    def showEvent(self, event) -> None:
        super().showEvent(event)
        QTimer.singleShot(0, self.hide_stale_tab_bars)     # after the first layout (also a restored one)
        if self._fit_on_show:
            self._fit_on_show = False
            QTimer.singleShot(0, self.fit_docks)      # after the first layout has placed the docks
        elif self._check_restored_on_show:
            self._check_restored_on_show = False
            QTimer.singleShot(0, self._fit_squeezed_docks)

    def _fit_squeezed_docks(self) -> None:
        """A restored layout stays as saved unless a side panel in it is too narrow for its controls
        (saved on a larger screen, or dragged narrow): then the docks are fitted as at first start."""
        if any(scroll.width() < scroll.need_width() for _dock, scroll in self._side_panels()
               if not scroll.visibleRegion().isEmpty()):
            self.fit_docks()

    def _side_panels(self):
        """(dock, its PanelScrollArea) of each visible panel docked at the left or right."""
        for dock in self.docks.values():
            scroll = dock.widget()
            if not dock.isFloating() and dock.isVisible() and isinstance(scroll, PanelScrollArea) \
                    and scroll.widget() is not None \
                    and self.dockWidgetArea(dock) in (Qt.DockWidgetArea.LeftDockWidgetArea, Qt.DockWidgetArea.RightDockWidgetArea):
                yield dock, scroll

    def _install_base_menus(self) -> None:
        file_menu = self.menu("File")
        file_menu.addSeparator()
        self._install_export_action(file_menu)
        file_menu.addSeparator()
        prefs = QAction("&Settings…", self)
        prefs.setObjectName("actionSettings")
        prefs.setShortcut(QKeySequence("Ctrl+,"))
        prefs.setToolTip("Default folders and the default camera, lens and rig presets")
        prefs.triggered.connect(self.open_settings)
        file_menu.addAction(prefs)
        quit_action = QAction("&Quit", self)
        quit_action.setShortcut(QKeySequence.StandardKey.Quit)
        quit_action.setToolTip("Close lfstudio")
        quit_action.triggered.connect(self.close)
        file_menu.addAction(quit_action)

        view_menu = self.menu("View")
        view_menu.addSeparator()
        reset = QAction("&Reset layout", self)
        reset.setObjectName("actionResetLayout")
        reset.setToolTip("Every panel back in its first-start place and width (floating panels docked, "
                         "closed ones shown), the window fitted to the screen")
        reset.setStatusTip(reset.toolTip())
        reset.triggered.connect(self.reset_layout)
        view_menu.addAction(reset)
        self.reset_layout_action = reset

        help_menu = self.menu("Help")
        guide = QAction("&User guide", self)
        guide.setObjectName("actionUserGuide")
        guide.setShortcut(QKeySequence.StandardKey.HelpContents)
        guide.setShortcutContext(Qt.ShortcutContext.ApplicationShortcut)     # F1 in a dialog too: its page
        guide.setToolTip("Read the user guide (planning, rig, cameras, scanning, calibration, processing)")
        guide.triggered.connect(lambda: self.show_user_guide(self.help_topic()))
        logs = QAction("Show &log folder", self)
        logs.setObjectName("actionShowLogFolder")
        logs.setToolTip("Open the folder with lfstudio's log files (send them with a problem report)")
        logs.triggered.connect(self.show_log_folder)
        about = QAction("&About lfstudio", self)
        about.setObjectName("actionAbout")
        about.setToolTip("lfstudio's version and the versions of Qt, OpenCV, LibRaw, FFmpeg, libgphoto2 …")
        about.triggered.connect(self.show_about)
        help_menu.addSeparator()
        for action in (guide, logs):
            help_menu.addAction(action)
        help_menu.addSeparator()
        help_menu.addAction(about)

    def _install_stop_toolbar(self) -> None:
        """STOP, always in sight: a toolbar that cannot be moved, floated, hidden or closed."""
        action = getattr(self.panels.get("rigDock"), "stop_action", None)
        if action is None:          # no Rig panel: stop the connected rig directly
            action = QAction("&STOP all motion", self)
            action.setShortcut(QKeySequence(Qt.Key.Key_Escape))
            action.triggered.connect(self.stop_rig)
            self.addAction(action)
        action.setIconText("STOP (Esc)")
        self.stop_action = action
        bar = QToolBar("STOP", self)
        bar.setObjectName("stopToolBar")
        bar.setMovable(False)
        bar.setFloatable(False)
        bar.setContextMenuPolicy(Qt.ContextMenuPolicy.PreventContextMenu)
        bar.toggleViewAction().setVisible(False)       # not in the toolbar/dock context menu either
        bar.addAction(action)
        self.stop_button = bar.widgetForAction(action)
        self.stop_button.setObjectName("stopToolButton")
        self.stop_button.setToolTip("Stop all motion now (Esc), whatever runs: a jog, a go-to, homing or a scan "
                                    "(the scan pauses). Never waits behind other commands.")
        from lfstudio.gui.rig_badge import RigBadge

        self.rig_badge = RigBadge(self.state, self.show_rig_panel)
        bar.addSeparator()
        bar.addWidget(self.rig_badge)
        self.scan_lock_label = QLabel("")
        self.scan_lock_label.setObjectName("scanLockLabel")
        self.scan_lock_label.setContentsMargins(12, 0, 12, 0)
        bar.addWidget(self.scan_lock_label)
        self.addToolBar(Qt.ToolBarArea.TopToolBarArea, bar)
        self.stop_toolbar = bar

    def show_rig_panel(self) -> None:
        """The Rig panel in front (shown and docked back if it was closed)."""
        dock = self.docks.get("rigDock")
        if dock is not None:
            dock.show()
            dock.raise_()

    def stop_rig(self) -> None:
        """STOP without a Rig panel: the connected rig's stop, bypassing its queue."""
        device = self.state.devices.get("rig")
        if device is not None:
            device.stop_now()
            self.statusBar().showMessage("Rig: STOP", 5000)
        self.state.stopRequested.emit()        # a rig no panel holds yet (a scan being prepared) stops too

    def _on_scan_state(self, scan_state: ScanState) -> None:
        label = self.state.scan_label or "the scan"
        if self.state.scan_owns_rig:
            text = f"{label[0].upper()}{label[1:]} has the rig: motion controls are locked until it ends or is paused."
        elif scan_state is ScanState.PAUSED:
            text = f"{label[0].upper()}{label[1:]} is paused: the rig is free (Resume in the Scan panel)."
        else:
            text = ""
        self.scan_lock_label.setText(text)
        if self._quit_after_scan and not self.state.scan_active:
            QTimer.singleShot(0, self.close)

    def _install_export_action(self, menu: QMenu) -> None:
        self.export_dialog = None
        self.export_action = QAction("&Export dataset…", self)
        self.export_action.setObjectName("actionExport")
        self.export_action.setShortcut(QKeySequence("Ctrl+E"))
        self.export_action.triggered.connect(self.open_export_dialog)
        menu.addAction(self.export_action)
        self.state.datasetChanged.connect(self._update_export_action)
        self._update_export_action(self.state.dataset)

    def _update_export_action(self, dataset) -> None:
        if dataset is None:
            tip = "Export dataset: no dataset is open. Open one (File → Open dataset…) or scan one first."
        else:
            tip = (f"Export {dataset.root.name} as 16-bit PNG, HEVC 12-bit 4:4:4 or the HCI benchmark layout, "
                   "with a size estimate first")
        self.export_action.setEnabled(dataset is not None)
        self.export_action.setToolTip(tip)
        self.export_action.setStatusTip(tip)

    def open_export_dialog(self) -> None:
        """File → Export dataset…: the export dialog for the open dataset (one at a time)."""
        if self.state.dataset is None:
            self.state.report_error("Export dataset", "No dataset is open: open a dataset folder first "
                                    "(File → Open dataset…) or scan one.")
            return
        from lfstudio.gui.dialogs.export_dialog import ExportDialog

        dialog = self.export_dialog
        if dialog is not None and dialog.isVisible():
            if dialog.dataset.root == self.state.dataset.root or dialog.runner.running:
                dialog.raise_()
                dialog.activateWindow()
                return
            dialog.close()
        try:
            self.export_dialog = ExportDialog(self.state, self)
        except LfError as exc:
            self.state.report_error("Export dataset", window_message(exc))
            return
        self.export_dialog.show()

    def open_settings(self):
        from lfstudio.gui.dialogs.settings_dialog import SettingsDialog, apply_to_window

        dialog = SettingsDialog(self)
        old = dialog.values()

        def accepted() -> None:
            new = dialog.values()
            dialog.store()
            applied = apply_to_window(self, old, new)
            self.statusBar().showMessage("Settings saved" + (f"; applied to {', '.join(applied)}" if applied else ""),
                                         8000)

        dialog.accepted.connect(accepted)
        dialog.open()
        return dialog

    def help_topic(self) -> str | None:
        """The dialog in front (its object name, when the site has a page for it), else the panel the
        keyboard focus is in (its dock's object name), or None."""
        from lfstudio.support.userguide import SITE_PAGES

        window = QApplication.activeWindow()
        if window is not None and window is not self and window.objectName() in SITE_PAGES:
            return window.objectName()
        widget = QApplication.focusWidget()
        while widget is not None:
            if isinstance(widget, QDockWidget) and widget.objectName() in self.docks:
                return widget.objectName()
            widget = widget.parentWidget()
        return None

    def show_user_guide(self, topic: str | None = None):
        """The documentation site's page for ``topic`` (a panel) in the browser when the site is built and
        shipped (:func:`lfstudio.support.userguide.site_page`; returns None), else the in-app user guide
        (returns the dialog)."""
        from lfstudio.gui.dialogs.help_dialogs import UserGuideDialog
        from lfstudio.support.userguide import site_page

        page = site_page(topic)
        if page is not None and QDesktopServices.openUrl(QUrl.fromLocalFile(str(page))):
            self.statusBar().showMessage(f"User guide: {page} opened in the browser", 10000)
            return None
        dialog = UserGuideDialog(self)
        dialog.show()
        return dialog

    def show_about(self):
        from lfstudio.gui.dialogs.help_dialogs import AboutDialog

        dialog = AboutDialog(self)
        dialog.show()
        return dialog

    def show_log_folder(self) -> None:
        from lfstudio.gui.crash import open_log_folder
        from lfstudio.support.logs import log_dir

        if not open_log_folder():
            self.show_error("Log folder", f"No file manager could be opened. The log files are in {log_dir()}")
        else:
            self.statusBar().showMessage(f"Log files: {log_dir()}", 10000)

    def show_error(self, title: str, message: str) -> None:
        self.statusBar().showMessage(f"{title}: {message.splitlines()[0] if message else ''}", 10000)
        box = QMessageBox(QMessageBox.Icon.Warning, title, message, QMessageBox.StandardButton.Ok, self)
        box.setObjectName("errorBox")
        box.open()  # non-modal: never blocks the event loop

    def connect_simulated_studio(self) -> None:
        """Connect the simulated rig and camera (the built-in studio), as ``lfstudio`` does on start.

        Homing stays the operator's step, as on the real rig."""
        from lfstudio.gui.panels.camera import CameraPanel
        from lfstudio.gui.panels.rig import RigPanel

        rig, camera = self.panels.get("rigDock"), self.panels.get("cameraDock")
        if isinstance(rig, RigPanel) and not rig.connected and rig.chosen_port() in ("sim", "sim-dryve"):
            rig.connect_rig()
        if isinstance(camera, CameraPanel) and not camera.connected and camera.current_kind() == "sim":
            camera.connect_camera()
        self.statusBar().showMessage("Simulated studio: rig and camera connecting. Home the rig "
                                     "(Rig → Home) before jogging or scanning.", 15000)

    # -- persistence -------------------------------------------------------------------------------
    def _restore_geometry(self) -> None:
        s = settings()
        geometry, window_state = s.value("window/geometry"), s.value("window/state")
        if geometry is not None:
            self.restoreGeometry(geometry)
            self._fit_to_screen()
        else:       # first start: as large as the default but no larger than the screen's free room
            room = _screen_room(self)
            self.resize(self.size().boundedTo(room))
            screen = self.screen()
            if screen is not None:
                free = screen.availableGeometry()
                self.move(free.x() + (free.width() - self.width()) // 2,
                          free.y() + max(0, (free.height() - self.height() - WINDOW_FRAME_PX.height()) // 2))
        if window_state is not None:
            self.restoreState(window_state)
            self.stop_toolbar.setVisible(True)          # STOP stays in sight whatever was saved
            self._check_restored_on_show = True         # ... and no side panel squeezed (see showEvent)
        else:  # first start: the panels of the first steps in front, the side docks as wide as they need
            self._raise_first_steps()
            self._fit_on_show = True

    def _fit_to_screen(self) -> None:
        """A remembered geometry from a larger screen (or another monitor) fitted to the screen the
        window opens on: no larger than its free room, and moved inside it. A maximised or full-screen
        window is the screen's own size already."""
        if self.isMaximized() or self.isFullScreen():
            return
        screen = self.screen() or QGuiApplication.primaryScreen()
        if screen is None:
            return
        free = screen.availableGeometry()
        room = _screen_room(self)
        if self.width() > room.width() or self.height() > room.height():
            self.resize(self.size().boundedTo(room))
        frame = QSize(self.width() + WINDOW_FRAME_PX.width(), self.height() + WINDOW_FRAME_PX.height())
        x = min(max(self.x(), free.left()), free.left() + free.width() - frame.width())
        y = min(max(self.y(), free.top()), free.top() + free.height() - frame.height())
        if (x, y) != (self.x(), self.y()):
            self.move(x, y)

    def ask_quit_during_scan(self) -> QMessageBox:
        """The question asked when the window is closed during a scan (non-blocking)."""
        box = self._quit_box
        if box is not None and box.isVisible():
            box.raise_()
            return box
        dataset = self.state.dataset
        folder = str(dataset.root) if dataset is not None else "the dataset folder"
        box = QMessageBox(QMessageBox.Icon.Warning, "Quit during a scan", self._quit_question(),
                          QMessageBox.StandardButton.NoButton, self)
        box.setObjectName("quitDuringScanBox")
        box.setInformativeText(
            "If you quit now, the scan stops after the current view. Everything captured stays in "
            f"{folder} and can be resumed: lfstudio offers it at its next start (or put this folder in the "
            "Scan panel's Folder field and press Start).")
        stop = box.addButton("Stop the scan and quit", QMessageBox.ButtonRole.DestructiveRole)
        keep = box.addButton("Cancel: keep scanning", QMessageBox.ButtonRole.RejectRole)
        stop.setObjectName("stopAndQuitButton")
        keep.setObjectName("keepScanningButton")
        box.setDefaultButton(keep)
        box.setEscapeButton(keep)
        box.buttonClicked.connect(lambda button: self._quit_answered(button is stop))
        self._quit_box = box
        box.open()
        return box

    def _quit_question(self) -> str:
        label = self.state.scan_label or "the scan"
        done, total = self.state.scan_progress
        how = "paused" if self.state.scan_state is ScanState.PAUSED else "running"
        return f"{label[0].upper()}{label[1:]} is {how}: {done} of {total} {'view' if total == 1 else 'views'} captured."

    def _refresh_quit_box(self, _events=None) -> None:
        """The quit question's count follows the scan while it is open (it was frozen at opening)."""
        box = self._quit_box
        if box is not None and box.isVisible():
            text = self._quit_question()
            if box.text() != text:
                box.setText(text)

    def _quit_answered(self, stop_scan: bool) -> None:
        if not stop_scan:
            self.statusBar().showMessage("Not quitting: the scan goes on.", 5000)
            return
        self._quit_after_scan = True
        from lfstudio.gui.panels.scan import ScanPanel

        scan = self.panels.get("scanPanel")
        if isinstance(scan, ScanPanel):
            scan.abort()
        self.statusBar().showMessage("Stopping the scan after the current view; lfstudio closes when it has "
                                     "stopped.", 0)
        if not self.state.scan_active:
            QTimer.singleShot(0, self.close)

    def closeEvent(self, event) -> None:
        if self.state.scan_active and not self._quit_after_scan:
            event.ignore()
            self.ask_quit_during_scan()
            return
        s = settings()
        s.setValue("window/geometry", self.saveGeometry())
        s.setValue("window/state", self.saveState())
        for widget in [self.central, *self.panels.values(), getattr(self, "export_dialog", None)]:
            shutdown = getattr(widget, "shutdown", None)
            if shutdown is not None:
                try:
                    shutdown()
                except Exception:
                    log.exception("shutdown of %s failed", type(widget).__name__)
        super().closeEvent(event)
