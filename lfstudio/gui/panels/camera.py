"""Camera panel: choose the camera (simulated studio / USB via gphoto2 / hot folder / every other
registered camera kind, GenICam and plugins included, each with a form built from its described
options: :class:`lfstudio.gui.kind_form.KindForm`), its settings,
connect it (it then appears as ``state.devices["camera"]`` for the scan and the live view), and
take a test shot that the Live view shows.

While a scan owns the camera (``AppState.scan_owns_camera``) Test shot, Apply to camera and
Connect/Disconnect (buttons and menu entries) are disabled with a tooltip saying why, and a note
names the scan; they come back when it ends or is paused. The core refuses such calls anyway (the
scan holds the camera worker's lease, :meth:`lfstudio.rig.worker.DeviceWorker.claim`)."""

from __future__ import annotations

import datetime as _dt
import shlex
from pathlib import Path
from typing import Any

from PySide6.QtCore import Qt
from PySide6.QtGui import QAction, QKeySequence
from PySide6.QtWidgets import (QComboBox, QDoubleSpinBox, QFileDialog, QFormLayout, QGroupBox, QHBoxLayout,
                               QLabel, QLineEdit, QPushButton, QSpinBox, QVBoxLayout, QWidget)

from lfstudio.dataset.paths import expand_path
from lfstudio.errors import InputError
from lfstudio.gui.devices import QtDevice
from lfstudio.gui.kind_form import KindForm
from lfstudio.gui.path_field import expand_on_edit
from lfstudio.gui.settings import read_float, read_int, read_text, settings
from lfstudio.gui.state import AppState
from lfstudio.gui.widgets import PageStack, show_lock_note
from lfstudio.resources import user_config_dir
from lfstudio.rig.camera import DescribesSettings
from lfstudio.rig.worker import DeviceWorker

#: the kinds with a page of their own here; every other registered camera kind (but "instant", for tests)
#: gets a KindForm from its description
KINDS = (("sim", "Simulated studio camera"), ("gphoto2", "USB camera (gphoto2)"),
         ("folder", "Hot folder (vendor software)"))
HIDDEN_KINDS = ("instant",)
#: where versions before the generated hot-folder page saved its Timeout (now devices/folder/timeout_s)
OLD_HOT_TIMEOUT_KEY = "camera/hot_timeout_s"


def form_kinds() -> list[Any]:
    """The registered camera kinds the panel shows with a KindForm (built-in GenICam, plugins)."""
    from lfstudio.studio.kinds import camera_kinds

    own = {key for key, _ in KINDS} | set(HIDDEN_KINDS)
    return [kind for name, kind in camera_kinds().items() if name not in own]
ISO_CHOICES = ("50", "100", "200", "400", "800", "1600", "3200", "6400")


def test_shot(driver: Any, folder: Path) -> tuple[Any, Any]:
    """Capture into ``folder`` and make an 8-bit preview of the file (runs on the camera's thread)."""
    from lfstudio.dataset.images import preview_rgb8

    from lfstudio.rig.camera import stored

    stem = folder / _dt.datetime.now().strftime("test_%Y%m%d_%H%M%S_%f")
    result = stored(driver.capture(stem))         # an array camera's frame written as a file
    return result, preview_rgb8(result.path, 1600)


def simulated_position(state: AppState):
    """The camera position the simulated camera asks for: the true position of the GRBL simulator the
    Rig panel runs, or of the ``lfstudio sim-rig`` whose port it is connected to; else (0, 0)."""
    sources: dict[str, Any] = {}

    def position() -> tuple[float, float]:
        sim = state.devices.get("rig_simulator")
        try:
            if sim is not None and hasattr(sim, "true_position_mm"):
                return tuple(sim.true_position_mm())
            link = state.devices.get("rig_link")
            port = getattr(link, "port", "")
            if port:
                if port not in sources:
                    from lfstudio.studio.simulated import truth_source

                    sources[port] = truth_source(port)
                if sources[port] is not None:
                    return tuple(sources[port]())
        except Exception:  # noqa: BLE001 - the simulator is closing: fall back to the origin
            return (0.0, 0.0)
        return (0.0, 0.0)
    return position


class CameraPanel(QWidget):
    def __init__(self, state: AppState, parent: QWidget | None = None):
        super().__init__(parent)
        self.state = state
        self.device: QtDevice | None = None
        self.link: Any = None          # the CameraLink (driver + lock) while connected
        s = settings()

        self.kind = QComboBox()
        for key, label in KINDS:
            self.kind.addItem(label, key)
        self.forms: dict[str, KindForm] = {}
        for kind in form_kinds():
            self.kind.addItem(kind.label or kind.name, kind.name)
            self.forms[kind.name] = KindForm(kind)
            self.forms[kind.name].settingRequested.connect(self.set_on_camera)
        self.kind.setToolTip("Which camera to use: the simulated studio (renders the virtual scene from the "
                             "simulated rig's position), a USB camera through libgphoto2, a folder that "
                             "the camera's own software saves into, a machine-vision camera (GenICam), or an "
                             "installed plugin's camera")
        index = self.kind.findData(s.value(self.kind_key, "sim" if state.simulated else "gphoto2"))
        self.kind.setCurrentIndex(max(0, index))

        # simulated
        self.sim_width = QSpinBox()
        self.sim_width.setRange(320, 7952)
        self.sim_width.setSingleStep(100)
        self.sim_width.setValue(read_int("camera/sim_width_px", 2000, s))
        self.sim_width.setSuffix(" px")
        self.sim_width.setToolTip("Width of the simulated images (the reference sensor is 7952 px; 2000 renders fast)")
        self.sim_noise = QDoubleSpinBox()
        self.sim_noise.setRange(0, 5)
        self.sim_noise.setDecimals(2)
        self.sim_noise.setSingleStep(0.05)
        self.sim_noise.setSuffix(" %")
        self.sim_noise.setValue(read_float("camera/sim_noise_pct", 0.2, s))
        self.sim_noise.setToolTip("Read noise in % of the clipping level (shot noise is always added with it)")
        self.sim_flicker = QDoubleSpinBox()
        self.sim_flicker.setRange(0, 20)
        self.sim_flicker.setDecimals(1)
        self.sim_flicker.setSuffix(" %")
        self.sim_flicker.setValue(read_float("camera/sim_flicker_pct", 1.0, s))
        self.sim_flicker.setToolTip("Light flicker: the brightness of each shot varies by this standard deviation")
        self.sim_vignetting = QDoubleSpinBox()
        self.sim_vignetting.setRange(0, 80)
        self.sim_vignetting.setDecimals(0)
        self.sim_vignetting.setSuffix(" %")
        self.sim_vignetting.setValue(read_float("camera/sim_vignetting_pct", 20, s))
        self.sim_vignetting.setToolTip("Light lost in the image corners")
        self.sim_time_scale = QDoubleSpinBox()
        self.sim_time_scale.setRange(0, 1)
        self.sim_time_scale.setDecimals(2)
        self.sim_time_scale.setSingleStep(0.1)
        self.sim_time_scale.setValue(read_float("camera/sim_time_scale", 1.0, s))
        self.sim_time_scale.setToolTip("Simulated exposure/transfer delays: 1 = real time, 0 = none")
        self.sim_truth = QLabel("")
        self.sim_truth.setWordWrap(True)
        self.sim_truth.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        sim_page = QWidget()
        f = QFormLayout(sim_page)
        f.setContentsMargins(0, 0, 0, 0)
        f.addRow("Image width", self.sim_width)
        f.addRow("Noise", self.sim_noise)
        f.addRow("Flicker", self.sim_flicker)
        f.addRow("Vignetting", self.sim_vignetting)
        f.addRow("Time scale", self.sim_time_scale)
        f.addRow(self.sim_truth)

        # gphoto2: the page its kind's description makes (no argument, no options: what to do first)
        from lfstudio.studio.kinds import camera_kind

        gp_page = KindForm(camera_kind("gphoto2"))

        # hot folder
        self.folder_edit = QLineEdit(read_text("camera/hot_folder", "", s))
        self.folder_edit.setPlaceholderText("folder the camera software saves into")
        self.folder_edit.setToolTip("New files appearing here are taken as the shots "
                                    "(~ and $VARIABLES are expanded)")
        expand_on_edit(self.folder_edit, "Folder")
        browse = QPushButton("Browse…")
        browse.setToolTip("Choose the hot folder")
        browse.clicked.connect(self._browse)
        row = QHBoxLayout()
        row.addWidget(self.folder_edit, 1)
        row.addWidget(browse)
        self.trigger_edit = QLineEdit(read_text("camera/trigger_command", "", s))
        self.trigger_edit.setPlaceholderText('optional, e.g. vendorcli --capture')
        self.trigger_edit.setToolTip("Command run for each shot, split into arguments like a shell would but "
                                     "never run through a shell; leave empty to trigger by hand")
        # the hot folder's connection options (wait for the file, unchanged for) from its kind's description;
        # the wait an earlier version saved (camera/hot_timeout_s) is taken over once
        if s.contains(OLD_HOT_TIMEOUT_KEY):
            if not s.contains("devices/folder/timeout_s"):
                s.setValue("devices/folder/timeout_s", f"{read_float(OLD_HOT_TIMEOUT_KEY, 30.0, s):g}")
            s.remove(OLD_HOT_TIMEOUT_KEY)
        self.folder_options = KindForm(camera_kind("folder"), argument=False)
        self.folder_options.info.setVisible(False)
        # Folder and Trigger command in the form's own layout: one label column, the fields aligned
        # (in a form of their own around it, the option rows' fields stood 7 px to the right)
        folder_page = self.folder_options
        ff = folder_page.layout()
        assert isinstance(ff, QFormLayout)
        ff.insertRow(1, "Folder", row)
        ff.insertRow(2, "Trigger command", self.trigger_edit)

        self.pages = PageStack()          # the room of the shown page only (QStackedWidget: the tallest's)
        for page in (sim_page, gp_page, folder_page, *self.forms.values()):
            self.pages.addWidget(page)
        self.kind.currentIndexChanged.connect(self._kind_changed)
        before: QWidget = self.trigger_edit           # added after the option rows: Tab from it on to them
        for field in self.folder_options.fields.values():
            QWidget.setTabOrder(before, field)
            before = field

        self.connect_button = QPushButton("Connect")
        self.connect_button.setToolTip("Connect or disconnect the camera (Ctrl+Shift+K)")
        self.connect_button.clicked.connect(self.toggle_connection)
        self.status_label = QLabel("Not connected")
        self.status_label.setWordWrap(True)
        self.lock_label = QLabel("")
        self.lock_label.setObjectName("cameraLockLabel")
        self.lock_label.setWordWrap(True)
        self.lock_label.setProperty("role", "warning")
        self.lock_label.setVisible(False)

        # exposure
        self.iso = QComboBox()
        self.iso.addItems(ISO_CHOICES)
        self.iso.setCurrentText(read_text("camera/iso", "100", s))
        self.iso.setToolTip("Sensor sensitivity")
        self.shutter = QDoubleSpinBox()
        self.shutter.setRange(0.0001, 60)
        self.shutter.setDecimals(4)
        self.shutter.setValue(read_float("camera/shutter_s", 0.5, s))
        self.shutter.setSuffix(" s")
        self.shutter.setToolTip("Exposure time")
        self.aperture = QDoubleSpinBox()
        self.aperture.setRange(1.0, 32.0)
        self.aperture.setDecimals(1)
        self.aperture.setValue(read_float("camera/aperture", 16.0, s))
        self.aperture.setPrefix("f/")
        self.aperture.setToolTip("f-number (the Planner proposes the one that keeps the scene sharp)")
        self.apply_button = QPushButton("Apply to camera")
        self.apply_button.setToolTip("Send ISO, shutter and aperture to the connected camera")
        self.apply_button.clicked.connect(self.apply_settings)
        exposure = self.exposure_group = QGroupBox("Exposure")
        ef = QFormLayout(exposure)
        ef.addRow("ISO", self.iso)
        ef.addRow("Shutter", self.shutter)
        ef.addRow("Aperture", self.aperture)
        ef.addRow(self.apply_button)

        self.shot_button = QPushButton("Test shot")
        self.shot_button.setToolTip("Take one picture, show it in the Live view (Ctrl+T)")
        self.shot_button.clicked.connect(self.take_test_shot)
        self.shot_label = QLabel("")
        self.shot_label.setWordWrap(True)
        self.shot_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)

        layout = QVBoxLayout(self)
        top = QFormLayout()
        top.addRow("Camera", self.kind)
        layout.addLayout(top)
        layout.addWidget(self.pages)
        buttons = QHBoxLayout()
        buttons.addWidget(self.connect_button)
        buttons.addWidget(self.shot_button)
        layout.addLayout(buttons)
        layout.addWidget(self.lock_label)
        layout.addWidget(self.status_label)
        layout.addWidget(exposure)
        layout.addWidget(self.shot_label)
        layout.addStretch(1)

        self.connect_action = QAction("Connect &camera", self)
        self.connect_action.setShortcut(QKeySequence("Ctrl+Shift+K"))
        self.connect_action.setToolTip("Connect or disconnect the camera chosen in the Camera panel")
        self.connect_action.triggered.connect(self.toggle_connection)
        self.shot_action = QAction("&Test shot", self)
        self.shot_action.setShortcut(QKeySequence("Ctrl+T"))
        self.shot_action.setToolTip("Take one picture with the connected camera and show it in the Live view")
        self.shot_action.triggered.connect(self.take_test_shot)

        self._lock_shown = ""
        self._base_tips = [(w, w.toolTip()) for w in self._camera_controls()]
        state.planChanged.connect(lambda _plan: self._show_truth())
        state.scanStateChanged.connect(lambda _state: self._update_enabled())
        self._kind_changed()

    def _camera_controls(self) -> list[QWidget | QAction]:
        """Everything that commands the camera (disabled while a scan owns it)."""
        return [self.shot_button, self.shot_action, self.apply_button, self.connect_button, self.connect_action]

    def install_menus(self, window: Any) -> None:
        menu = window.menu("Rig")
        menu.addSeparator()
        menu.addAction(self.connect_action)
        menu.addAction(self.shot_action)

    # -- choices -------------------------------------------------------------------------------------
    @property
    def kind_key(self) -> str:
        """Where the camera choice is kept: the simulated studio (``gui --simulated``) and the
        hardware session each remember their own, so neither inherits the other's camera."""
        return "camera/kind_simulated" if self.state.simulated else "camera/kind"

    def current_kind(self) -> str:
        return str(self.kind.currentData())

    def _kind_changed(self) -> None:
        current = self.kind.currentIndex()
        self.pages.setCurrentIndex(current)
        settings().setValue(self.kind_key, self.current_kind())
        # a DSLR's exposure (the simulated camera's too); a kind with a form shows its own settings; the
        # hot folder's camera is set in its own software (Apply to camera stayed greyed out there)
        self.exposure_group.setVisible(self.current_kind() in ("sim", "gphoto2"))
        self._show_truth()
        self._update_enabled()

    def _browse(self) -> None:
        folder = QFileDialog.getExistingDirectory(self, "Hot folder", self.folder_edit.text())
        if folder:
            self.folder_edit.setText(folder)

    def _studio_kwargs(self) -> dict[str, Any]:
        """The virtual scene follows the current plan (distances, lens, sensor, grid extent)."""
        from lfstudio.studio.simulated import DEMO_PP_OFFSET_PX, DEMO_ROTATION_DEG, REFERENCE_REGION_MM

        kw: dict[str, Any] = {"width_px": self.sim_width.value() // 2 * 2, "rotation_deg": DEMO_ROTATION_DEG,
                              "pp_offset_px": DEMO_PP_OFFSET_PX, "view_region_mm": REFERENCE_REGION_MM}
        plan = self.state.plan
        if plan is not None:
            try:
                kw.update(near_m=float(plan.near_m), far_m=float(plan.far_m),
                          focal_length_mm=float(plan.focal_length_mm), sensor_width_mm=float(plan.sensor_mm[0]))
                cols, rows = int(plan.grid_columns), int(plan.grid_rows)
                sx, sy = (float(v) for v in plan.spacing_mm)
                kw["view_region_mm"] = (0.0, max(1.0, (cols - 1) * sx), 0.0, max(1.0, (rows - 1) * sy))
            except (AttributeError, TypeError, ValueError, IndexError):
                pass
        return kw

    def _show_truth(self) -> None:
        if self.current_kind() != "sim":
            return
        kw = self._studio_kwargs()
        rx, ry, rz = kw["rotation_deg"]
        px, py = kw["pp_offset_px"]
        self.sim_truth.setText(f"Ground truth: orientation error ({rx:g}°, {ry:g}°, {rz:g}°), principal point "
                               f"offset ({px:g}, {py:g}) px; scene {kw.get('near_m', 1.77):g} … "
                               f"{kw.get('far_m', 4.77):g} m. Files: .dng + .jpg + .truth.json")

    def _save_settings(self) -> None:
        for form in self.forms.values():
            form.save()
        s = settings()
        s.setValue("camera/sim_width_px", self.sim_width.value())
        s.setValue("camera/sim_noise_pct", self.sim_noise.value())
        s.setValue("camera/sim_flicker_pct", self.sim_flicker.value())
        s.setValue("camera/sim_vignetting_pct", self.sim_vignetting.value())
        s.setValue("camera/sim_time_scale", self.sim_time_scale.value())
        s.setValue("camera/hot_folder", self.folder_edit.text())
        s.setValue("camera/trigger_command", self.trigger_edit.text())
        self.folder_options.save()
        s.setValue("camera/iso", self.iso.currentText())
        s.setValue("camera/shutter_s", self.shutter.value())
        s.setValue("camera/aperture", self.aperture.value())

    def build_link(self) -> Any:
        """The chosen camera, not yet connected, as a :class:`lfstudio.studio.devices.CameraLink` (a USB
        camera or hot folder locked for this window). Raises InputError for bad fields, LockBusy when
        another lfstudio process uses the camera."""
        from lfstudio.studio.devices import CameraSpec, open_camera

        kind = self.current_kind()
        doing = "the lfstudio window"
        if kind == "sim":
            options = dict(studio_kwargs=self._studio_kwargs(), exposure_s=self.shutter.value(),
                           iso=int(self.iso.currentText()), aperture=self.aperture.value(),
                           time_scale=self.sim_time_scale.value(), noise=self.sim_noise.value() / 100,
                           flicker=self.sim_flicker.value() / 100, vignetting=self.sim_vignetting.value() / 100)
            return open_camera(CameraSpec("sim"), position_mm=simulated_position(self.state), doing=doing,
                               options=options, connect=False)
        if kind == "gphoto2":
            return open_camera(CameraSpec("gphoto2"), doing=doing, connect=False)
        if kind in self.forms:
            form = self.forms[kind]
            return open_camera(CameraSpec.parse(form.word(), form.kind.argument or "Camera"), doing=doing,
                               options=form.options(), connect=False)
        if not self.folder_edit.text().strip():
            raise InputError("Folder", "choose the folder the camera software saves into")
        folder = str(expand_path(self.folder_edit.text(), "Folder", absolute=True))
        try:
            argv = shlex.split(self.trigger_edit.text())
        except ValueError as exc:
            raise InputError("Trigger command", f"cannot be split into arguments ({exc})") from None
        return open_camera(CameraSpec("folder", folder), doing=doing, trigger_command=argv or None,
                           options=self.folder_options.options(), connect=False)

    # -- connection ----------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self.device is not None

    def toggle_connection(self) -> None:
        if self._refuse_while_scanning("Connect camera"):
            return
        if self.connected:
            self.disconnect_camera()
        else:
            self.connect_camera()

    def connect_camera(self) -> None:
        if self.connected:
            return
        self._save_settings()
        try:
            self.link = self.build_link()
        except Exception as exc:  # noqa: BLE001 - a missing library, a bad field, a busy camera: say so
            self._show(str(exc), "error")
            self.state.report_error("Camera", str(exc))
            return
        worker = DeviceWorker(self.link.camera, name="camera", status_method="status", publish_hz=4)
        self.device = QtDevice(worker, self)
        self.device.statusChanged.connect(self._on_status)
        self.device.busyChanged.connect(lambda _b: self._update_enabled())
        self._show("Connecting…" + (" (building the virtual scene)" if self.current_kind() == "sim" else ""),
                   "warning")
        self.connect_button.setText("Disconnect")
        self.connect_action.setText("Disconnect &camera")
        self.device.run("connect", timeout_s=60, on_result=lambda _r: self._connected(),
                        on_error=self._connect_failed)
        self.state.set_device("camera", self.device)
        self.state.set_device("camera_link", self.link)
        self._update_enabled()

    def _connected(self) -> None:
        if self.device is None:     # disconnected before the camera's answer arrived
            return
        name = self.kind.currentText()
        self._show(f"Connected: {name}", "ok")
        self.state.show_status(f"Camera connected ({name})")
        form = self.forms.get(self.current_kind())
        if form is not None:
            if isinstance(self.device.driver, DescribesSettings):
                self.device.run("describe_settings", on_result=form.show_settings, on_error=lambda _m: None)
        elif self.current_kind() != "folder":
            self.device.run("settings", on_result=self._show_settings, on_error=lambda _m: None)

    def _connect_failed(self, message: str) -> None:
        self.disconnect_camera()
        self._show(message, "error")
        self.state.report_error("Camera", message)

    def disconnect_camera(self) -> None:
        device, self.device = self.device, None
        link, self.link = self.link, None
        # the camera's lock, once the worker has disconnected the driver (never waited for here)
        close_link = None if link is None else (lambda: link.close(disconnect=False))
        if device is not None:
            device.stop_now()
            device.close(disconnect=True, then=close_link)
            device.deleteLater()
        elif close_link is not None:
            close_link()
        self.state.set_device("camera", None)
        self.state.set_device("camera_link", None)
        for form in self.forms.values():
            form.clear_settings()
        self.connect_button.setText("Connect")
        self.connect_action.setText("Connect &camera")
        self._show("Not connected", "")
        self._update_enabled()

    def shutdown(self) -> None:
        if self.device is not None:
            self.disconnect_camera()

    def _on_status(self, snapshot: Any) -> None:
        message = getattr(snapshot, "message", "")
        if message:
            self._show(message, "error")

    def _show_settings(self, values: Any) -> None:
        if not isinstance(values, dict):
            return
        if "iso" in values and str(values["iso"]) in ISO_CHOICES:
            self.iso.setCurrentText(str(values["iso"]))
        if isinstance(values.get("shutter_s"), (int, float)):
            self.shutter.setValue(float(values["shutter_s"]))
        if isinstance(values.get("aperture"), (int, float)):
            self.aperture.setValue(float(values["aperture"]))

    def _show(self, text: str, kind: str) -> None:
        colours = {"ok": "#2a7a2a", "warning": "#a06000", "error": "#c02020", "": "#555555"}
        self.status_label.setText(text)
        self.status_label.setStyleSheet(f"color: {colours.get(kind, '#555555')};")

    def _update_enabled(self) -> None:
        connected = self.device is not None
        busy = self.device is not None and self.device.busy
        free = not self.state.scan_owns_camera
        self.kind.setEnabled(not connected)
        form = self.forms.get(self.current_kind())
        self.pages.setEnabled(not connected or form is not None)   # a form keeps its settings row usable
        for each in self.forms.values():
            each.set_editable(not connected, free and connected and not busy)
        self.shot_button.setEnabled(free and connected and not busy)
        self.shot_action.setEnabled(free and connected and not busy)
        self.apply_button.setEnabled(free and connected and not busy and self.current_kind() in ("sim", "gphoto2"))
        self.connect_button.setEnabled(free)
        self.connect_action.setEnabled(free)
        self._show_lock(self.state.camera_lock_reason())

    def _show_lock(self, reason: str) -> None:
        """The lock note and the "why disabled" tooltips, when the scan takes or gives back the camera."""
        if reason == self._lock_shown:
            return
        self._lock_shown = reason
        show_lock_note(self.lock_label, self._base_tips, reason,
                       f"<b>Camera in use by {self.state.scan_label or 'the scan'}</b>: test shots and settings "
                       "return when it ends or is paused.")

    def _refuse_while_scanning(self, what: str) -> bool:
        """True (and the reason said) when a scan owns the camera: nothing is sent."""
        reason = self.state.camera_lock_reason()
        if reason:
            self.state.show_status(f"{what}: {reason}", 8000)
        return bool(reason)

    # -- actions -------------------------------------------------------------------------------------
    def apply_settings(self) -> None:
        if self.device is None or self._refuse_while_scanning("Apply to camera"):
            return
        self._save_settings()
        refused: list[str] = []        # one line per setting the camera refused (kept, not covered by "applied")
        for name, value in (("iso", int(self.iso.currentText())), ("shutter_s", self.shutter.value()),
                            ("aperture", self.aperture.value())):
            self.device.run("set_setting", name, value, timeout_s=20,
                            on_error=lambda m, n=name: (refused.append(m if m.startswith(n) else f"{n}: {m}"),
                                                        self._show("\n".join(refused), "error")))
        self.device.run("settings", on_result=lambda v: (self._show_settings(v), None if refused else
                                                         self._show("Settings applied", "ok")),
                        on_error=lambda m: None)

    def set_on_camera(self, name: str, value: Any) -> None:
        """One setting of a camera with a form (GenICam, plugins) sent to it; its settings shown again."""
        form = self.forms.get(self.current_kind())
        if self.device is None or form is None or self._refuse_while_scanning("Set"):
            return
        self.device.run("set_setting", name, value, timeout_s=20,
                        on_result=lambda _r: (self._show(f"{name} set", "ok"),
                                              self.device.run("describe_settings", on_result=form.show_settings,
                                                              on_error=lambda _m: None) if self.device else None),
                        on_error=lambda m: self._show(m, "error"))

    def take_test_shot(self) -> None:
        if self.device is None:
            self.state.show_status("Test shot: connect a camera first")
            return
        if self._refuse_while_scanning("Test shot"):
            return
        folder = user_config_dir() / "test_shots"
        folder.mkdir(parents=True, exist_ok=True)
        self._show("Taking a test shot…", "warning")
        self.device.run(test_shot, self.device.driver, folder, timeout_s=120,
                        on_result=self._shot_done, on_error=lambda m: (self._show(m, "error"),
                                                                       self.state.report_error("Test shot", m)))

    def _shot_done(self, outcome: Any) -> None:
        result, image = outcome
        size_mb = result.path.stat().st_size / 1e6 if result.path.exists() else 0
        text = (f"{result.path.name}: {size_mb:.1f} MB; exposure {result.exposure_s:.2f} s, transfer "
                f"{result.transfer_s:.2f} s")
        truth = result.metadata.get("ground_truth") if isinstance(result.metadata, dict) else None
        if truth:
            x, y = truth["true_position_mm"]
            text += f"; camera at ({x:.3f}, {y:.3f}) mm"
        self.shot_label.setText(f"Last test shot: {text}\n{result.path}")
        self._show("Connected", "ok")
        self.state.cameraFrame.emit(image, f"test shot {result.path.name}")
        self.state.show_status(f"Test shot saved: {result.path}")
