"""CANopen between processes (issue 38): ``lfstudio sim-drive --canopen udp_multicast`` serves the two
emulated drives as CANopen nodes on python-can's UDP multicast bus, and ``lfstudio rig`` / ``lfstudio
scan`` in other processes drive them over ``--port canopen:udp_multicast:1,2`` (SDO through
python-canopen, the real stacks at both ends).

The multicast frames stay inside a network namespace this test makes (``unshare -n``: only a loopback
interface, multicast routed to it), so nothing leaves the machine; the test skips where namespaces
cannot be made."""

from __future__ import annotations

import subprocess
import sys
from contextlib import ExitStack

import pytest

from lfstudio.dataset import Dataset
from tests.conftest import REPO_ROOT
from tests.netns import canopen_sim_drive, own_network_namespace
from tests.scankill import lfstudio_env

RIG = "dryve D1 gantry 4 m x 0.5 m"


@pytest.fixture
def own_network():
    with own_network_namespace() as prefix:
        yield prefix


def _lfstudio(prefix: list[str], *args, timeout: float = 180) -> subprocess.CompletedProcess:
    return subprocess.run([*prefix, sys.executable, "-m", "lfstudio", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, env=lfstudio_env(), cwd=REPO_ROOT)


@pytest.fixture
def canopen_drives(own_network):
    """``lfstudio sim-drive --canopen udp_multicast`` in its own process, inside the namespace."""
    with ExitStack() as stack:
        yield lambda *options: stack.enter_context(canopen_sim_drive(own_network, *options))


def test_rig_and_scan_in_other_processes_over_the_udp_multicast_bus(own_network, canopen_drives, tmp_path):
    word = canopen_drives()
    r = _lfstudio(own_network, "rig", "--port", word, "--rig-profile", RIG, "home", "move", "100", "50", "status")
    assert r.returncode == 0, r.stderr
    last = r.stdout.strip().splitlines()[-1]
    assert "x=100.000 y=50.000" in last and "homed" in last and "x: operation enabled 0000h" in last
    out = tmp_path / "ds"
    r = _lfstudio(own_network, "scan", "--port", word, "--rig-profile", RIG, "--camera", "sim", "--home", "--grid",
                  "3x2", "--spacing-mm", "4x6", "--sim-width-px", "96", "--time-scale", "0", "--out", out)
    assert r.returncode == 0, r.stderr
    assert "6 of 6 views captured" in r.stderr
    ds = Dataset.open(out)
    try:
        assert ds.manifest["devices"]["rig"]["port"] == word
        for v in ds.views:
            assert v["reported_mm"] == pytest.approx(v["commanded_mm"], abs=0.011)
    finally:
        ds.close()


def test_the_variety_over_canopen_in_another_process(own_network, canopen_drives):
    """Objects left out, other units, found enabled but never homed: over CANopen between processes."""
    word = canopen_drives("--leave-out", "605A,607D,603F,60F4,6085,606C", "--feed-constant", "70",
                          "--enabled-unhomed")
    r = _lfstudio(own_network, "rig", "--port", word, "--rig-profile", RIG, "status", "move", "30", "4")
    assert r.returncode == 1
    assert "60A8h" in r.stderr and "increments_per_mm = 100" in r.stderr and "Traceback" not in r.stderr
    assert "has no 605Ah" in r.stderr and "has no 606Ch" in r.stderr            # the fallbacks, said once each
    assert r.stderr.count("drive x (horizontal) at udp_multicast node 1 has no 605Ah") == 1
    r = _lfstudio(own_network, "rig", "--port", word, "--rig-profile", RIG, "units", "home", "move", "30", "4",
                  "status")
    assert r.returncode == 0, r.stderr
    assert "x=30.000 y=4.000" in r.stdout.strip().splitlines()[-1]


def test_a_fly_scan_in_another_process_over_the_udp_multicast_bus(own_network, canopen_drives, tmp_path):
    """#40: ``lfstudio scan --fly`` on CiA 402 drives served by ``sim-drive --canopen udp_multicast
    --touch-probe`` in another process: each row a profile position move at the row speed, the drives'
    touch probes latching the camera's exposure output (wired across the processes)."""
    word = canopen_drives("--time-scale", "0.5", "--touch-probe", "--seed", "5")
    out = tmp_path / "ds"
    r = _lfstudio(own_network, "scan", "--port", word, "--rig-profile", RIG, "--camera", "sim",
                  "--keep-drive-reference", "--fly", "--grid", "4x2", "--offset-mm", "-1950x-200", "--sim-width-px",
                  "64", "--time-scale", "0.5", "--exposure-s", "0.001", "--transfer-s", "0.05", "--out", out)
    assert r.returncode == 0, r.stderr
    assert "fly scan: rows at" in r.stderr
    ds = Dataset.open(out)
    try:
        assert ds.manifest["acquisition"]["mode"] == "fly" and ds.status_counts()["done"] == 8
        sources = [(v.get("fly") or {}).get("source") for v in ds.views]
        assert "touch probe" in sources, sources
    finally:
        ds.close()
