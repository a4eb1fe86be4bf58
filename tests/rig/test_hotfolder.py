"""The hot-folder camera: new complete files only, partial/temporary names ignored, trigger as argv."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from lfstudio.errors import DeviceError, InputError
from lfstudio.rig.camera import Camera
from lfstudio.rig.hotfolder import HotFolderCamera, is_partial_name
from lfstudio.sim.dng import write_dng


def _dng_bytes(tmp_path, size: int | None = None) -> bytes:
    """A real (small) DNG as a camera would leave it; ``size``: padded with zeros to that many bytes
    (LibRaw reads it all the same)."""
    path = tmp_path / "_src.dng"
    write_dng(path, np.random.default_rng(3).integers(512, 16383, (24, 40), dtype=np.uint16))
    data = path.read_bytes()
    path.unlink()
    assert size is None or len(data) <= size
    return data if size is None else data + bytes(size - len(data))


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
    dng = _dng_bytes(tmp_path, 12000)
    chunks = [dng[i * 1000:(i + 1) * 1000] for i in range(12)]

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
    dng = _dng_bytes(tmp_path)
    sim = SimTime([
        lambda: (hot / ".DSC0002.dng.tmp").write_bytes(dng),          # being written under a temp name
        lambda: (hot / "notes.txt").write_bytes(b"hello"),
        lambda: (hot / "DSC0002.dng.part").write_bytes(b"y" * 10),
        lambda: (hot / ".DSC0002.dng.tmp").rename(hot / "DSC0002.dng"),
    ])
    cam = _camera(hot, sim)
    result = cam.capture(tmp_path / "out" / "v")
    assert result.path.name == "v.dng"
    assert result.path.read_bytes() == dng
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
    (tmp_path / "shot.dng").write_bytes(_dng_bytes(tmp_path))
    script = ("import sys, pathlib; p = pathlib.Path(sys.argv[1]); "
              "t = p / '.IMG_1.CR2.tmp'; t.write_bytes(pathlib.Path(sys.argv[2]).read_bytes()); t.rename(p / 'IMG_1.CR2')")
    cam = HotFolderCamera(hot, [sys.executable, "-c", script, str(hot), str(tmp_path / "shot.dng")], stable_s=0.05,
                          poll_s=0.02, timeout_s=30)
    cam.connect()
    result = cam.capture(tmp_path / "out" / "r01_c002")
    assert result.path.name == "r01_c002.cr2" and result.path.stat().st_size == (tmp_path / "shot.dng").stat().st_size
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


def test_the_picture_is_what_libraw_or_opencv_reads_not_a_suffix(tmp_path):
    """A RAW under a suffix no list names (a Canon .CRW here) is the picture; an XMP sidecar beside it
    is not; a new binary file that nothing reads stops the capture with its name."""
    hot = tmp_path / "hot"
    hot.mkdir()
    dng = _dng_bytes(tmp_path)
    sim = SimTime([lambda: (hot / "IMG_0001.xmp").write_text("<x:xmpmeta/>"),
                   lambda: (hot / "IMG_0001.CRW").write_bytes(dng)])
    cam = _camera(hot, sim)
    result = cam.capture(tmp_path / "out" / "v")
    assert result.path.name == "v.crw" and result.path.read_bytes() == dng
    assert (hot / "IMG_0001.xmp").exists()                     # the sidecar stays where it was
    sim.steps = [lambda: (hot / "IMG_0002.CRW").write_bytes(np.random.default_rng(5).bytes(5000))]
    with pytest.raises(DeviceError, match=r"IMG_0002\.CRW arrived but is not a picture"):
        cam.capture(tmp_path / "out" / "w")
    assert (hot / "IMG_0002.CRW").exists() and not list((tmp_path / "out").glob("w*"))
