"""Shared fixtures. Qt runs offscreen; settings go to a temporary folder per test."""

from __future__ import annotations

import dataclasses
import inspect
import os
import re
import sys
import tempfile
from pathlib import Path

import pytest

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
# port/camera lock files of this test run (and of the lfstudio processes it starts) in a folder of
# its own, so tests never meet the locks of an lfstudio running beside them
# (with pytest-xdist, one per worker: the workers inherit the controller's environment, and one
# worker's simulated devices must not meet another's locks)
_worker = os.environ.get("PYTEST_XDIST_WORKER")
if _worker:
    os.environ["LFSTUDIO_RUNTIME_DIR"] = tempfile.mkdtemp(prefix=f"lfstudio-test-runtime-{_worker}-")
else:
    os.environ.setdefault("LFSTUDIO_RUNTIME_DIR", tempfile.mkdtemp(prefix="lfstudio-test-runtime-"))

REPO_ROOT = Path(__file__).resolve().parent.parent
#: real files from outside the project: ``shared/data`` beside the checkout, or beside the folder of
#: a git worktree's checkout (``wt/NAME`` next to ``shared``)
SHARED_DATA = next((p / "shared" / "data" for p in (REPO_ROOT.parent, REPO_ROOT.parent.parent)
                    if (p / "shared" / "data").is_dir()), REPO_ROOT.parent / "shared" / "data")


#: whole-package tool runs (pyright, lint-imports, ruff): the longest single tests, collected first so a
#: worker starts them at once and no worker waits for one at the end of the run
_TOOL_TESTS = ("tests/test_types.py", "tests/test_import_rules.py", "tests/test_lint.py")


# -- tiers -------------------------------------------------------------------------------------------
# Every test is in one of two tiers, given here by rules (a new test gets its tier without a marker):
#   fast: unit tests and in-process CLI tests; `./test.sh -m fast` runs them (what a developer runs
#         while working).
#   full: everything else: the GUI (real Qt loop), subprocesses (the CLI run as a program, emulator and
#         firmware processes), real cameras' stacks, the fault and concurrency tests, the benchmarks'
#         smoke runs and the whole-package tool runs. `./test.sh` (and CI) run both tiers.
# A test is full when it is marked `full` or `slow`, lives in one of _FULL_FOLDERS or _FULL_FILES, skips
# without ../shared/data, uses one of _FULL_FIXTURES (directly or through another fixture), or its own code,
# that of a fixture it uses or of its module's functions these call names one of _FULL_WORDS (a process, a
# firmware, an emulator in another process, a real camera stack) or _HEAVY_WORDS (a whole stage).
_FULL_FOLDERS = ("tests/gui/", "tests/faults/", "tests/studio/", "tests/benchmarks/", "tests/docs/",
                 "tests/contract/")       # every camera and rig kind on its real stack (fake GigE camera, PTP, ...)
#: whole stages on a dataset, each seconds a test in-process: rendering the virtual studio, calibration (a
#: dataset's, or its statistics over simulated trials), processing, export, the quality check, depth, a scan
#: run by its engine (threads: a concurrency test) (`./test.sh -m fast --durations=25` shows what the rules missed)
_HEAVY_WORDS = re.compile(r"\b(make_virtual_dataset|calibrate_dataset|simulate|make_trial|process_dataset|"
                          r"export_dataset|check_dataset|estimate_depth|depth_view_task|ScanEngine|FlyScanEngine|"
                          # the CiA 402 drive emulator (in scaled real time) and a checker in a process of its own
                          r"start_drive_emulator|LiveCheckerProcess)\b")
_FULL_FILES = _TOOL_TESTS
#: fixtures that start another process, a Qt loop, a firmware or an emulator
_FULL_FIXTURES = frozenset({"qtbot", "qapp", "run_cli", "start_cli", "sim_rig_port", "vcamera", "grbl_firmware",
                            "grbl_firmware_exe", "small_disk", "scanned", "fake_gv", "fakegv",
                            "shared_data"})      # real files from outside: large, and absent on some machines
_FULL_WORDS = re.compile(r"\b(subprocess|Popen|sys\.executable|multiprocessing|LocalCluster|ProcessPoolExecutor|"
                         r"os\.fork|fake_gv_camera|own_network_namespace|canopen_sim_drive|lfstudio_env|"
                         r"kill_9_after|FirmwareSimulator|build_firmware_simulator|use_vcamera|sim-drive)\b")
_source_cache: dict = {}


def _source(fn) -> str:
    if fn not in _source_cache:
        try:
            _source_cache[fn] = inspect.getsource(fn)
        except (OSError, TypeError):
            _source_cache[fn] = ""
    return _source_cache[fn]


def _own_code(item) -> str:
    """The test function's source and that of every fixture it uses (directly or through others), with
    the test module's own functions these call (and those they call)."""
    fns = [getattr(item, "function", None)]
    defs = getattr(getattr(item, "_fixtureinfo", None), "name2fixturedefs", {})
    for name in item.fixturenames:
        fns += [getattr(d, "func", None) for d in defs.get(name, ())]
    module = getattr(item, "module", None)
    seen: set = set()
    todo = [fn for fn in fns if fn is not None]
    while todo:
        fn = todo.pop()
        if fn in seen:
            continue
        seen.add(fn)
        for name in re.findall(r"\b([A-Za-z_]\w*)\(", _source(fn)):
            helper = getattr(module, name, None)
            if inspect.isfunction(helper) and helper.__module__ == getattr(module, "__name__", None):
                todo.append(helper)
    return "\n".join(_source(fn) for fn in seen)


def tier_of(item) -> str:
    """``"fast"`` or ``"full"`` (the rules above)."""
    path = item.nodeid.split("::")[0]
    shared = any("shared/data" in str(m.kwargs.get("reason", "")) for m in item.iter_markers("skipif"))
    if (item.get_closest_marker("full") or item.get_closest_marker("slow") or path in _FULL_FILES or shared
            or path.startswith(_FULL_FOLDERS) or _FULL_FIXTURES.intersection(item.fixturenames)
            or _FULL_WORDS.search(_own_code(item)) or _HEAVY_WORDS.search(_own_code(item))):
        return "full"
    return "fast"


def pytest_collection_modifyitems(config, items):
    for item in items:
        if tier_of(item) == "fast":
            item.add_marker(pytest.mark.fast)
        elif not item.get_closest_marker("full"):
            item.add_marker(pytest.mark.full)
    order = {path: i for i, path in enumerate(_TOOL_TESTS)}
    items.sort(key=lambda item: order.get(item.nodeid.split("::")[0], len(order)))     # stable: the rest keep order


@pytest.fixture(autouse=True)
def _isolated_config(tmp_path_factory, monkeypatch):
    """Every test gets its own user config folder (QSettings, presets) and log folder."""
    monkeypatch.setenv("LFSTUDIO_CONFIG_DIR", str(tmp_path_factory.mktemp("config")))
    monkeypatch.setenv("LFSTUDIO_LOG_DIR", str(tmp_path_factory.mktemp("logs")))
    monkeypatch.setenv("LFSTUDIO_DOCS_SITE", "")      # F1 shows the in-app guide, even where docs/_build exists


@pytest.fixture(autouse=True)
def _log_handlers_end_with_the_test():
    """The log handlers a test's code installed (``setup_logging``: lfstudio.cli.main, the window) are
    removed when it ends: they write to that test's captured stderr, closed afterwards, so a later
    warning in this worker printed "--- Logging error --- ... I/O operation on closed file" into
    another test's output (and failed a test that checks its stderr holds no traceback)."""
    import logging

    from lfstudio.support.logs import _HANDLER_TAG

    root = logging.getLogger()
    before = set(root.handlers)
    yield
    for handler in [h for h in root.handlers if h not in before and getattr(h, _HANDLER_TAG, False)]:
        root.removeHandler(handler)
        handler.close()


@pytest.fixture
def shared_data() -> Path:
    """``../shared/data`` (real files from outside the project); skips when absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not present on this machine")
    return SHARED_DATA


@pytest.fixture
def run_cli():
    """Run ``python -m lfstudio ARGS`` in a subprocess; returns CompletedProcess (text).
    ``env={"NAME": value}`` adds to this process's environment (None removes NAME)."""
    import subprocess

    def run(*args: str, timeout: float = 120, **kw):
        env = dict(os.environ)
        for name, value in kw.pop("env", {}).items():
            if value is None:
                env.pop(name, None)
            else:
                env[name] = value
        env["PYTHONPATH"] = str(REPO_ROOT) + os.pathsep + env.get("PYTHONPATH", "")
        return subprocess.run([sys.executable, "-m", "lfstudio", *map(str, args)], capture_output=True,
                              text=True, timeout=timeout, env=env, cwd=kw.pop("cwd", REPO_ROOT), **kw)

    return run


@dataclasses.dataclass
class CliRun:
    """What ``cli_main`` returns: as ``run_cli``'s CompletedProcess (``returncode``, ``stdout``, ``stderr``)."""

    args: list[str]
    returncode: int
    stdout: str
    stderr: str


@pytest.fixture
def cli_main(capsys, monkeypatch):
    """Run ``lfstudio ARGS`` in this process (``lfstudio.cli.main``), for tests of parsing and messages
    (fast tier: starting Python for ``run_cli`` costs ~0.85 s a command). Not for commands that open
    the window, devices or long jobs: those keep ``run_cli``."""
    import logging

    from lfstudio.cli import main
    from lfstudio.support.logs import _HANDLER_TAG

    def run(*args) -> CliRun:
        argv = [str(a) for a in args]
        monkeypatch.setattr(sys, "argv", ["lfstudio", *argv])      # the parser's hints read the command line
        capsys.readouterr()
        try:
            code = main(argv)
        except SystemExit as exc:                                   # argparse: --help, --version, usage errors
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        finally:
            root = logging.getLogger()
            for handler in [h for h in root.handlers if getattr(h, _HANDLER_TAG, False)]:
                root.removeHandler(handler)                         # they hold this test's captured streams
                handler.close()
        out, err = capsys.readouterr()
        return CliRun(["lfstudio", *argv], code, out, err)

    return run


@pytest.fixture
def vcamera(tmp_path, monkeypatch):
    """libgphoto2's own virtual PTP camera for this test, in this process and in ``run_cli``
    subprocesses (see tests/vcamera.py); skips when python-gphoto2 or its vusb library is missing."""
    from tests.vcamera import use_vcamera

    return use_vcamera(tmp_path / "vcamera", monkeypatch)


# -- virtual studio datasets (lfstudio.sim) ---------------------------------------------------------
#: the scene and camera of the ``tiny_dataset`` fixtures: 5 x 3 views, 640 px wide, known orientation error
TINY_DATASET_ARGS = dict(columns=5, rows=3, spacing_mm=(4.0, 6.0), width_px=640,
                         rotation_deg=(1.0, -1.5, 0.7), pp_offset_px=(0.0, 0.0), seed=7)


@pytest.fixture(scope="session")
def _tiny_dataset_cache(tmp_path_factory):
    """Renders each variant once per session; tests get their own copy."""
    cache: dict = {}

    def get(fmt: str, **overrides):
        from lfstudio.sim.virtual_dataset import make_virtual_dataset

        key = (fmt, tuple(sorted((k, repr(v)) for k, v in overrides.items())))
        if key not in cache:
            root = tmp_path_factory.mktemp(f"tiny_{fmt}") / "dataset"
            make_virtual_dataset(root, fmt=fmt, **{**TINY_DATASET_ARGS, **overrides})
            cache[key] = root
        return cache[key]

    return get


@pytest.fixture
def make_tiny_dataset(_tiny_dataset_cache, tmp_path):
    """``make_tiny_dataset(fmt="png"|"dng", **make_virtual_dataset overrides) -> Dataset`` (a fresh copy
    in tmp_path; ``ground_truth.json`` at its root)."""
    import shutil

    from lfstudio.dataset import Dataset

    def make(fmt: str = "png", **overrides):
        src = _tiny_dataset_cache(fmt, **overrides)
        dst = tmp_path / f"tiny_{fmt}_{len(list(tmp_path.glob('tiny_*')))}"
        shutil.copytree(src, dst)
        return Dataset.open(dst)

    return make


@pytest.fixture
def tiny_dataset(make_tiny_dataset):
    """A 5 x 3 virtual-studio dataset (640 px wide, 16-bit linear PNG views) with ground truth."""
    return make_tiny_dataset("png")


@pytest.fixture
def tiny_dataset_dng(make_tiny_dataset):
    """The same scene as ``tiny_dataset`` stored as 14-bit Bayer DNG files."""
    return make_tiny_dataset("dng")


def hevc_round_trip(root, tmp_path, name: str = "part"):
    """The dataset at ``root`` processed (no rectification), its first two views of row 0 exported as
    HEVC and imported back (``import-hevc``): the restored Dataset."""
    from lfstudio.dataset import Dataset
    from lfstudio.dataset.profile import Profile
    from lfstudio.export import ExportOptions, export_dataset, import_hevc
    from lfstudio.processing.pipeline import process_dataset

    profile = Profile()
    profile.rectify.enabled = False
    assert process_dataset(root, profile, workers=0).ok
    video = tmp_path / f"{name}.mkv"
    export_dataset(Dataset.open(root), ExportOptions("hevc", video, views="r0,c0-1"))
    return Dataset.open(import_hevc(video, tmp_path / "restored"))


#: the principal-point offset of the calibrated tiny datasets
PP_OFFSET_PX = (8.0, -5.0)


def calibrated_tiny(make_tiny_dataset, **kw):
    """The tiny 5 x 3 virtual dataset (``make_tiny_dataset`` options, rotation (1, -1.5, 0.7) deg, a
    principal-point offset) with the studio's own camera written as its calibration.json: the exact
    rotation, focal length and principal point."""
    from lfstudio.calibration.model import rectifying_homography
    from lfstudio.dataset import Dataset
    from lfstudio.dataset.atomic import atomic_write_json
    from lfstudio.sim.virtual_dataset import load_ground_truth

    ds = make_tiny_dataset("png", pp_offset_px=PP_OFFSET_PX, **kw)
    t = load_ground_truth(ds.root)
    w, h = t["image_size_px"]
    pp = [(w - 1) / 2 + PP_OFFSET_PX[0], (h - 1) / 2 + PP_OFFSET_PX[1]]
    atomic_write_json(ds.root / "calibration.json", {
        "format": "lfstudio-calibration", "version": 1, "rotation_deg": list(t["rotation_deg"]),
        "image_size_px": [w, h], "focal_length_px": t["focal_length_px"], "principal_point_px": pp,
        "principal_point_estimated": True,
        "homography": rectifying_homography(t["rotation_deg"], t["focal_length_px"], (w, h), pp).tolist()})
    return Dataset.open(ds.root)


@pytest.fixture
def calibrated(make_tiny_dataset):
    """The tiny 5 x 3 dataset (640 px) with an exact calibration.json."""
    return calibrated_tiny(make_tiny_dataset)


@pytest.fixture
def calibrated_noisy(make_tiny_dataset):
    """The tiny 5 x 3 dataset (640 px, exact calibration.json) shot where the reference rig stands:
    each view off its grid position by its repeatability (σ 80 × 50 µm)."""
    return calibrated_tiny(make_tiny_dataset, position_noise_um=(80.0, 50.0))


@pytest.fixture
def calibrated_1000(make_tiny_dataset):
    """A 5 x 3 virtual dataset at 1000 px with an exact calibration.json."""
    return calibrated_tiny(make_tiny_dataset, width_px=1000)


@pytest.fixture
def sim_rig():
    """``(controller, simulator)``: the reference rig's GRBL simulator on a real pty (time_scale 0.02,
    so moves take 1/50 of real time), connected and homed. Closed after the test."""
    from lfstudio.rig.profile import load_rig
    from lfstudio.studio.devices import open_rig

    link = open_rig("sim", load_rig(), time_scale=0.02, seed=1, timeout_s=1.0)
    link.controller.home()
    yield link.controller, link.simulator
    link.close()
