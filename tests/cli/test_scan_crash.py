"""A real ``kill -9`` of a scanning ``lfstudio scan`` process at a random moment, then ``--resume``:
every view exactly once, no partial or stray file, a valid manifest."""

from __future__ import annotations

import os
import random

import pytest

from lfstudio.dataset import Dataset
from lfstudio.dataset.paths import view_stem
from lfstudio.dataset.store import temporary_files
from tests.scankill import kill_9_after

ARGS = ["--port", "sim", "--camera", "sim", "--grid", "4x3", "--spacing-mm", "4x6", "--time-scale", "0.02",
        "--sim-width-px", "96"]


#: the GRBL simulator, and the emulated CiA 402 drives (dryve D1 over Modbus TCP)
RIGS = {"sim": [], "sim-dryve": ["--port", "sim-dryve", "--rig-profile", "dryve D1 gantry 4 m x 0.5 m"]}


@pytest.mark.parametrize("rig, seed", [("sim", 1), ("sim", 2), ("sim-dryve", 3)])
def test_kill_9_at_a_random_moment_then_resume(run_cli, tmp_path, rig, seed):
    rng = random.Random(seed * 7919 + os.getpid())
    out = tmp_path / "ds"
    ARGS = [*globals()["ARGS"], *RIGS[rig]]     # noqa: N806 - the module's arguments on this rig
    # pick the moment: after a random number of finished views, plus a random fraction of a view
    kill_9_after(["scan", *ARGS, "--out", out], out, rng.randint(0, 9), rng, jitter_s=0.08)
    assert (out / "dataset.json").is_file()

    crashed = Dataset.open(out)            # valid as it is, journal replayed
    before = {(v["row"], v["column"]): v["sha256"] for v in crashed.views if v["status"] == "done"}
    crashed.close()

    r = run_cli("scan", *ARGS, "--out", out, "--resume", timeout=120)
    assert r.returncode == 0, r.stderr
    assert f"{len(before)} done, {12 - len(before)} to capture" in r.stderr or len(before) == 12

    ds = Dataset.open(out)
    assert ds.status_counts()["done"] == 12
    assert ds.verify_files() == []
    assert list(temporary_files(out)) == []
    # views captured before the crash were not captured again
    for cell, sha in before.items():
        assert ds.view(*cell)["sha256"] == sha
    expected_raw = {f"{view_stem(r_, c)}{suffix}" for r_ in range(3) for c in range(4)
                    for suffix in (".dng", ".jpg", ".truth.json")}
    assert {p.name for p in (out / "raw").iterdir()} == expected_raw
    assert {p.name for p in (out / "thumbs").iterdir()} == {f"{view_stem(r_, c)}.jpg" for r_ in range(3)
                                                            for c in range(4)}
