"""The rig contract runs the GRBL 1.1h firmware with the fixtures of the GRBL tests."""

from tests.rig.conftest import grbl_firmware, grbl_firmware_exe  # noqa: F401 - fixtures used by test_rigs.py
