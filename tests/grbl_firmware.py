"""The real GRBL 1.1h firmware, run by its official simulator (grbl-sim) on a pseudo-terminal.

``../shared/vendor/grbl`` holds the firmware sources and grbl-sim. :func:`build_firmware_simulator`
builds them with their own Makefile into a cache folder outside the repository (never into the
sources, never into the repo), keyed by a hash of the sources and of the build options, so a
session builds once and later sessions reuse it. :class:`FirmwareSimulator` runs the binary and
bridges it to a second pseudo-terminal whose path our driver opens with pyserial, byte for byte
like a USB serial port.

Where the sources come from: ``$LFSTUDIO_GRBL_SRC``, else ``<repo>/../shared/vendor/grbl``, else
``/work/shared/vendor/grbl``. No sources, no ``make``/C compiler, or a failed build: the caller gets
:class:`FirmwareUnavailable` with the reason (the fixtures turn it into a skip).

Build options (see :data:`BUILD_OPTIONS`):

- ``CLOCK=1000000``: the simulated AVR runs at 1 MHz instead of 16 MHz. grbl-sim simulates every
  clock tick; a lower clock makes each simulated second 16x cheaper. Steps, positions, the
  planner and every protocol answer are the same; only step timing granularity is coarser.
- ``-fcommon``: the 2015 sources define globals in headers; GCC >= 10 needs it to link.
- ``tests/grbl_sim_shim.c`` is linked in with ``--wrap`` (see its header): fast stdin polling,
  input pins idle high, optional limit switches (so ``$H`` homes for real), lockstep between the
  simulated stepper interrupt and the firmware's main loop (results do not depend on how the OS
  schedules the two threads), and EEPROM written through at once.

Speed: grbl-sim's ``-t <factor>`` multiplies its real-time clock. :class:`FirmwareSimulator` runs
at ``speedup`` x real time (default 10) when the CPU allows; it is slower, never different, on a
busy machine. Tests must not depend on it: wait for states, never for durations.

A board reset: opening a real Arduino's port toggles DTR and reboots GRBL (banner, and with homing
enabled ``[MSG:'$H'|'$X' to unlock]``). ``reset_on_open=True`` emulates that: each time a client
opens the port the firmware process is restarted (machine position back to 0, EEPROM settings kept).
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import os
import select
import shutil
import signal
import subprocess
import tempfile
import threading
import time
import tty
from pathlib import Path

import serial

REPO_ROOT = Path(__file__).resolve().parent.parent
SHIM = Path(__file__).resolve().parent / "grbl_sim_shim.c"
_WRAPPED = ("platform_poll_stdin", "grbl_per_tick", "st_prep_buffer", "platform_sleep", "eeprom_put_char",
            "serial_write", "interrupt_SERIAL_UDRE", "system_set_exec_state_flag", "system_clear_exec_state_flag",
            "system_set_exec_alarm", "system_clear_exec_alarm", "system_set_exec_motion_override_flag",
            "system_set_exec_accessory_override_flag", "system_clear_exec_motion_overrides",
            "system_clear_exec_accessory_overrides")
#: make variables passed to grbl-sim's own Makefile (see the module docstring)
BUILD_OPTIONS = {
    "CLOCK": "1000000",
    "FLAGS": "-O2 -fcommon",
    "LINUX_LIBRARIES": "lfstudio_shim.o -lrt -pthread " + " ".join(f"-Wl,--wrap={f}" for f in _WRAPPED),
}
#: GRBL 1.1h's defaults (DEFAULTS_GENERIC in defaults.h), as a fresh EEPROM reports them
FIRMWARE_DEFAULTS = {110: 500.0, 111: 500.0, 112: 500.0, 120: 10.0, 121: 10.0, 122: 10.0,
                     130: 200.0, 131: 200.0, 132: 200.0, 20: 0, 21: 0, 22: 0, 23: 0, 27: 1.0}
_REALTIME = frozenset(b"?!~\x18") | frozenset(range(0x80, 0x100))


class FirmwareUnavailable(RuntimeError):
    """The firmware simulator cannot be built or run here; the message says why."""


def find_grbl_source() -> Path:
    """The vendored GRBL folder (holding ``grbl/grbl-sim/Makefile``), or FirmwareUnavailable."""
    candidates = []
    if os.environ.get("LFSTUDIO_GRBL_SRC"):
        candidates.append(Path(os.environ["LFSTUDIO_GRBL_SRC"]))
    candidates += [REPO_ROOT.parent / "shared" / "vendor" / "grbl", Path("/work/shared/vendor/grbl")]
    for path in candidates:
        if (path / "grbl" / "grbl-sim" / "Makefile").is_file():
            return path
    raise FirmwareUnavailable("GRBL sources not found (set LFSTUDIO_GRBL_SRC, or put them in "
                              f"../shared/vendor/grbl); looked in {', '.join(map(str, candidates))}")


def _cache_root() -> Path:
    if os.environ.get("LFSTUDIO_GRBL_SIM_CACHE"):
        return Path(os.environ["LFSTUDIO_GRBL_SIM_CACHE"])
    import platformdirs      # $XDG_CACHE_HOME or ~/.cache on Linux

    return Path(platformdirs.user_cache_dir("lfstudio-grbl-sim", appauthor=False))


def _source_hash(src: Path) -> str:
    h = hashlib.sha256()
    for path in sorted((src / "grbl").rglob("*")):
        if path.is_file() and path.suffix not in (".o", ".exe"):
            h.update(str(path.relative_to(src)).encode() + b"\0" + path.read_bytes() + b"\0")
    h.update(SHIM.read_bytes())
    h.update(repr(sorted(BUILD_OPTIONS.items())).encode())
    return h.hexdigest()[:16]


def build_firmware_simulator(source: Path | None = None, cache_root: Path | None = None) -> Path:
    """Build (once per source hash) and return the path of ``grbl_sim.exe``."""
    src = source or find_grbl_source()
    if not (src / "grbl" / "grbl-sim" / "Makefile").is_file():
        raise FirmwareUnavailable(f"{src} holds no GRBL sources (grbl/grbl-sim/Makefile is missing)")
    make = shutil.which("make")
    cc = shutil.which("cc") or shutil.which("gcc")
    if make is None or cc is None:
        raise FirmwareUnavailable("make and a C compiler are needed to build the GRBL simulator "
                                  "(apt-get install build-essential)")
    root = cache_root or _cache_root()
    key = _source_hash(src)
    exe = root / key / "grbl" / "grbl-sim" / "grbl_sim.exe"
    if exe.is_file():
        return exe
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError:                               # no writable home (CI user): a private temp folder
        root = Path(tempfile.gettempdir()) / f"lfstudio-grbl-sim-{os.getuid()}"
        exe = root / key / "grbl" / "grbl-sim" / "grbl_sim.exe"
        if exe.is_file():
            return exe
        root.mkdir(mode=0o700, parents=True, exist_ok=True)
    with open(root / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)             # one build at a time (parallel sessions)
        if exe.is_file():
            return exe
        work = Path(tempfile.mkdtemp(prefix=f"build-{key}-", dir=root))
        try:
            shutil.copytree(src / "grbl", work / "grbl", copy_function=shutil.copyfile,
                            ignore=shutil.ignore_patterns("*.o", "*.exe"))
            for d, _, _ in os.walk(work):
                os.chmod(d, 0o755)                   # the vendored tree is read-only
            sim_dir = work / "grbl" / "grbl-sim"
            shutil.copyfile(SHIM, sim_dir / "lfstudio_shim.c")
            cmd = [make, "-C", str(sim_dir), "lfstudio_shim.o", "main", f"CC={cc}"]
            cmd += [f"{k}={v}" for k, v in BUILD_OPTIONS.items()]
            try:
                done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
            except subprocess.TimeoutExpired:
                raise FirmwareUnavailable("building the GRBL simulator took over 10 minutes") from None
            if done.returncode != 0 or not (sim_dir / "grbl_sim.exe").is_file():
                tail = "\n".join((done.stdout + done.stderr).strip().splitlines()[-15:])
                raise FirmwareUnavailable(f"building the GRBL simulator failed ({' '.join(cmd[:5])} ...):\n{tail}")
            os.replace(work, root / key)
        finally:
            if work.exists():
                shutil.rmtree(work, ignore_errors=True)
    return exe


def read_spindle_log(path: Path) -> list[tuple[float, bool, tuple[int, int, int], int]]:
    """The spindle output's changes the shim logged: (simulated time s, on, X Y Z step counts, OCR2A)."""
    out = []
    if not Path(path).is_file():
        return out
    for line in Path(path).read_text().splitlines():
        parts = line.split()
        if len(parts) == 6:
            out.append((float(parts[0]), parts[1] == "1", (int(parts[2]), int(parts[3]), int(parts[4])),
                        int(parts[5])))
    return out


class SpindleLineFollower:
    """The firmware's spindle output as a trigger line on this machine's clock, for the simulated camera
    (``SimulatedCamera.trigger_line``): a thread follows the shim's spindle log as the firmware writes it
    (flushed at each change) and sets :attr:`line` (a :class:`lfstudio.sim.trigger_line.TriggerLine`)
    at the ``time.monotonic()`` it reads each change.

    The clocks: the firmware's simulated time runs at ``speedup`` x real time only while the CPU allows,
    so it is not mapped by a formula; a change is dated when it is read. The firmware's status reports
    are dated the same way (when the driver reads them), so both are the firmware's present as this
    machine sees it; the edge is late by the follower's reading (its poll, ``poll_s``, and the thread's
    wake-up: about a millisecond, 0.05 mm at 50 mm/s), not by a drift between clocks.

    :attr:`edges`: ``(t_monotonic, t_simulated, on, (x_mm, y_mm))`` with the carriage's work position
    from the logged step counts (``steps_per_mm``, less the work offset ``wco_mm``). For the camera's
    renders, :meth:`true_position_at` is the position at the last change at or before ``t`` (the
    firmware says nothing between changes; an exposure of 1 ms after a rising edge is 0.05 mm on)."""

    def __init__(self, log: Path, steps_per_mm: tuple[float, float], wco_mm: tuple[float, float] = (0.0, 0.0),
                 poll_s: float = 0.0005):
        from lfstudio.sim.trigger_line import TriggerLine

        self.log = Path(log)
        self.steps_per_mm = steps_per_mm
        self.wco_mm = wco_mm
        self.poll_s = poll_s
        self.line = TriggerLine("GRBL 1.1h spindle output (firmware simulator)")
        self.edges: list[tuple[float, float, bool, tuple[float, float]]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._follow, name="grbl-spindle-follower", daemon=True)

    def start(self) -> "SpindleLineFollower":
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)

    def _follow(self) -> None:
        handle = None
        pending = b""
        try:
            while not self._stop.is_set():
                if handle is None and self.log.is_file():
                    handle = open(self.log, "rb")
                chunk = handle.read() if handle is not None else b""
                if chunk:
                    now = time.monotonic()
                    pending += chunk
                    *lines, pending = pending.split(b"\n")
                    for raw in lines:
                        parts = raw.split()
                        if len(parts) != 6:
                            continue
                        on = parts[1] == b"1"
                        x = int(parts[2]) / self.steps_per_mm[0] - self.wco_mm[0]
                        y = int(parts[3]) / self.steps_per_mm[1] - self.wco_mm[1]
                        with self._lock:
                            self.edges.append((now, float(parts[0]), on, (x, y)))
                        self.line.set(on, now)
                    continue
                self._stop.wait(self.poll_s)
        finally:
            if handle is not None:
                handle.close()

    def true_position_at(self, t: float) -> tuple[float, float] | None:
        with self._lock:
            before = [e for e in self.edges if e[0] <= t]
        return before[-1][3] if before else None

    def position_mm(self) -> tuple[float, float]:
        with self._lock:
            return self.edges[-1][3] if self.edges else (0.0, 0.0)


def _split_lines(buf: bytearray) -> list[str]:
    lines = []
    while True:
        cut = min((i for i in (buf.find(b"\n"), buf.find(b"\r")) if i >= 0), default=-1)
        if cut < 0:
            return lines
        raw = bytes(buf[:cut])
        del buf[:cut + 1]
        if raw:
            lines.append(raw.decode("ascii", "replace"))


class FirmwareSimulator:
    """One GRBL 1.1h firmware process on a pty. ``start()`` returns the port path for pyserial.

    ``workdir`` holds the firmware's EEPROM (``EEPROM.DAT``: settings, work offsets), so settings
    persist across :meth:`power_cycle` like on a real board. ``switches``: per axis
    ``(min_mm, max_mm)`` limit-switch positions relative to the power-up position (None: no switch);
    without switches ``$H`` fails with ALARM 9 as on a rig that has none. ``spindle_log``: a file the
    firmware process writes each change of its spindle PWM output to (:func:`read_spindle_log`).

    What passed: :attr:`lines_received` (lines the host sent), :attr:`realtime_received`
    (realtime bytes: ``?`` is left out), :attr:`lines_sent` (lines the firmware sent).
    """

    def __init__(self, exe: Path, workdir: Path, *, speedup: float = 10.0,
                 switches: tuple[tuple[float | None, float | None], ...] | None = None,
                 reset_on_open: bool = False, spindle_log: Path | None = None):
        self.exe = Path(exe)
        self.spindle_log = spindle_log
        self.workdir = Path(workdir)
        self.speedup = float(speedup)
        self.switches = switches
        self.reset_on_open = reset_on_open
        self.lines_received: list[str] = []
        self.realtime_received: list[bytes] = []
        self.lines_sent: list[str] = []
        self.boots = 0
        self.opens = 0
        self._host_open = False
        self._host_changed = threading.Condition()
        self._banners = 0                         # banners printed (one per boot, one per reset)
        self._proc: subprocess.Popen | None = None
        self._fw_master: int | None = None
        self._host_master: int | None = None
        self._port: str | None = None
        self._lock = threading.RLock()
        self._running = threading.Event()
        self._thread: threading.Thread | None = None
        self._from_host = bytearray()
        self._from_fw = bytearray()
        self._to_fw = bytearray()
        self._to_host = bytearray()

    # -- lifecycle ---------------------------------------------------------------------------------
    @property
    def port(self) -> str | None:
        return self._port

    def start(self) -> str:
        if self._thread is not None:
            return self._port or ""
        self.workdir.mkdir(parents=True, exist_ok=True)
        host_master, host_slave = os.openpty()
        tty.setraw(host_slave)
        self._port = os.ttyname(host_slave)
        os.close(host_slave)                      # nobody has the port open: like a cable not plugged in
        os.set_blocking(host_master, False)
        self._host_master = host_master
        self._spawn()
        self._running.set()
        self._thread = threading.Thread(target=self._bridge, name="grbl-firmware-bridge", daemon=True)
        self._thread.start()
        self._wait_booted()
        return self._port

    def _spawn(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        env = dict(os.environ)
        env.pop("LFSTUDIO_GRBL_SIM_SWITCHES", None)
        env.pop("LFSTUDIO_GRBL_SIM_SPINDLE_LOG", None)
        if self.spindle_log is not None:
            env["LFSTUDIO_GRBL_SIM_SPINDLE_LOG"] = str(self.spindle_log)
        if self.switches:
            env["LFSTUDIO_GRBL_SIM_SWITCHES"] = ",".join(
                f"{'' if lo is None else lo}:{'' if hi is None else hi}" for lo, hi in self.switches)
        args = [str(self.exe), "-n", "-t", f"{self.speedup:g}", "-b", os.devnull, "-s", os.devnull]
        try:
            self._proc = subprocess.Popen(args, stdin=slave, stdout=slave, stderr=subprocess.DEVNULL,
                                          cwd=self.workdir, env=env, start_new_session=True)
        finally:
            os.close(slave)
        os.set_blocking(master, False)
        self._fw_master = master
        self._from_fw.clear()
        self._to_fw.clear()
        self.boots += 1

    def _kill(self) -> None:
        proc, self._proc = self._proc, None
        if proc is not None and proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait(5)
        fd, self._fw_master = self._fw_master, None
        if fd is not None:
            os.close(fd)

    def power_cycle(self, wait: bool = True) -> None:
        """Switch the board off and on: the firmware restarts (MPos 0; EEPROM settings kept).
        ``wait``: return once it has printed its banner (bytes sent before that are lost)."""
        banners = self._banners
        with self._lock:
            self._kill()
            self._spawn()
        if wait:
            self._wait_booted(banners)

    def _wait_booted(self, banners_before: int = 0, timeout_s: float = 20.0) -> None:
        with self._host_changed:
            if not self._host_changed.wait_for(lambda: self._banners > banners_before, timeout_s):
                raise TimeoutError(f"the GRBL firmware did not boot within {timeout_s:g} s")

    def close(self) -> None:
        self._running.clear()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5)
        with self._lock:
            self._kill()
            if self._host_master is not None:
                os.close(self._host_master)
                self._host_master = None

    def __enter__(self) -> "FirmwareSimulator":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def alive(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    # -- the bridge --------------------------------------------------------------------------------
    def wait_port_closed(self, timeout_s: float = 10.0) -> bool:
        """Block until the bridge has seen the client close the port (True) or the timeout."""
        with self._host_changed:
            return self._host_changed.wait_for(lambda: not self._host_open, timeout_s)

    def _set_host_open(self, value: bool) -> None:
        with self._host_changed:
            self._host_open = value
            self._host_changed.notify_all()

    def _bridge(self) -> None:
        host_open = False
        while self._running.is_set():
            with self._lock:
                fw, host = self._fw_master, self._host_master
            if fw is None or host is None:
                return
            poller = select.poll()
            poller.register(fw, select.POLLIN | (select.POLLOUT if self._to_fw else 0))
            poller.register(host, select.POLLIN | (select.POLLOUT if self._to_host else 0))
            events = dict(poller.poll(20))
            hup = bool(events.get(host, 0) & select.POLLHUP)
            if hup and host_open:
                host_open = False                   # the client closed the port
                self._to_host.clear()
                self._set_host_open(False)
            elif not hup and not host_open and self._probe_open(host):
                host_open = True
                self.opens += 1
                self._set_host_open(True)
                if self.reset_on_open:              # DTR: the board reboots
                    self.power_cycle(wait=False)
                    continue
            with self._lock:
                if fw != self._fw_master:
                    continue
                if events.get(fw, 0) & select.POLLIN:
                    data = self._read(fw)
                    if data:
                        self._from_fw += data
                        lines = _split_lines(self._from_fw)
                        self.lines_sent += lines
                        if any(line.startswith("Grbl ") for line in lines):
                            with self._host_changed:
                                self._banners += sum(line.startswith("Grbl ") for line in lines)
                                self._host_changed.notify_all()
                        if host_open:
                            self._to_host += data
                if host_open and events.get(host, 0) & select.POLLIN:
                    data = self._read(host)
                    if data:
                        self._note_host_bytes(data)
                        self._to_fw += data
                self._to_fw = self._write(fw, self._to_fw)
                if host_open:
                    self._to_host = self._write(host, self._to_host)
            if hup:
                time.sleep(0.005)                   # POLLHUP is level-triggered: don't spin

    @staticmethod
    def _probe_open(host: int) -> bool:
        p = select.poll()
        p.register(host, select.POLLIN)
        return not any(ev & select.POLLHUP for _, ev in p.poll(0))

    @staticmethod
    def _read(fd: int) -> bytes:
        try:
            return os.read(fd, 4096)
        except BlockingIOError:
            return b""
        except OSError as exc:
            if exc.errno == errno.EIO:
                return b""
            raise

    @staticmethod
    def _write(fd: int, pending: bytearray) -> bytearray:
        if not pending:
            return pending
        try:
            n = os.write(fd, bytes(pending[:4096]))
        except (BlockingIOError, InterruptedError):
            return pending
        except OSError:
            return bytearray()
        del pending[:n]
        if len(pending) > 1 << 20:                  # nobody reads: a UART drops bytes
            del pending[:-4096]
        return pending

    def _note_host_bytes(self, data: bytes) -> None:
        for b in data:
            if b in _REALTIME:
                if b != 0x3F:
                    self.realtime_received.append(bytes([b]))
            else:
                self._from_host.append(b)
        self.lines_received += [line.strip() for line in _split_lines(self._from_host) if line.strip()]

    # -- helpers for tests -------------------------------------------------------------------------
    def configure(self, settings: dict[int, float], timeout_s: float = 20.0) -> None:
        """Write ``$N=value`` settings through the port (nobody else may have it open), then
        power-cycle so the firmware boots with them, as an operator's setup tool would."""
        with serial.Serial(self.port, 115200, timeout=0.05) as port:
            deadline = time.monotonic() + timeout_s
            buf = bytearray()

            def next_line(poll: bool = False) -> str:
                while True:
                    lines = _split_lines(buf) if (b"\n" in buf or b"\r" in buf) else []
                    if lines:
                        rest = "\n".join(lines[1:])
                        if rest:
                            buf[:0] = rest.encode() + b"\n"
                        return lines[0]
                    if time.monotonic() > deadline:
                        raise TimeoutError(f"the GRBL firmware did not answer on {self.port}")
                    if poll:
                        port.write(b"?")           # bytes sent while the firmware boots are lost
                    buf.extend(port.read(256))

            while not next_line(poll=True).startswith("<"):   # boot messages (error:7 on a fresh EEPROM)
                pass
            for key, value in settings.items():
                text = f"${key}={value:g}" if isinstance(value, float) else f"${key}={value}"
                port.write(text.encode() + b"\n")
                while (answer := next_line()) != "ok":
                    if answer.startswith("error:"):
                        raise RuntimeError(f"the firmware refused {text!r}: {answer}")
        self.wait_port_closed()                 # the boot messages must not reach the next client
        self.power_cycle()
