"""A real ``kill -9`` of a bracketed ``lfstudio scan`` at a random moment (between or inside a view's
frames), then ``--resume``: every view done exactly once with all its frames, the views done before the
crash kept as they were, an unfinished view's frames taken again whole, no stray file."""

from __future__ import annotations

import os
import random

import pytest

from lfstudio.dataset import Dataset
from lfstudio.dataset.paths import view_stem
from lfstudio.dataset.store import temporary_files
from tests.scankill import kill_9_after

ARGS = ["--port", "sim", "--camera", "sim", "--grid", "3x2", "--spacing-mm", "4x6", "--time-scale", "0.02",
        "--sim-width-px", "96", "--bracket", "-1,0,+1"]


@pytest.mark.parametrize("seed", [1, 2])
def test_kill_9_inside_a_bracket_then_resume(run_cli, tmp_path, seed):
    rng = random.Random(seed * 7919 + os.getpid())
    out = tmp_path / "ds"
    # the journal has a line per frame: views and frames between
    kill_9_after(["scan", *ARGS, "--out", out], out, rng.randint(1, 14), rng, jitter_s=0.08)
    assert (out / "dataset.json").is_file()

    crashed = Dataset.open(out)
    before = {(v["row"], v["column"]): [f["sha256"] for f in v["frames"]] for v in crashed.views
              if v["status"] == "done"}
    assert all(len(shas) == 3 for shas in before.values())       # done only with every frame
    crashed.close()

    r = run_cli("scan", "--out", out, "--resume", "--time-scale", "0.02", timeout=120)
    assert r.returncode == 0, r.stderr
    ds = Dataset.open(out)
    assert ds.status_counts()["done"] == 6 and ds.verify_files() == []
    assert list(temporary_files(out)) == []
    for cell, shas in before.items():                              # not captured again
        assert [f["sha256"] for f in ds.view(*cell)["frames"]] == shas
    for v in ds.views:
        assert [f["index"] for f in v["frames"]] == [0, 1, 2]
        assert [f["exposure_s"] for f in v["frames"]] == pytest.approx([0.25, 0.5, 1.0])
    expected = {f"{view_stem(r_, c)}.f{k}{suffix}" for r_ in range(2) for c in range(3) for k in range(3)
                for suffix in (".dng", ".jpg", ".truth.json")}
    assert {p.name for p in (out / "raw").iterdir()} == expected
