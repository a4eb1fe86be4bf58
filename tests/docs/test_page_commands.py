"""Every command a documentation page shows runs (tests/docs/page_commands.py collects them): one test
per block, its commands in order, in a folder of its own. A command that fails names its page and line.

In place of the names the pages use:
  DATASET        a copy of a simulated scan (the virtual studio, 11 x 9 views, 400 px, DNG), calibrated
                 and processed; ``~`` a home folder of the test's own; ``/tmp/...`` a folder of the test's own
  tcp://10.0.0.5:8786  a Dask cluster on this machine (one worker process)
  /dev/pts/N     the port the block's ``lfstudio sim-rig`` printed
  [--option]     (optional) given
  ``lfstudio scan ...``   the block's first whole ``lfstudio scan`` command (with an ``--out`` of its own)
  pip install docs/plugins/X   into a folder of the test's own (the block's later commands find it)
  files the examples take as given (``some_photo.jpg``, another rig's images in ``~/other_rig/``, ...):
                 made by the test (_some_photo, _import_images_source)
An example with its output (``$ `` lines) that runs as shown prints each line the page shows (the
page may leave lines out). And sizes made tiny (``tiny``: a scan of 101 x 21 views scans 3 x 2, simulated devices run at time scale 0
and render 400 px wide, depth maps are computed for 3 of DATASET's views (a page's own ``--views`` too), COLMAP and
nerfstudio exports take 15 of them,
a statistic of 200 trials takes one of 20 points a pair, a focal length in the reference camera's pixels is scaled to
DATASET's): the test checks that the command works as shown, not its figures.

``lfstudio`` commands run in this process (``lfstudio.cli.main``); one with variables set before it
(``VCAMERADIR=... lfstudio ...``), and the simulators that serve until Ctrl-C (``sim-rig``, ``sim-drive``),
run as programs, as in a terminal. Commands a page marks ``not-run`` (with its reason) are only parsed.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import re
import select
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import REPO_ROOT
from tests.docs.page_commands import Block, Command, all_blocks

BLOCKS = all_blocks(REPO_ROOT)
#: at most this many commands of all pages are not run (each with its page's reason); keep it small
MAX_NOT_RUN = 24
#: lfstudio commands that serve until Ctrl-C (they call serving.serve_until_stopped): started as
#: programs, their first line (a port, an address) kept for the block's later commands
SERVING = {"sim-rig", "sim-drive"}
#: programs that install software: never run (``pip install FOLDER`` of the checkout goes to a folder of
#: the test's own)
INSTALLERS = {"pip", "pip3", "pipx", "apt", "apt-get", "sudo", "dpkg"}
#: the simulated scan DATASET stands for
DATASET_GRID = ("11", "9")
DATASET_WIDTH_PX = 400
#: the reference camera's image width (a pixel size a page gives for it is scaled to DATASET's)
REFERENCE_WIDTH_PX = 7952
#: the cluster address the pages show: a Dask cluster on this machine in its place
CLUSTER = "tcp://10.0.0.5:8786"


# -- the sizes made tiny ---------------------------------------------------------------------------
def _option(argv: list[str], name: str) -> int | None:
    return argv.index(name) if name in argv and argv.index(name) + 1 < len(argv) else None


def tiny(argv: list[str]) -> list[str]:
    """``argv`` (an lfstudio command line) with sizes that take minutes made small."""
    argv = list(argv)
    command = argv[0] if argv else ""

    def set_value(name: str, value: str) -> None:
        i = _option(argv, name)
        if i is not None:
            argv[i + 1] = value

    def value(name: str) -> str | None:
        i = _option(argv, name)
        return argv[i + 1] if i is not None else None

    if command == "scan":
        grid = value("--grid")
        if grid and re.fullmatch(r"\d+x\d+", grid):
            c, r = map(int, grid.split("x"))
            if c * r > 27:
                set_value("--grid", "3x2")
    if command in ("scan", "sim-rig", "sim-drive", "rig") and (value("--time-scale") or "0") != "0":
        set_value("--time-scale", "0")
    if command == "scan" and "--resume" not in argv:
        if "--time-scale" not in argv:
            argv += ["--time-scale", "0"]
        if (value("--camera") or "sim") == "sim" and "--sim-width-px" not in argv:
            argv += ["--sim-width-px", "400"]
    if command == "export" and value("--format") in ("colmap", "nerfstudio") and "--views" not in argv:
        argv += ["--views", "r3-5,c3-7"]    # 15 of DATASET's views: their sparse point cloud takes seconds
    if command == "depth":                  # 3 of DATASET's views (a page's own --views: the same syntax)
        argv += ["--views", "r4,c4-6"] if "--views" not in argv else []
        set_value("--views", "r4,c4-6")
    if command == "rig" and _option(argv, "--port") is not None and value("--port") == "sim" \
            and "--time-scale" not in argv:
        argv[1:1] = ["--time-scale", "0"]
    if command == "virtual-dataset":
        width = value("--width")
        if width is None or int(width) > 400:
            argv += ["--width", "400"] if width is None else []
            set_value("--width", "400")
    if command == "simulate-calibration":
        set_value("--trials", "1")
        if "--points-per-pair" not in argv:
            argv += ["--points-per-pair", "20"]
        sweep = value("--sweep")
        if sweep and sweep.count(":") == 2:
            a, b, _ = sweep.split(":")
            set_value("--sweep", f"{a}:{b}:{float(b) - float(a):g}")
    return argv


# -- placeholders the examples take as given -------------------------------------------------------
def _some_photo(path: Path) -> None:
    import cv2
    import numpy as np

    y, x = np.mgrid[0:240, 0:320]
    cv2.imwrite(str(path), np.dstack([(x + y) % 256, x % 256, y % 256]).astype(np.uint8))


def _other_rig(path: Path, columns: int, rows: int, pattern: str, order: str) -> None:
    """Another rig's images: the virtual studio's views, as files of that rig's naming."""
    import tifffile

    from lfstudio.sim.virtual_dataset import make_virtual_dataset

    root = path.parent / f".render-{path.name}"
    make_virtual_dataset(root, columns=columns, rows=rows, width_px=240, fmt="png", truth_maps=False)
    import cv2

    path.mkdir(parents=True, exist_ok=True)
    n = 0
    for r in range(rows):
        cols = range(columns) if order == "row-major" or r % 2 == 0 else range(columns - 1, -1, -1)
        for c in cols:
            img = cv2.imread(str(root / "raw" / f"r{r:02d}_c{c:03d}.png"), cv2.IMREAD_UNCHANGED)
            name = pattern.replace("*", f"{n:03d}")
            if name.endswith(".tif"):
                tifffile.imwrite(path / name, img[:, :, ::-1])
            else:
                cv2.imwrite(str(path / name), img)
            n += 1
    shutil.rmtree(root)


def _import_images_source(argv: list[str], home: Path) -> None:
    """The folder an ``import-images`` example reads, made when the page takes it as given."""
    folder = Path(os.path.expanduser(argv[1]))
    if folder.exists() or not str(folder).startswith(str(home)):
        return
    grid = argv[argv.index("--grid") + 1]
    c, r = map(int, grid.split("x"))
    pattern = argv[argv.index("--pattern") + 1] if "--pattern" in argv else "img_*.png"
    order = argv[argv.index("--order") + 1] if "--order" in argv else "row-major"
    _other_rig(folder, c, r, pattern, order)


# -- running ---------------------------------------------------------------------------------------
class _Block:
    """One block's run: its folders, its servers, what its commands printed."""

    def __init__(self, block: Block, tmp: Path, monkeypatch, capsys, dataset_template):
        self.block, self.tmp, self.capsys = block, tmp, capsys
        self.home = tmp / "home"
        self.work = tmp / "work"
        self.home.mkdir()
        self.work.mkdir()
        self.fake_tmp = tmp / "tmp"
        self.fake_tmp.mkdir()
        monkeypatch.setenv("HOME", str(self.home))
        monkeypatch.chdir(self.work)
        self.dataset_template = dataset_template
        self.dataset: Path | None = None
        self.served: str | None = None
        self.servers: list[subprocess.Popen] = []
        self.background: list[subprocess.Popen] = []
        self.dask = None
        self.site: Path | None = None                 # where the block's `pip install` put a package
        self.base: dict[str, list[str]] = {}          # a command's first whole form in the block (for "...")

    # words -----------------------------------------------------------------------------------------
    def word(self, w: str) -> str:
        if w == "DATASET" or w.startswith("DATASET/"):
            if self.dataset is None:
                self.dataset = self.tmp / "DATASET"
                shutil.copytree(self.dataset_template(), self.dataset)
            return str(self.dataset) + w[len("DATASET"):]
        if w == "/dev/pts/N":
            assert self.served, f"{self.block.where}: /dev/pts/N, but no sim-rig before it in the block"
            return self.served
        if w == CLUSTER:
            return self.cluster()
        if w.startswith("~"):
            return os.path.expanduser(w)
        if w.startswith("/tmp/"):
            return str(self.fake_tmp / w[len("/tmp/"):])
        m = re.fullmatch(r"\[(--?[\w-]+)\]", w)
        return m.group(1) if m else w

    def lfstudio_argv(self, words: list[str], c: Command) -> list[str]:
        argv = [self.word(w) for w in words]
        if "DATASET" in words and "--focal-length-px" in argv:     # the reference camera's, in DATASET's pixels
            i = argv.index("--focal-length-px") + 1
            argv[i] = f"{float(argv[i]) * DATASET_WIDTH_PX / REFERENCE_WIDTH_PX:.1f}"
        if argv and "..." in argv:
            base = self.base.get(argv[0])
            assert base, f"{c.where}: `lfstudio {argv[0]} ...` but no whole `lfstudio {argv[0]}` before it"
            base = list(base)
            if "--out" in base:                 # a scan of its own
                i = base.index("--out")
                base[i + 1] = f"{base[i + 1]}-{c.line}"
            i = argv.index("...")
            argv[i:i + 1] = base[1:]
        elif argv and "--resume" not in argv:
            self.base.setdefault(argv[0], argv)
        return tiny(argv)

    def cluster(self) -> str:
        if self.dask is None:
            from distributed import LocalCluster

            self.dask = LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None)
        return self.dask.scheduler_address

    # commands --------------------------------------------------------------------------------------
    def run(self, c: Command) -> None:
        words = c.words()
        for part in _split_and(words):
            self.run_one(c, part)

    def run_one(self, c: Command, words: list[str]) -> None:
        env = {}
        while words and re.fullmatch(r"[A-Z_][A-Z0-9_]*=.*", words[0]):
            name, value = words.pop(0).split("=", 1)
            env[name] = self.word(value)
        background = bool(words) and words[-1] == "&"
        if background:
            words = words[:-1]
        program = words[0]
        if program in ("pip", "pip3") and words[1:2] == ["install"]:
            self.pip_install(c, words[2:])
            return
        if program in INSTALLERS:
            pytest.fail(f"{c.where}: `{c.text}` installs software on this machine: the test does not run it "
                        "(mark it <!-- not-run: why -->)")
        if program == "lfstudio" or program.endswith("/lfstudio"):
            argv = self.lfstudio_argv(words[1:], c)
            if argv and argv[0] == "import-images":
                _import_images_source(argv, self.home)
            if argv and argv[0] in SERVING:
                self.serve(c, argv)
            elif env or background or self.site is not None:
                self.program(c, [sys.executable, "-m", "lfstudio", *argv], env, background)
            else:
                self.in_process(c, argv)
            return
        args = [self.word(w) for w in words[1:]]
        for w in args:
            if w == "some_photo.jpg" and not Path(w).exists():
                _some_photo(self.work / w)
        exe = shutil.which(str(REPO_ROOT / program) if program.startswith(("./", "packaging/", "tools/")) else program)
        if exe is None:
            pytest.skip(f"{c.where}: {program} is not installed here")
        self.program(c, [exe, *args], env, background)

    def pip_install(self, c: Command, args: list[str]) -> None:
        """``pip install FOLDER`` (a page's example package): into a folder of the test's own, which the
        block's later commands find on their path (they run as programs: the plugins a process loaded stay)."""
        folders = [a for a in args if not a.startswith("-")]
        assert len(folders) == 1 and (REPO_ROOT / folders[0]).is_dir(), \
            f"{c.where}: `{c.text}`: the test installs only a folder of the checkout"
        source = self.tmp / "pip-source" / Path(folders[0]).name
        shutil.copytree(REPO_ROOT / folders[0], source)          # a build writes beside its sources
        self.site = self.tmp / "pip-site"
        self.program(c, [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                         "--no-index", "--disable-pip-version-check", "--target", str(self.site), str(source)], {}, False)

    def in_process(self, c: Command, argv: list[str]) -> None:
        from lfstudio.cli import main
        from lfstudio.support.logs import _HANDLER_TAG

        self.capsys.readouterr()
        old_argv = sys.argv
        sys.argv = ["lfstudio", *argv]              # the parser's hints read the command line
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        finally:
            sys.argv = old_argv
            root = logging.getLogger()
            for handler in [h for h in root.handlers if getattr(h, _HANDLER_TAG, False)]:
                root.removeHandler(handler)
                handler.close()
        out, err = self.capsys.readouterr()
        assert code == 0, _failed(c, ["lfstudio", *argv], code, out, err)
        if c.output and argv == [self.word(w) for w in c.words()[1:]]:     # an example, run as shown
            printed = {" ".join(line.split()) for line in (out + err).splitlines()}
            missing = [line for line in c.output if " ".join(line.split()) not in printed and "..." not in line]
            assert not missing, (f"{c.where}: `{c.text}` no longer prints what the page shows:\n"
                                 + "\n".join(missing) + "\n-- it printed:\n" + out[-3000:])

    def program(self, c: Command, args: list[str], env: dict[str, str], background: bool) -> None:
        full = dict(os.environ, **env)
        full["PYTHONPATH"] = os.pathsep.join([str(REPO_ROOT), *([str(self.site)] if self.site else []),
                                              full.get("PYTHONPATH", "")])
        if background:
            proc = subprocess.Popen(args, env=full, cwd=self.work, stdin=subprocess.DEVNULL,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            self.background.append(proc)
            ready = READY.get(Path(args[0]).name)
            if ready is not None:
                ready(c, proc)
            return
        proc = subprocess.run(args, env=full, cwd=self.work, capture_output=True, text=True, timeout=240)
        assert proc.returncode == 0, _failed(c, args, proc.returncode, proc.stdout, proc.stderr)

    def serve(self, c: Command, argv: list[str]) -> None:
        env = dict(os.environ, PYTHONPATH=str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        proc = subprocess.Popen([sys.executable, "-m", "lfstudio", *argv], env=env, cwd=self.work,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.servers.append(proc)
        ready, _, _ = select.select([proc.stdout], [], [], 60)
        line = proc.stdout.readline().strip() if ready else ""
        if not line:
            proc.kill()
            _, err = proc.communicate(timeout=10)
            pytest.fail(_failed(c, ["lfstudio", *argv], proc.returncode, "", err))
        self.served = line

    def close(self) -> None:
        if self.dask is not None:
            self.dask.close()
        for proc in self.servers:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)            # Ctrl-C, as the page says
        for proc in self.background:
            if proc.poll() is None:
                proc.terminate()
        for proc in self.servers + self.background:
            try:
                proc.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()


def _fake_gv_ready(c: Command, proc: subprocess.Popen, timeout_s: float = 20.0) -> None:
    """aravis's fake camera answers discovery (as tests/fakegv.py waits for it)."""
    from lfstudio.rig.genicam import list_cameras
    from tests.fakegv import DEVICE_ID

    deadline = time.monotonic() + timeout_s
    while DEVICE_ID not in list_cameras():           # each try waits ~1 s for answers
        if proc.poll() is not None:
            pytest.fail(f"{c.where}: `{c.text}` ended at once: {(proc.stderr.read() if proc.stderr else '').strip()}")
        if time.monotonic() > deadline:
            pytest.fail(f"{c.where}: `{c.text}` did not answer discovery within {timeout_s:g} s")


#: programs a page starts in the background (``&``), and how the test knows each is ready (an operator
#: waits for it before typing the next command)
READY = {"arv-fake-gv-camera-0.8": _fake_gv_ready}


def _split_and(words: list[str]) -> list[list[str]]:
    parts: list[list[str]] = [[]]
    for w in words:
        if w == "&&":
            parts.append([])
        else:
            parts[-1].append(w)
    return [p for p in parts if p]


def _failed(c: Command, args: list[str], code, out: str, err: str) -> str:
    tail = "\n".join((err.strip() or out.strip()).splitlines()[-12:])
    return (f"{c.where}: `{c.text}` exited {code}\n  (run as: {shlex.join(map(str, args))})\n{tail}")


@pytest.fixture(scope="session")
def dataset_template(tmp_path_factory):
    """DATASET: a simulated scan (virtual studio), calibrated and processed; made once."""
    made: list[Path] = []

    def get() -> Path:
        if not made:
            from lfstudio.dataset.profile import Profile
            from lfstudio.processing.pipeline import process_dataset
            from lfstudio.sim.virtual_dataset import make_virtual_dataset

            root = tmp_path_factory.mktemp("docs-dataset") / "DATASET"
            make_virtual_dataset(root, columns=int(DATASET_GRID[0]), rows=int(DATASET_GRID[1]), width_px=DATASET_WIDTH_PX,
                                 rotation_deg=(1.0, -1.5, 0.7), fmt="dng", truth_maps=False, workers=0)
            from lfstudio.cli import main

            assert main(["calibrate", str(root)]) == 0
            assert process_dataset(root, Profile.for_dataset(root), workers=0).ok
            made.append(root)
        return made[0]

    return get


@contextlib.contextmanager
def _fake_gv_turn(block: Block):
    """Blocks starting aravis's fake GigE camera take turns with the tests' (its port is fixed)."""
    if not any("arv-fake-gv-camera" in c.text for c in block.commands):
        yield
        return
    from tests.fakegv import LOCK, need_aravis

    need_aravis()
    with open(LOCK, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield


def _needs(block: Block) -> None:
    text = " ".join(c.text for c in block.commands if not c.not_run)
    if "VCAMERADIR=" in text:
        pytest.importorskip("gphoto2")


@pytest.mark.parametrize("block", BLOCKS, ids=[b.where for b in BLOCKS])
def test_the_commands_a_page_shows_run(block: Block, tmp_path, monkeypatch, capsys, dataset_template):
    parse_only = [c for c in block.commands if c.not_run]
    for c in parse_only:
        _parses(c)
    if len(parse_only) == len(block.commands):
        return
    _needs(block)
    run = _Block(block, tmp_path, monkeypatch, capsys, dataset_template)
    with _fake_gv_turn(block):
        try:
            for c in block.commands:
                if not c.not_run:
                    run.run(c)
        finally:
            run.close()


def _parses(c: Command) -> None:
    """A command the test does not run still names a command and options that exist."""
    from lfstudio.cli import attach_dash_values, build_parser

    for words in _split_and(c.words()):
        while words and re.fullmatch(r"[A-Z_][A-Z0-9_]*=.*", words[0]):
            words.pop(0)
        if not words or not (words[0] == "lfstudio" or words[0].endswith("/lfstudio")):
            continue
        argv = [w for w in words[1:] if w != "&"]
        if "..." in argv:
            i = argv.index("...")
            argv[i:i + 1] = ["--out", "x"] if argv[0] == "scan" and "--out" not in argv else []
        parser = build_parser()
        try:
            parser.parse_args(attach_dash_values(parser, argv))
        except SystemExit as exc:
            if exc.code not in (0, None):
                pytest.fail(f"{c.where}: `{c.text}` (not run: {c.not_run}) does not parse")


def test_few_commands_are_not_run_and_each_says_why():
    not_run = [c for b in BLOCKS for c in b.commands if c.not_run]
    run = [c for b in BLOCKS for c in b.commands if not c.not_run]
    assert len(run) >= 50, len(run)
    assert all(c.not_run.strip() and c.not_run != "(no reason given)" for c in not_run), \
        [c.where for c in not_run if not c.not_run.strip() or c.not_run == "(no reason given)"]
    assert len(not_run) <= MAX_NOT_RUN, "\n".join(f"{c.where}: {c.text} ({c.not_run})" for c in not_run)


def test_the_serving_commands_are_those_that_serve_until_stopped():
    cli = REPO_ROOT / "lfstudio" / "cli"
    serving = {p.stem.replace("_", "-") for p in cli.glob("*.py")
               if p.stem != "serving" and "serve_until_stopped" in p.read_text(encoding="utf-8")}
    assert serving == SERVING


def test_the_collector_finds_commands_markers_and_prompts(tmp_path):
    from tests.docs.page_commands import blocks_of

    page = tmp_path / "docs" / "p.md"
    page.parent.mkdir()
    page.write_text("# T\n\n```bash\nlfstudio plan   # a comment\nlfstudio info x \\\n    --json\n```\n\n"
                    "<!-- not-run \"/dev/ttyUSB0\": a GRBL board -->\n```bash\nlfstudio rig --port sim status\n"
                    "lfstudio rig --port /dev/ttyUSB0 status\n```\n\n```\n$ lfstudio plan\nDepth of field\n```\n\n"
                    "```{toctree}\nlfstudio\n```\n", encoding="utf-8")
    blocks = blocks_of(page, tmp_path)
    assert [b.line for b in blocks] == [3, 10, 15]
    assert [(c.line, c.text, c.not_run) for b in blocks for c in b.commands] == [
        (4, "lfstudio plan", ""), (5, "lfstudio info x --json", ""), (11, "lfstudio rig --port sim status", ""),
        (12, "lfstudio rig --port /dev/ttyUSB0 status", "a GRBL board"), (16, "lfstudio plan", "")]
    assert blocks[2].commands[0].output == ["Depth of field"]
    assert tiny(["scan", "--grid", "101x21", "--time-scale", "0.1"]) == [
        "scan", "--grid", "3x2", "--time-scale", "0", "--sim-width-px", "400"]
    assert tiny(["scan", "--camera", "gphoto2", "--grid", "9x3"]) == [
        "scan", "--camera", "gphoto2", "--grid", "9x3", "--time-scale", "0"]
