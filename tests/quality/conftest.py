"""Virtual-studio datasets with injected faults for the quality check (rendered once per session)."""

from __future__ import annotations

import shutil

import pytest

#: the grid the fault tests render: 5 x 5 views, 640 px wide, the demo orientation error
FAULT_GRID = dict(columns=5, rows=5, spacing_mm=(4.0, 6.0), width_px=640, fmt="png",
                  rotation_deg=(1.0, -1.5, 0.7), seed=7)


@pytest.fixture(scope="session")
def _quality_cache(tmp_path_factory):
    cache: dict = {}

    def get(name: str, **overrides):
        from lfstudio.sim.virtual_dataset import make_virtual_dataset

        if name not in cache:
            root = tmp_path_factory.mktemp(f"quality_{name}") / "dataset"
            make_virtual_dataset(root, **{**FAULT_GRID, **overrides})
            cache[name] = root
        return cache[name]

    return get


@pytest.fixture
def quality_dataset(_quality_cache, tmp_path):
    """``quality_dataset(name, **make_virtual_dataset overrides) -> Dataset``: a fresh copy in tmp_path of
    the 5 x 5 grid (``name`` keys the session cache: same name, same overrides)."""
    from lfstudio.dataset import Dataset

    def make(name: str = "clean", **overrides):
        dst = tmp_path / name
        shutil.copytree(_quality_cache(name, **overrides), dst)
        return Dataset.open(dst)

    return make
