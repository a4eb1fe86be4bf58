"""The two test tiers (tests/conftest.py: tier_of): every test gets exactly one, by rules, without a
marker of its own."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.conftest import REPO_ROOT

pytestmark = pytest.mark.full          # it runs pytest itself (a helper does: the rules see only test code)

PROBES = {
    "tests/test_optics.py::test_image_coordinate": "fast",                          # a unit test
    "tests/cli/test_main.py::test_unknown_command_is_usage_error": "fast",          # in-process CLI (cli_main)
    "tests/cli/test_main.py::test_version": "full",                                 # the CLI as a program
    "tests/gui/test_widgets.py::test_a_finished_job_shows_how_long_it_took": "full",            # qtbot
    "tests/rig/test_grbl_firmware.py::test_the_official_simulator_is_built_outside_the_repo_from_untouched_sources":
        "full",                                                                     # the firmware
    "tests/test_types.py::test_pyright_basic_finds_nothing_in_the_package": "full",           # a tool run
    "tests/processing/test_pipeline.py::test_chain_writes_16bit_views_and_records_them": "full",   # a whole stage
    "tests/rig/test_cia402_objects.py::test_units_are_not_written_to_a_moving_drive[modbus]": "full",  # drive emulator
    "tests/quality/test_disparity_words.py::test_stanford_chess_every_view_names_the_zero_plane": "full",  # ../shared
    "tests/cli/test_plan.py::test_json_has_the_keys_and_the_worked_check": "fast",  # parsing and messages in-process
}


def _collected(marker: str) -> set[str]:
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    files = sorted({p.split("::")[0] for p in PROBES})
    proc = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-n", "0", "--collect-only", "-q",
                           "-m", marker, *files], capture_output=True, text=True, timeout=200, env=env, cwd=REPO_ROOT)
    assert proc.returncode in (0, 5), proc.stdout[-2000:] + proc.stderr[-2000:]
    return {line.strip() for line in proc.stdout.splitlines() if "::" in line}


def test_each_test_is_in_one_tier_by_the_rules():
    fast, full = _collected("fast"), _collected("full")
    assert fast and full and not fast & full
    for nodeid, tier in PROBES.items():
        assert nodeid in (fast if tier == "fast" else full), (nodeid, tier)
