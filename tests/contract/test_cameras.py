"""One contract every registered camera kind keeps (cf. python-microscope's CameraTests): connect, its
record, a settings round trip, a capture whose file lfstudio reads, errors as one operator line, disconnect,
and a second lfstudio process refused while one holds the camera.

Installed plugins' kinds run it too when named in ``LFSTUDIO_CONTRACT_CAMERAS`` (tests/studio/test_plugins.py
does so for the documented example plugin). Each built-in kind runs on its real stack: the virtual studio (sim), the instant camera, libgphoto2's own virtual
PTP camera (gphoto2, tests/vcamera.py), a hot folder fed by a trigger command, aravis's fake GigE Vision
camera over the real protocol (genicam, tests/fakegv.py). A kind registered without a case here fails
:func:`test_every_registered_camera_kind_has_a_contract_case`, so a new built-in kind must join."""

from __future__ import annotations

import os
import sys
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import cv2
import numpy as np
import pytest

from lfstudio.dataset import images
from lfstudio.errors import InputError, LfError
from lfstudio.rig.camera import Camera, stored
from lfstudio.studio.devices import CameraLink, open_camera
from lfstudio.studio.kinds import camera_kind, camera_kinds


@dataclass
class Case:
    """How one kind is opened for the contract, and one setting it round-trips."""

    word: str
    setting: tuple[str, Any, Any]                   # (name, value set, value read back)
    options: dict[str, Any] = field(default_factory=dict)
    position: bool = False
    trigger: list[str] | None = None


def _sim(tmp: Path, stack: ExitStack, monkeypatch: pytest.MonkeyPatch) -> Case:
    from lfstudio.studio.simulated import studio_kwargs_for

    return Case("sim", ("iso", 200, 200), {"studio_kwargs": studio_kwargs_for(width_px=320), "time_scale": 0.0},
                position=True)


def _instant(tmp: Path, stack: ExitStack, monkeypatch: pytest.MonkeyPatch) -> Case:
    return Case("instant", ("shutter_s", 0.25, 0.25), position=True)


def _gphoto2(tmp: Path, stack: ExitStack, monkeypatch: pytest.MonkeyPatch) -> Case:
    from tests.vcamera import use_vcamera

    use_vcamera(tmp / "vcamera", monkeypatch)
    return Case("gphoto2", ("aperture", 8, 8.0))


def _folder(tmp: Path, stack: ExitStack, monkeypatch: pytest.MonkeyPatch) -> Case:
    folder = tmp / "incoming"
    folder.mkdir()
    source = tmp / "picture.png"
    cv2.imwrite(str(source), np.random.default_rng(1).integers(0, 65535, (48, 64, 3), dtype=np.uint16))
    counter = tmp / "n"
    script = (f"import shutil, pathlib; c = pathlib.Path({str(counter)!r}); n = int(c.read_text()) + 1 "
              f"if c.exists() else 1; c.write_text(str(n)); "
              f"shutil.copy({str(source)!r}, pathlib.Path({str(folder)!r}) / f'shot{{n}}.png')")
    return Case(f"folder:{folder}", ("timeout_s", 12.0, 12.0), {"stable_s": 0.05, "poll_s": 0.02},
                trigger=[sys.executable, "-c", script])


def _genicam(tmp: Path, stack: ExitStack, monkeypatch: pytest.MonkeyPatch) -> Case:
    from tests.fakegv import fake_gv_camera

    fake = stack.enter_context(fake_gv_camera())
    return Case(f"genicam:{fake.device_id}", ("exposure_s", 0.02, 0.02), {"timeout_s": 3.0})


CASES: dict[str, Callable[[Path, ExitStack, pytest.MonkeyPatch], Case]] = {
    "sim": _sim, "instant": _instant, "gphoto2": _gphoto2, "folder": _folder, "genicam": _genicam}


def _installed(spec: str) -> Callable[[Path, ExitStack, pytest.MonkeyPatch], Case]:
    """A plugin's kind from ``LFSTUDIO_CONTRACT_CAMERAS``: ``WORD|NAME=VALUE`` (its word, one setting)."""
    word, _, setting = spec.partition("|")
    name, _, text = setting.partition("=")
    value: Any = float(text) if text.replace(".", "", 1).isdigit() else text
    return lambda tmp, stack, monkeypatch: Case(word.strip(), (name.strip(), value, value))


#: installed plugins' kinds run the same contract: LFSTUDIO_CONTRACT_CAMERAS="ramp:64x48|gain=2;OTHER|..."
for _spec in filter(None, os.environ.get("LFSTUDIO_CONTRACT_CAMERAS", "").split(";")):
    CASES[f"plugin:{_spec.partition('|')[0]}"] = _installed(_spec)


@contextmanager
def opened(case: Case, connect: bool = True) -> Iterator[CameraLink]:
    link = open_camera(case.word, position_mm=(lambda: (0.0, 0.0)) if case.position else None,
                       doing="the camera contract", trigger_command=case.trigger, options=dict(case.options),
                       connect=connect)
    try:
        yield link
    finally:
        link.close()


@pytest.fixture(params=sorted(CASES))
def case(request, tmp_path, monkeypatch):
    with ExitStack() as stack:
        yield CASES[request.param](tmp_path, stack, monkeypatch)


def test_every_registered_camera_kind_has_a_contract_case():
    built_in = [name for name, kind in camera_kinds().items() if kind.origin == "built-in"]
    assert sorted(built_in) == sorted(c for c in CASES if not c.startswith("plugin:"))


def test_connect_record_settings_capture_disconnect(case, tmp_path):
    with opened(case) as link:
        camera = link.camera
        assert isinstance(camera, Camera)
        record = link.record()
        assert record["kind"] == camera_kind(case.word.split(":")[0]).name and record["spec"] == case.word
        assert record["model"]
        settings = camera.settings()
        assert isinstance(settings, dict) and settings
        name, value, back = case.setting
        camera.set_setting(name, value)
        assert camera.settings()[name] == pytest.approx(back)
        result = stored(camera.capture(tmp_path / "shot"))
        assert result.files and all(Path(f).is_file() and Path(f).stat().st_size > 0 for f in result.files)
        assert Path(result.path).name.startswith("shot.")
        assert images.kind(result.path) in ("raw", "image")          # lfstudio reads what it stored
        assert images.full_size_px(result.path)[0] > 0
        camera.disconnect()


def test_errors_are_one_operator_line(case, tmp_path):
    with opened(case) as link:
        camera = link.camera
        with pytest.raises(InputError) as err:
            camera.set_setting("no_such_setting", 1)
        assert "\n" not in str(err.value) and "no_such_setting" in str(err.value)
        camera.disconnect()
        if case.word in ("sim", "instant"):
            return                     # the simulated cameras render whether connected or not
        with pytest.raises(LfError) as err:
            stored(camera.capture(tmp_path / "after"))
        assert "\n" not in str(err.value)
        assert not list(tmp_path.glob("after*"))


def test_a_second_process_is_refused_while_one_holds_the_camera(case, tmp_path, run_cli):
    kind = camera_kind(case.word.split(":")[0])
    if kind.lock_key is None:
        pytest.skip(f"{kind.name}: a simulated camera in each process, nothing to share")
    with opened(case, connect=False):
        r = run_cli("camera", tmp_path / "other", "--camera", case.word, timeout=60)
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert "is in use by" in r.stderr and "the camera contract" in r.stderr, r.stderr
    assert not list(tmp_path.glob("other*"))
