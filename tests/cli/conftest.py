"""Fixtures the command-line tests share with other folders."""

from tests.faults.conftest import small_disk  # noqa: F401  (the fixture: a real small tmpfs)
