"""tools/setup-env.sh: the Qt system-library check and its apt step, run by real bash.

The script runs as root here, so every test points apt at a private state folder (APT_CONFIG)
whose locks this test process holds: whatever the script decides, the real apt-get it calls can
never change the machine; it meets "another apt's lock" exactly as it would on a busy system.
`ldconfig` on PATH prints this machine's real linker cache (optionally minus one library, or
followed by many more entries like a machine with a big cache), so the format is ldconfig's own.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "tools" / "setup-env.sh"
QT_LIBS = ("libEGL.so.1", "libGL.so.1", "libfontconfig.so.1", "libxkbcommon.so.0",
           "libdbus-1.so.3", "libglib-2.0.so.0")

pytestmark = [
    pytest.mark.skipif(os.geteuid() != 0, reason="the apt step runs only as root"),
    pytest.mark.skipif(shutil.which("apt-get") is None, reason="needs Debian's apt-get"),
]


def _real_cache() -> str:
    ldconfig = shutil.which("ldconfig") or "/sbin/ldconfig"
    text = subprocess.run([ldconfig, "-p"], capture_output=True, text=True, check=True).stdout
    missing = [lib for lib in QT_LIBS if f"\t{lib} (" not in text]
    if missing:
        pytest.skip(f"this machine lacks {missing}")
    return text


@pytest.fixture
def held_apt(tmp_path):
    """APT_CONFIG for a private apt state whose list and dpkg locks this process holds."""
    base = tmp_path / "apt"
    for sub in ("lists/partial", "dpkg", "cache/archives/partial"):
        (base / sub).mkdir(parents=True)
    (base / "dpkg" / "status").touch()
    conf = base / "apt.conf"
    conf.write_text(f'Dir::State::Lists "{base}/lists";\n'
                    f'Dir::State::status "{base}/dpkg/status";\n'
                    f'Dir::Cache "{base}/cache";\n')
    fds = []
    for lock in ("lists/lock", "dpkg/lock-frontend", "dpkg/lock"):
        fd = os.open(base / lock, os.O_RDWR | os.O_CREAT)
        fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        fds.append(fd)
    yield conf, base
    for fd in fds:
        os.close(fd)


def _run(tmp_path, apt_conf, cache_text: str) -> subprocess.CompletedProcess:
    """Source setup-env.sh with `ldconfig` printing cache_text and an installed venv stand-in."""
    shims = tmp_path / "shims"
    shims.mkdir()
    (tmp_path / "cache.txt").write_text(cache_text)
    ldconfig = shims / "ldconfig"
    ldconfig.write_text(f"#!/bin/sh\nexec cat '{tmp_path / 'cache.txt'}'\n")
    ldconfig.chmod(0o755)
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    (venv / "bin" / "python").symlink_to(sys.executable)
    stamp = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    (venv / ".lfstudio-installed").write_text(stamp + "\n")
    env = dict(os.environ, PATH=f"{shims}:{os.environ['PATH']}", LFSTUDIO_VENV=str(venv),
               PYTHON=sys.executable, APT_CONFIG=str(apt_conf))
    return subprocess.run(["bash", "-c", f"source '{SCRIPT}' && echo \"PY=$LFSTUDIO_PY\""],
                          env=env, capture_output=True, text=True, cwd=tmp_path, timeout=120)


def test_present_libraries_are_found_when_the_cache_is_long(tmp_path, held_apt):
    """A big linker cache (4 MB, as on a machine with many libraries): a reader that stops at
    its match leaves ldconfig writing into a closed pipe; present libraries must still count."""
    apt_conf, _ = held_apt
    filler = "".join(f"\tlibother{i}.so.0 (libc6,x86-64) => /usr/lib/libother{i}.so.0\n"
                     for i in range(60000))
    result = _run(tmp_path, apt_conf, _real_cache() + filler)
    assert result.returncode == 0, result.stderr
    # nothing to install, nothing to warn about: apt-get is never started
    assert result.stdout == f"PY={tmp_path / 'venv' / 'bin' / 'python'}\n"
    assert result.stderr == ""


def test_a_library_name_inside_another_is_not_taken_for_it(tmp_path, held_apt):
    """Only libGL.so.10 and libEGL.so.1 present: libGL.so.1 is still missing."""
    apt_conf, _ = held_apt
    cache = "".join(line + "\n" for line in _real_cache().splitlines()
                    if not line.startswith("\tlibGL.so.1 "))
    cache += "\tlibGL.so.10 (libc6,x86-64) => /usr/lib/libGL.so.10\n"
    result = _run(tmp_path, apt_conf, cache)
    assert "missing: libgl1." in result.stdout
    assert "libegl1" not in result.stdout + result.stderr


def test_apt_step_says_what_it_did_and_that_another_apt_holds_the_lock(tmp_path, held_apt):
    apt_conf, base = held_apt
    cache = "".join(line + "\n" for line in _real_cache().splitlines()
                    if not line.startswith("\tlibxkbcommon.so.0 "))
    result = _run(tmp_path, apt_conf, cache)
    # What it is doing, before apt-get runs:
    assert "Qt needs system libraries that are missing: libxkbcommon0" in result.stdout
    assert "refresh the package lists: apt-get update" in result.stdout
    # Why it failed, in one line naming the step, the cause and the lock, then what to do:
    err = result.stderr
    assert "'apt-get update -qq' (refresh the package lists) failed because another package " \
           "manager is running" in err
    assert f"{base}/lists/lock" in err and f"held by process {os.getpid()}" in err
    assert "Wait for it to finish, then run this again" in err
    assert "apt-get install libxkbcommon0" in err
    # ... and the rest of the set-up still happens (the command line needs no Qt libraries).
    assert result.returncode == 0
    assert "PY=" in result.stdout
