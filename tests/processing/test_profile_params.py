"""One description per parameter, the processing profile (lfstudio.dataset.profile.PARAMS): its
validator and loader, 'lfstudio process''s options and the Process dialog's editors all come from
the description on each step's field (choices, ranges, list lengths, tips)."""

from __future__ import annotations

import dataclasses
import re

import pytest

from lfstudio.cli.process import profile_option
from lfstudio.dataset.profile import PARAMS, STEP_TYPES, Profile
from lfstudio.errors import InputError


def test_every_setting_of_every_step_is_described():
    assert set(PARAMS) == {(s, f.name) for s, cls in STEP_TYPES.items() for f in dataclasses.fields(cls)}
    defaults = Profile()
    for (step, key), param in PARAMS.items():
        assert param.label and param.tip, (step, key)
        default = getattr(getattr(defaults, step), key)
        if isinstance(default, bool):
            assert param.flag, (step, key)
        elif isinstance(default, list):
            assert param.lengths and param.number is not None, (step, key)
        elif isinstance(default, (int, float)):
            assert param.number is not None and param.number.integer == isinstance(default, int), (step, key)
        param.check(key, default)                        # every default is valid


@pytest.mark.parametrize("step, key", [k for k, p in PARAMS.items() if p.number is not None or p.choices])
def test_the_validator_enforces_each_described_range_and_choice(step, key):
    param = PARAMS[(step, key)]
    if param.choices:
        bad = "nonsense"
    elif param.lengths:
        bad = [0.0] * (max(param.lengths) + 1)
    else:
        n = param.number
        bad = n.high * 2 + 1 if n.high is not None else n.low - 1
        if n.integer:
            bad = int(bad)
    with pytest.raises(InputError) as err:
        Profile.from_dict({step: {key: bad}}, "p.toml")
    assert str(err.value).startswith(f"p.toml: [{step}] {key}: ") and f"(valid: {param.valid()})" in str(err.value)
    profile = Profile()
    setattr(getattr(profile, step), key, bad)           # the validator of a profile built in code, too
    with pytest.raises(InputError, match=re.escape(f"[{step}] {key}")):
        profile.validate("p.toml")


def test_the_command_line_lists_every_setting_and_applies_it(run_cli, tmp_path):
    r = run_cli("process", "--help")
    assert r.returncode == 0
    for (step, key), param in PARAMS.items():
        assert profile_option(step, key) in r.stdout, (step, key)
    assert "--no-deflicker" in r.stdout and "{png,tiff}" in r.stdout
    out = tmp_path / "p.toml"
    r = run_cli("process", tmp_path, "--write-profile", out, "--resample-scale", "0.25", "--no-deflicker",
                "--lens-dist-coeffs", "0.1,0,0,0", "--debayer-demosaic", "AHD", "--color-patch-px", "7")
    assert r.returncode == 0, r.stderr
    written = Profile.load(out)
    assert (written.resample.scale, written.deflicker.enabled, written.lens.dist_coeffs, written.debayer.demosaic,
            written.color.patch_px) == (0.25, False, [0.1, 0.0, 0.0, 0.0], "AHD", 7)
    assert written.color == Profile().color.__class__(patch_px=7)          # nothing else changed


@pytest.mark.parametrize("args, words", [
    (("--resample-scale", "2"), "--resample-scale: 2 is out of range (valid: > 0 and ≤ 1)"),
    (("--lens-dist-coeffs", "1,2"), "--lens-dist-coeffs: has 2 numbers (valid: 4 or 5 or 8 numbers"),
    (("--output-format", "jpg"), "invalid choice: 'jpg'"),
    (("--deflicker-low", "0.95"), "--deflicker-low/high: need low < high"),
])
def test_a_bad_option_is_one_line_naming_it(run_cli, tmp_path, args, words):
    r = run_cli("process", tmp_path, "--write-profile", tmp_path / "p.toml", *args)
    assert r.returncode == 2 and words in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "p.toml").exists()
