"""One description per parameter (lfstudio.numbers.Param on the dataclass field): the scene plan's
validator, its file loader and the command line's options all come from the same description."""

from __future__ import annotations

import dataclasses

import pytest

from lfstudio.errors import InputError
from lfstudio.numbers import PARAM, Number, Param, check_described, described
from lfstudio.planning.scene_plan import CLI_OPTION, PARAMS, ScenePlan


def test_every_field_of_the_plan_is_described_with_an_option_label_and_tip():
    names = [f.name for f in dataclasses.fields(ScenePlan)]
    assert list(PARAMS) == names
    for name, param in PARAMS.items():
        assert param.label and param.tip and param.option.startswith("--") and param.metavar and param.group, name
    assert CLI_OPTION["grid_columns"] == CLI_OPTION["grid_rows"] == "--grid"
    assert CLI_OPTION["target_parallax_fraction"] == "--parallax-fraction"


@pytest.mark.parametrize("name", [n for n, p in PARAMS.items() if p.number is not None])
def test_the_validator_enforces_each_described_range(name):
    param = PARAMS[name]
    number = param.number
    bad = number.high * 2 + 1
    value = (bad, bad) if param.pair else bad
    plan = ScenePlan().replace(**{name: value})
    with pytest.raises(InputError) as err:
        plan.validate(check_travel=False)
    assert err.value.field == name and number.valid() in str(err.value)


def test_the_command_line_lists_every_described_option(run_cli):
    r = run_cli("plan", "--help")
    assert r.returncode == 0
    for param in PARAMS.values():
        assert param.option in r.stdout
    assert "Columns × rows of camera positions" in r.stdout        # the tip is the help


def test_param_checks_pairs_optional_values_and_text():
    @dataclasses.dataclass(frozen=True)
    class Thing:
        size: tuple = described((1.0, 2.0), number=Number("mm", 0, 10, low_open=True), pair=True, label="Size")
        pitch: float | None = described(None, number=Number("µm", 0.1, 100), optional="auto", label="Pitch")
        name: str = described("x", label="Name")

    check_described(Thing())
    assert isinstance(dataclasses.fields(Thing)[0].metadata[PARAM], Param)
    with pytest.raises(InputError, match=r"size: 0 mm is out of range \(valid: > 0 mm and ≤ 10 mm\)"):
        check_described(Thing(size=(0.0, 2.0)))
    with pytest.raises(InputError, match="size: 3.0 is not a pair"):
        check_described(Thing(size=3.0))
    with pytest.raises(InputError, match="pitch: 0.05 µm is out of range"):
        check_described(Thing(pitch=0.05))
    with pytest.raises(InputError, match="name: 5 is not text"):
        check_described(Thing(name=5))
