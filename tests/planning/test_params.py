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


def test_param_checks_choices_flags_lists_and_the_one_loader():
    from lfstudio.numbers import load_described

    @dataclasses.dataclass(frozen=True)
    class Thing:
        size: float = described(dataclasses.MISSING, number=Number("mm", 0, 10), label="Size")
        mode: str = described("a", choices=("a", "b"), label="Mode")
        method: int = described(17, number=Number("", 0, 99, integer=True), choices=(17, 18), label="Method")
        on: bool = described(True, flag=True, label="On")
        coeffs: list = described([0.0, 0.0], number=Number("", -1, 1), lengths=(2, 3), label="Coefficients")

    assert Thing(size=1).coeffs is not Thing(size=1).coeffs                 # a list default is copied
    assert load_described(Thing, {"size": 2, "mode": "b", "method": 18.0, "coeffs": [0.5, 0, 1]}) == \
        {"size": 2.0, "mode": "b", "method": 18, "coeffs": [0.5, 0.0, 1.0]}
    for data, words in [({"size": 1, "mode": "c"}, r"mode: 'c' is not one of the choices \(valid: a, b\)"),
                        ({"size": 1, "method": 1}, r"method: 1 is not one of the choices \(valid: 17, 18\)"),
                        ({"size": 1, "on": 1}, r"on: 1 is not true or false"),
                        ({"size": 1, "coeffs": [0]}, r"coeffs: has 1 numbers \(valid: 2 or 3 numbers, each -1 … 1\)"),
                        ({"size": 1, "coeffs": [0, 2]}, r"coeffs: 2 is out of range"),
                        ({"size": 1, "colour": 1}, r"colour: unknown setting \(valid: size, mode"),
                        ({}, r"size: missing \(valid: 0 … 10 mm\)"),
                        ([], r"is not a table")]:
        with pytest.raises(InputError, match=words):
            load_described(Thing, data)
