"""Fixtures for the GRBL tests: the real GRBL 1.1h firmware (built from ../shared/vendor/grbl,
see tests/grbl_firmware.py) and our simulator, on pseudo-terminals."""

from __future__ import annotations

import pytest

from tests.grbl_firmware import FirmwareSimulator, FirmwareUnavailable, build_firmware_simulator


@pytest.fixture(scope="session")
def grbl_firmware_exe():
    """Path of the built firmware simulator; skips (with the reason) where it cannot be built."""
    try:
        return build_firmware_simulator()
    except FirmwareUnavailable as exc:
        pytest.skip(f"GRBL firmware simulator unavailable: {exc}")


@pytest.fixture
def grbl_firmware(grbl_firmware_exe, tmp_path):
    """``grbl_firmware(**options) -> FirmwareSimulator`` started on a fresh EEPROM (GRBL's
    defaults) in tmp_path; ``options`` go to :class:`FirmwareSimulator`. Closed after the test."""
    started: list[FirmwareSimulator] = []

    def start(**options) -> FirmwareSimulator:
        sim = FirmwareSimulator(grbl_firmware_exe, tmp_path / f"fw{len(started)}", **options)
        started.append(sim)
        sim.start()
        return sim

    yield start
    for sim in started:
        sim.close()
