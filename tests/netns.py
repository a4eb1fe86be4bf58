"""A network namespace of the test's own, with only a loopback interface and multicast routed to it
(``unshare -n``), for python-can's UDP multicast bus between processes: nothing leaves the machine."""

from __future__ import annotations

import shutil
import subprocess
from contextlib import contextmanager
from typing import Iterator

import pytest

SETUP = "ip link set lo up && ip link set lo multicast on && ip route add 224.0.0.0/4 dev lo && echo ready && " \
        "exec sleep 600"


@contextmanager
def own_network_namespace() -> Iterator[list[str]]:
    """Yields the command prefix that runs a program inside the namespace; skips the test where no
    namespace can be made (no unshare/nsenter/ip, or not allowed)."""
    if not (shutil.which("unshare") and shutil.which("nsenter") and shutil.which("ip")):
        pytest.skip("unshare, nsenter or ip missing: no network namespace for the multicast bus")
    holder = subprocess.Popen(["unshare", "-n", "sh", "-c", SETUP], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    line = holder.stdout.readline().strip() if holder.stdout else ""
    if line != "ready":
        holder.kill()
        _, err = holder.communicate()
        pytest.skip(f"no network namespace here ({err.strip() or 'unshare failed'})")
    try:
        yield ["nsenter", "-t", str(holder.pid), "-n", "--"]
    finally:
        holder.kill()
        holder.communicate()


@contextmanager
def canopen_sim_drive(prefix: list[str], *options: str) -> Iterator[str]:
    """``lfstudio sim-drive --canopen udp_multicast`` in its own process inside the namespace: yields
    its device word."""
    import sys

    from tests.conftest import REPO_ROOT
    from tests.scankill import lfstudio_env

    proc = subprocess.Popen([*prefix, sys.executable, "-m", "lfstudio", "sim-drive", "--canopen", "udp_multicast",
                             "--time-scale", "0", *options], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=lfstudio_env(), cwd=REPO_ROOT)
    try:
        word = proc.stdout.readline().strip() if proc.stdout else ""
        assert word == "canopen:udp_multicast:1,2", proc.stderr.read() if proc.poll() is not None else word
        yield word
    finally:
        proc.terminate()
        try:
            proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
