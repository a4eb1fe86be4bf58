"""Device kinds from plugins (entry points ``lfstudio.cameras``, ``lfstudio.rigs``): the documented example
plugins (a camera, a rig) pip-installed from a temporary folder and scanned with; broken and clashing plugins
named while the rest load."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from lfstudio.errors import InputError
from tests.conftest import REPO_ROOT

EXAMPLE = REPO_ROOT / "docs" / "plugins" / "example-camera"
EXAMPLE_RIG = REPO_ROOT / "docs" / "plugins" / "example-rig"


def write_dist(site: Path, name: str, entry_points: str) -> None:
    """An installed distribution with only metadata and entry points (what pip leaves in site-packages)."""
    info = site / f"{name.replace('-', '_')}-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(entry_points)


def pip_install(example: Path, root: Path) -> Path:
    """An example plugin pip-installed (no dependencies, no index) into a folder of its own, copied from
    docs/ to a temporary folder first (a build writes beside its sources)."""
    source = root / example.name
    shutil.copytree(example, source)
    site = root / "site"
    r = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                        "--no-index", "--disable-pip-version-check", "--target", str(site), str(source)],
                       capture_output=True, text=True, timeout=300)
    if r.returncode != 0:
        pytest.fail(f"pip install of {example.name} failed:\n{r.stderr[-2000:]}")
    return site


@pytest.fixture(scope="module")
def example_site(tmp_path_factory):
    return pip_install(EXAMPLE, tmp_path_factory.mktemp("plugin"))


@pytest.fixture(scope="module")
def example_rig_site(tmp_path_factory):
    return pip_install(EXAMPLE_RIG, tmp_path_factory.mktemp("rig-plugin"))


def test_the_example_plugin_installs_is_listed_and_scans(example_site, tmp_path, run_cli):
    env = {"PYTHONPATH": str(example_site)}
    r = run_cli("doctor", "--quick", env=env)
    line = next((ln for ln in r.stdout.splitlines() if "camera ramp:ARGUMENTS" in ln), "")
    assert "[plugin lfstudio-example-camera 0.1.0 (lfstudio_example_camera:open_camera)]" in line, r.stdout
    assert "camera genicam:ID" in r.stdout                     # the built-ins are there beside it
    out = tmp_path / "ds"
    r = run_cli("scan", "--port", "instant", "--camera", "ramp:64x48", "--grid", "3x2", "--out", out, env=env)
    assert r.returncode == 0, r.stderr
    manifest = json.loads((out / "dataset.json").read_text())
    assert [v["status"] for v in manifest["views"]] == ["done"] * 6
    for v in manifest["views"]:
        assert v["file"].endswith(".png") and (out / v["file"]).is_file()
        assert v["camera_frame"]["pixel_format"] == "Mono12" and v["camera_frame"]["size_px"] == [64, 48]
    camera = manifest["devices"]["camera"]
    assert camera["kind"] == "ramp" and camera["spec"] == "ramp:64x48" and camera["model"] == "Ramp"
    assert camera["origin"].startswith("plugin lfstudio-example-camera 0.1.0")
    r = run_cli("scan", "--port", "instant", "--camera", "ramp:huge", "--grid", "3x2", "--out", tmp_path / "b",
                env=env)
    assert r.returncode != 0 and "ramp:huge: cannot read the size" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "b").exists()


def test_broken_and_clashing_plugins_are_named_and_the_rest_load(tmp_path, run_cli):
    site = tmp_path / "site"
    write_dist(site, "broken-plugin", "[lfstudio.cameras]\nbroken = no_such_module_here:open_camera\n")
    write_dist(site, "twin-a", "[lfstudio.cameras]\ntwin = twin_a:open_camera\n")
    write_dist(site, "twin-b", "[lfstudio.cameras]\ntwin = twin_b:open_camera\n")
    write_dist(site, "impostor", "[lfstudio.cameras]\ngphoto2 = impostor:open_camera\n")
    env = {"PYTHONPATH": str(site)}
    r = run_cli("doctor", "--quick", env=env)
    assert r.returncode == 0, r.stdout + r.stderr
    warnings = [ln for ln in r.stdout.splitlines() if ln.startswith("warn ")]
    assert any("plugin broken-plugin 0.1 (no_such_module_here:open_camera): cannot be loaded (ModuleNotFoundError"
               in ln for ln in warnings), r.stdout
    assert any("camera kind 'twin' is claimed by plugin twin-a 0.1 (twin_a:open_camera) and plugin twin-b 0.1 "
               "(twin_b:open_camera): neither is loaded" in ln for ln in warnings), r.stdout
    assert any("camera kind 'gphoto2' of plugin impostor 0.1 (impostor:open_camera) is not loaded: 'gphoto2' is the "
               "built-in kind" in ln for ln in warnings), r.stdout
    assert "camera gphoto2" in r.stdout and "camera genicam:ID" in r.stdout
    out = tmp_path / "ds"
    r = run_cli("scan", "--port", "instant", "--camera", "twin:1", "--grid", "2x1", "--out", out, env=env)
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert "camera kind 'twin' is claimed by plugin twin-a 0.1" in r.stderr and "uninstall one of them" in r.stderr
    assert not out.exists()
    r = run_cli("scan", "--port", "instant", "--camera", "instant", "--grid", "2x1", "--out", out, env=env)
    assert r.returncode == 0, r.stderr                           # the rest still load


def test_a_kind_cannot_take_a_name_that_is_taken():
    from lfstudio.studio.kinds import CameraKind, camera_kinds, register_camera

    assert "genicam" in camera_kinds()
    with pytest.raises(InputError, match="'genicam' of plugin x is already the kind of built-in"):
        register_camera(CameraKind("genicam", lambda a, c: None, origin="plugin x"))
    with pytest.raises(InputError, match="is not a device word name"):
        register_camera(CameraKind("bad name", lambda a, c: None, origin="plugin x"))


def test_a_factory_that_returns_no_camera_is_named(tmp_path):
    from lfstudio.errors import DeviceError
    from lfstudio.studio.devices import open_camera
    from lfstudio.studio.kinds import CameraKind, register_camera, unregister

    register_camera(CameraKind("notacamera", lambda a, c: object(), argument="X", origin="plugin test 1.0 (m:f)"))
    try:
        with pytest.raises(DeviceError, match=r"camera kind 'notacamera' \(plugin test 1.0 \(m:f\)\) gave a object, "
                                              r"which is not a camera \(it lacks connect, disconnect"):
            open_camera("notacamera:1")
    finally:
        unregister("notacamera")


def test_a_rig_plugin_is_reached_by_port_and_recorded(tmp_path, run_cli):
    site = tmp_path / "site"
    write_dist(site, "toy-rig", "[lfstudio.rigs]\ntoyrig = toy_rig_plugin:open_rig\n")
    (site / "toy_rig_plugin.py").write_text(
        "from lfstudio.rig.profile import load_rig\n"
        "from lfstudio.studio.simulated import InstantRig\n\n\n"
        "def open_rig(arguments):\n"
        "    \"\"\"A rig that takes no time (the example of a rig plugin).\"\"\"\n"
        "    return InstantRig(load_rig())\n")
    env = {"PYTHONPATH": str(site)}
    r = run_cli("doctor", "--quick", env=env)
    assert "rig toyrig:ARGUMENTS" in r.stdout and "[plugin toy-rig 0.1 (toy_rig_plugin:open_rig)]" in r.stdout
    out = tmp_path / "ds"
    r = run_cli("scan", "--port", "toyrig:bench-1", "--camera", "instant", "--grid", "3x2", "--out", out, env=env)
    assert r.returncode == 0, r.stderr
    manifest = json.loads((out / "dataset.json").read_text())
    assert [v["status"] for v in manifest["views"]] == ["done"] * 6
    rig = manifest["devices"]["rig"]
    assert rig["kind"] == "toyrig" and rig["port"] == "toyrig:bench-1" and rig["origin"].startswith("plugin toy-rig")
    manifest["views"][-1]["status"] = "failed"                      # one view to take again: the resume connects
    (out / "dataset.json").write_text(json.dumps(manifest))
    r = run_cli("scan", "--resume", "--out", out, env=env)          # the record opens the same rig again
    assert "resuming with the dataset's own devices: the rig on toyrig:bench-1" in r.stderr, r.stderr
    assert "lfstudio rig --port toyrig:bench-1 home" in r.stderr    # a new instant rig stands at 0, 0: said
    r = run_cli("scan", "--port", "toyrig:", "--camera", "instant", "--grid", "2x1", "--out", tmp_path / "c",
                env={"PYTHONPATH": str(tmp_path / "nothing-installed")})
    assert r.returncode != 0 and "Traceback" not in r.stderr     # no such plugin: a serial port that is not there


def test_doctor_says_when_genicam_cameras_cannot_work(tmp_path, run_cli):
    shadow = tmp_path / "site" / "gi"
    shadow.mkdir(parents=True)
    (shadow / "__init__.py").write_text("raise ImportError('No module named gi (hidden by the test)')\n")
    r = run_cli("doctor", "--quick", env={"PYTHONPATH": str(tmp_path / "site")})
    line = next((ln for ln in r.stdout.splitlines() if "camera genicam:ID" in ln), "")
    assert line.startswith("warn") and "aravis is not available" in line and "apt-get install" in line, r.stdout
    r = run_cli("camera", tmp_path / "shot", "--camera", "genicam:X", env={"PYTHONPATH": str(tmp_path / "site")})
    assert r.returncode != 0 and "Traceback" not in r.stderr and "aravis is not available" in r.stderr
    assert not list(tmp_path.glob("shot*"))


def test_the_example_plugin_keeps_the_camera_contract(example_site):
    """The same suite as every built-in camera (tests/contract/test_cameras.py), on the installed plugin."""
    import os

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO_ROOT), str(example_site)]),
               LFSTUDIO_CONTRACT_CAMERAS="ramp:64x48|gain=2")
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "0",
                        "tests/contract/test_cameras.py", "-k", "plugin"], capture_output=True, text=True,
                       env=env, cwd=REPO_ROOT, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "3 passed" in r.stdout, r.stdout[-2000:]                 # connect…disconnect, errors, second process


def test_the_example_rig_plugin_installs_moves_and_scans(example_rig_site, tmp_path, run_cli):
    env = {"PYTHONPATH": str(example_rig_site)}
    r = run_cli("doctor", "--quick", env=env)
    line = next((ln for ln in r.stdout.splitlines() if "rig sled:BENCH" in ln), "")
    assert "[plugin lfstudio-example-rig 0.1.0 (lfstudio_example_rig:KIND)]" in line, r.stdout
    assert "option speed_mm_s (Speed): 1 … 10000 mm/s, default 500" in r.stdout
    assert "rig dryve:HOST[:PORT],HOST[:PORT]" in r.stdout             # the built-in rigs are kinds beside it
    r = run_cli("rig", "--port", "sled:bench-1", "--rig-option", "speed_mm_s=4000", "home", "move", "100", "50",
                "status", env=env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1].split()[:3] == ["status", "idle", "x=100.000"], r.stdout
    r = run_cli("rig", "--port", "sled:bench-1", "--rig-option", "speed_mm_s=0", "status", env=env)
    assert r.returncode != 0 and "--rig-option speed_mm_s: 0 mm/s is out of range" in r.stderr, r.stderr
    out = tmp_path / "ds"
    r = run_cli("scan", "--port", "sled:bench-1", "--rig-option", "speed_mm_s=5000", "--camera", "instant",
                "--grid", "3x2", "--home", "--out", out, env=env)
    assert r.returncode == 0, r.stderr
    manifest = json.loads((out / "dataset.json").read_text())
    assert [v["status"] for v in manifest["views"]] == ["done"] * 6
    assert manifest["views"][-1]["reported_mm"] == pytest.approx(manifest["views"][-1]["commanded_mm"], abs=0.01)
    rig = manifest["devices"]["rig"]
    assert rig["kind"] == "sled" and rig["port"] == "sled:bench-1"
    assert rig["origin"].startswith("plugin lfstudio-example-rig 0.1.0")


def test_the_example_rig_plugin_keeps_the_rig_contract(example_rig_site):
    """The same suite as every built-in rig (tests/contract/test_rigs.py), on the installed plugin."""
    import os

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO_ROOT), str(example_rig_site)]),
               LFSTUDIO_CONTRACT_RIGS="sled:contract|speed_mm_s=1000")
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "0",
                        "tests/contract/test_rigs.py", "-k", "plugin"], capture_output=True, text=True,
                       env=env, cwd=REPO_ROOT, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "5 passed" in r.stdout, r.stdout[-2000:]        # move, STOP, soft limits, disconnect, second process


def test_a_rig_plugin_whose_connect_fails_is_disconnected_and_its_lock_released(tmp_path, monkeypatch):
    """A plugin rig whose connect opened its serial port and then failed (no answer to its handshake):
    open_rig must disconnect it (close the port), not only release the lock, else the port stays open
    in this process (the window's, for good) while another process may take the lock."""
    import os
    import tty
    from typing import Any

    import serial

    from lfstudio.errors import DeviceError
    from lfstudio.rig.profile import load_rig
    from lfstudio.studio.devices import open_rig
    from lfstudio.studio.kinds import RigKind, register_rig, unregister
    from lfstudio.support.locks import port_lock

    monkeypatch.setenv("LFSTUDIO_RUNTIME_DIR", str(tmp_path))
    master, slave = os.openpty()
    tty.setraw(slave)
    port = os.ttyname(slave)
    opened: list[serial.Serial] = []

    class SilentRig:
        port = ""

        def __init__(self, argument: str):
            self.port = argument
            self.serial: serial.Serial | None = None

        def connect(self) -> None:
            self.serial = serial.Serial(self.port, timeout=0)
            opened.append(self.serial)
            raise DeviceError(f"no answer on {self.port}")

        def disconnect(self) -> None:
            if self.serial is not None:
                self.serial.close()
                self.serial = None

        config = load_rig()

        def home(self) -> None: ...
        def set_origin(self) -> None: ...
        def move_to(self, x_mm: float, y_mm: float, timeout_s: float | None = None) -> Any: ...
        def jog(self, dx_mm: float, dy_mm: float, speed_mm_s: float | None = None) -> None: ...
        def jog_cancel(self) -> None: ...
        def feed_hold(self) -> None: ...
        def resume(self) -> None: ...
        def stop(self) -> None: ...
        def reset(self) -> None: ...
        def status(self) -> Any: ...

    register_rig(RigKind("silentrig", lambda argument, _ctx: SilentRig(argument), argument="PORT",
                         lock_key=lambda argument: argument, origin="plugin t 1 (m:f)"))
    try:
        with pytest.raises(DeviceError, match="no answer"):
            open_rig(f"silentrig:{port}", load_rig())
        assert len(opened) == 1 and not opened[0].is_open       # the port it opened is closed again
        with port_lock(port, "next"):                             # and the lock is free
            pass
    finally:
        unregister("silentrig")
        for s in opened:
            s.close()
        os.close(master)
        os.close(slave)


def test_a_rig_plugin_lacking_part_of_the_controller_is_told_what(tmp_path):
    """A plugin rig with connect, home, move_to, stop and status but not the rest of MotionController: the
    line names what it lacks (it said 'it lacks part of lfstudio/rig/motion.py')."""
    from lfstudio.errors import DeviceError
    from lfstudio.rig.profile import load_rig
    from lfstudio.studio.devices import open_rig
    from lfstudio.studio.kinds import RigKind, register_rig, unregister

    class HalfRig:
        def connect(self) -> None: ...
        def home(self) -> None: ...
        def move_to(self, x_mm: float, y_mm: float) -> None: ...
        def stop(self) -> None: ...
        def status(self) -> None: ...

    register_rig(RigKind("halfrig", lambda argument, _ctx: HalfRig(), argument="X", origin="plugin t 1 (m:f)"))
    try:
        with pytest.raises(DeviceError) as refused:
            open_rig("halfrig:1", load_rig(), lock=False)
        text = str(refused.value)
        assert "gave a HalfRig, which is not a motion controller" in text
        assert "it lacks config, disconnect, set_origin, jog, jog_cancel, feed_hold, resume, reset;" in text, text
    finally:
        unregister("halfrig")
