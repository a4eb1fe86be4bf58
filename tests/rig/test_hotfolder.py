"""The hot-folder camera: new complete files only, partial/temporary names ignored, trigger as argv."""

from __future__ import annotations

import sys

import pytest

from lfstudio.errors import DeviceError, InputError
from lfstudio.rig.camera import Camera
from lfstudio.rig.hotfolder import HotFolderCamera, is_partial_name


class SimTime:
    """Simulated time for the driver: each poll advances the clock and runs the next scripted step
    (a camera writing its file), so the test is deterministic and never sleeps."""

    def __init__(self, steps=()):
        self.now = 0.0
        self.steps = list(steps)
        self.polls = 0

    def clock(self) -> float:
        return self.now

    def wait(self, seconds: float) -> bool:
        self.now += seconds
        self.polls += 1
        if self.steps:
            self.steps.pop(0)()
        return False


def _camera(folder, sim, **kw):
    cam = HotFolderCamera(folder, clock=sim.clock, wait=sim.wait, stable_s=0.5, poll_s=0.1, timeout_s=10, **kw)
    cam.connect()
    return cam


def test_waits_until_a_growing_file_stops_growing(tmp_path):
    hot, out = tmp_path / "hot", tmp_path / "out"
    hot.mkdir()
    target = hot / "DSC0001.ARW"
    chunks = [bytes([i]) * 1000 for i in range(12)]

    def write(i):
        def step():
            with open(target, "ab") as fh:
                fh.write(chunks[i])
        return step

    # the camera writes one chunk per poll (0.1 s): the file keeps growing for 1.2 s > stable_s
    sim = SimTime([write(i) for i in range(12)])
    cam = _camera(hot, sim)
    assert isinstance(cam, Camera)
    exposed = []
    result = cam.capture(out / "r00_c000", on_exposed=lambda: exposed.append(sim.now))
    assert result.path == out / "r00_c000.arw"
    assert result.path.read_bytes() == b"".join(chunks)        # complete, not a partial copy
    assert not target.exists()                                  # moved out of the hot folder
    assert sim.now >= 1.2 + 0.5 and exposed
    assert result.metadata["bytes"] == 12000


def test_ignores_temporary_names_old_files_and_other_extensions(tmp_path):
    hot = tmp_path / "hot"
    hot.mkdir()
    (hot / "old.dng").write_bytes(b"old")                       # there before connect: not ours
    sim = SimTime([
        lambda: (hot / ".DSC0002.dng.tmp").write_bytes(b"x" * 10),   # being written under a temp name
        lambda: (hot / "notes.txt").write_bytes(b"hello"),
        lambda: (hot / "DSC0002.dng.part").write_bytes(b"y" * 10),
        lambda: (hot / ".DSC0002.dng.tmp").rename(hot / "DSC0002.dng"),
    ])
    cam = _camera(hot, sim)
    result = cam.capture(tmp_path / "out" / "v")
    assert result.path.name == "v.dng"
    assert result.path.read_bytes() == b"x" * 10
    assert (hot / "old.dng").exists() and (hot / "notes.txt").exists()


def test_timeout_names_the_folder(tmp_path):
    sim = SimTime()
    cam = _camera(tmp_path, sim)
    with pytest.raises(DeviceError, match=r"no new complete file within 10 s"):
        cam.capture(tmp_path / "x")
    assert "no new complete file" in cam.status().message


def test_trigger_command_runs_as_argument_list_and_creates_the_file(tmp_path):
    hot = tmp_path / "hot with space"
    hot.mkdir()
    script = ("import sys, pathlib; p = pathlib.Path(sys.argv[1]); "
              "t = p / '.IMG_1.CR2.tmp'; t.write_bytes(b'raw' * 100); t.rename(p / 'IMG_1.CR2')")
    cam = HotFolderCamera(hot, [sys.executable, "-c", script, str(hot)], stable_s=0.05, poll_s=0.02, timeout_s=30)
    cam.connect()
    result = cam.capture(tmp_path / "out" / "r01_c002")
    assert result.path.name == "r01_c002.cr2" and result.path.stat().st_size == 300
    # the next trigger does not pick up anything old
    (hot / "stale.cr2").write_bytes(b"s")
    cam.trigger_command = [sys.executable, "-c", "import sys; sys.exit(0)"]
    cam.timeout_s = 0.3
    with pytest.raises(DeviceError):
        cam.capture(tmp_path / "out" / "r01_c003")


def test_failing_trigger_and_shell_strings_are_refused(tmp_path):
    with pytest.raises(InputError, match="shell string"):
        HotFolderCamera(tmp_path, "shoot --now")
    cam = HotFolderCamera(tmp_path, [sys.executable, "-c", "import sys; print('no camera', file=sys.stderr); "
                                     "sys.exit(3)"])
    cam.connect()
    with pytest.raises(DeviceError, match="exit code 3: no camera"):
        cam.capture(tmp_path / "x")
    cam.trigger_command = ["/nonexistent/vendor-cli"]
    with pytest.raises(DeviceError, match="not found"):
        cam.capture(tmp_path / "x")


def test_missing_folder_is_a_clear_error(tmp_path):
    with pytest.raises(DeviceError, match="not found or not a folder"):
        HotFolderCamera(tmp_path / "nope").connect()


@pytest.mark.parametrize("name,partial", [("IMG_1.CR2", False), (".IMG_1.CR2", True), ("IMG_1.CR2.tmp", True),
                                          ("~IMG.dng", True), ("a.dng.crdownload", True), ("a.part.dng", True),
                                          ("DSC0001.ARW", False)])
def test_partial_names(name, partial):
    assert is_partial_name(name) is partial
