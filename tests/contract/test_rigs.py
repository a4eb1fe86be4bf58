"""One contract every rig kind keeps: connect, its record, a reference (home or origin), a move that arrives,
STOP mid-move (the carriage stops short of the target, the controller answers after it), a target outside
the soft limits refused in one line before anything moves, disconnect, and a second lfstudio process
refused while one holds the rig.

Each kind on its real stack: the GRBL simulator on a pseudo-terminal, the GRBL 1.1h firmware (the
official simulator built from ../shared/vendor/grbl; skips without it), the CiA 402 driver against the
emulated igus dryve D1 pair over Modbus TCP on 127.0.0.1 and over CANopen on python-can's virtual bus.
A built-in rig kind without a case here (or a case of the kind that simulates it) fails
:func:`test_every_registered_rig_kind_has_a_contract_case`. Installed plugins' kinds run it too when
named in ``LFSTUDIO_CONTRACT_RIGS`` (tests/studio/test_plugins.py does so for the documented example)."""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

import pytest

from lfstudio.errors import InputError, LfError
from lfstudio.rig.motion import MotionController, RigConfig, RigState
from lfstudio.rig.profile import load_rig
from lfstudio.studio.devices import RigLink, open_rig

GANTRY = load_rig()
DRIVES = load_rig("dryve D1 gantry 4 m x 0.5 m")


@dataclass
class Case:
    word: str
    config: RigConfig
    home: bool                      # home (limit switches) or take the current position as the origin
    options: dict[str, Any]
    shared_word: Callable[[RigLink], str] | None = None   # the word another process would open it by


def _sim(request) -> Case:
    return Case("sim", GANTRY, True, {"time_scale": 0.05, "timeout_s": 3.0})


def _firmware(request) -> Case:
    start = request.getfixturevalue("grbl_firmware")
    fw = start()
    return Case(fw.port, GANTRY, False, {"timeout_s": 3.0}, shared_word=lambda link: link.spec.text)


def _dryve(request) -> Case:
    return Case("sim-dryve", DRIVES, True, {"time_scale": 0.05, "timeout_s": 0.5},
                shared_word=lambda link: link.simulator.word)


def _canopen(request) -> Case:
    return Case("sim-canopen", DRIVES, True, {"time_scale": 0.05, "timeout_s": 0.5})


CASES = {"grbl-sim": _sim, "grbl-firmware": _firmware, "cia402-modbus": _dryve, "cia402-canopen": _canopen}
#: the rig kind each case opens (a case of "sim-dryve" also covers "dryve": the same driver and links)
KIND_OF = {"grbl-sim": "sim", "grbl-firmware": "grbl", "cia402-modbus": "sim-dryve", "cia402-canopen": "sim-canopen"}
#: built-in kinds without a case: the instant rig takes no time (nothing to stop mid-move; tests only)
NO_CASE = {"instant"}


def _installed(spec: str) -> Callable[[Any], Case]:
    """A plugin's kind from ``LFSTUDIO_CONTRACT_RIGS``: ``WORD|NAME=VALUE,...`` (its word, its options)."""
    word, _, items = spec.partition("|")
    return lambda request: Case(word.strip(), GANTRY, True, {
        k.strip(): float(v) for k, _, v in (item.partition("=") for item in items.split(",") if item)},
        shared_word=lambda link: link.spec.text)


#: installed plugins' kinds run the same contract: LFSTUDIO_CONTRACT_RIGS="sled:bench|speed_mm_s=1000;..."
for _spec in filter(None, os.environ.get("LFSTUDIO_CONTRACT_RIGS", "").split(";")):
    CASES[f"plugin:{_spec.partition('|')[0]}"] = _installed(_spec)


def test_every_registered_rig_kind_has_a_contract_case():
    from lfstudio.studio.kinds import BUILT_IN, rig_kinds

    kinds = rig_kinds()
    covered = set(KIND_OF.values()) | {kinds[k].simulates for k in KIND_OF.values()} | NO_CASE
    missing = [name for name, kind in kinds.items() if kind.origin == BUILT_IN and name not in covered]
    assert not missing, f"built-in rig kinds without a contract case: {missing}"


@pytest.fixture(params=sorted(CASES))
def rig(request):
    case = CASES[request.param](request)
    link = open_rig(case.word, case.config, doing="the rig contract", **case.options)
    try:
        yield case, link
    finally:
        link.close()


def _referenced(case: Case, controller: Any) -> None:
    if case.home:
        controller.home()
    else:
        controller.set_origin()


def test_connect_reference_move_and_record(rig):
    case, link = rig
    controller = link.controller
    assert isinstance(controller, MotionController)
    assert controller.status().state is not RigState.DISCONNECTED
    record = link.record()
    assert record["kind"] and record["profile"] == case.config.name
    _referenced(case, controller)
    status = controller.move_to(40.0, 20.0)
    assert status.position_mm == pytest.approx((40.0, 20.0), abs=0.05)
    assert controller.status().state is RigState.IDLE


def test_stop_mid_move_stops_short_of_the_target(rig):
    case, link = rig
    controller = link.controller
    _referenced(case, controller)
    target = (min(case.config.horizontal.soft_max_mm, 3000.0), 20.0)
    outcome: dict[str, Any] = {}

    def move() -> None:
        try:
            outcome["status"] = controller.move_to(*target)
        except LfError as exc:
            outcome["error"] = exc

    mover = threading.Thread(target=move, daemon=True)
    mover.start()
    deadline = time.monotonic() + 30
    while controller.status().position_mm[0] < 60.0:        # it is on its way (polls the real status)
        assert time.monotonic() < deadline and mover.is_alive(), outcome
    controller.stop()
    mover.join(30)
    assert not mover.is_alive()
    deadline = time.monotonic() + 30
    while controller.status().state is RigState.MOVING:
        assert time.monotonic() < deadline
    x, _ = controller.status().position_mm
    assert x < target[0] - 100.0                               # stopped well short of the target


def test_a_target_outside_the_soft_limits_is_refused_before_anything_moves(rig):
    case, link = rig
    controller = link.controller
    _referenced(case, controller)
    before = controller.status().position_mm
    with pytest.raises(InputError) as err:
        controller.move_to(case.config.horizontal.soft_max_mm + 50.0, 10.0)
    assert "\n" not in str(err.value)
    assert controller.status().position_mm == pytest.approx(before, abs=0.01)


def test_disconnect_then_commands_are_refused(rig):
    case, link = rig
    controller = link.controller
    controller.disconnect()
    with pytest.raises(LfError) as err:
        controller.move_to(10.0, 10.0)
    assert "\n" not in str(err.value)


def test_a_second_process_is_refused_while_one_holds_the_rig(rig, run_cli):
    case, link = rig
    if case.shared_word is None:
        pytest.skip(f"{case.word}: each process starts its own simulated controller")
    word = case.shared_word(link)
    r = run_cli("rig", "--port", word, "--rig-profile", case.config.name, "status", timeout=60)
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert "is in use by" in r.stderr and "the rig contract" in r.stderr, r.stderr


def test_a_flying_controller_flies_reports_arrives_and_stops(rig):
    """Fly scanning's contract (lfstudio.rig.motion.FlyingController, #40), on every kind that offers it:
    fly_to returns while the carriage moves, report() gives time-stamped positions that advance along
    the move, wait_arrival ends at the target; a fly target outside the soft limits is refused before
    anything moves; STOP ends wait_arrival short of the target."""
    from lfstudio.rig.motion import FlyingController

    case, link = rig
    controller = link.controller
    if not isinstance(controller, FlyingController):
        pytest.skip(f"{case.word}: not a FlyingController")
    _referenced(case, controller)
    controller.move_to(20.0, 20.0)
    controller.fly_to(300.0, 20.0, 50.0)
    reports = [controller.report()]
    while reports[-1].x_mm < 150.0:                          # under way: reports advance with their time
        reports.append(controller.report())
        assert reports[-1].t_s > reports[-2].t_s and reports[-1].x_mm >= reports[-2].x_mm - 0.011
        assert reports[-1].uncertainty_s >= 0 and len(reports) < 1_000_000
    status = controller.wait_arrival(300.0, 20.0, 60.0)
    assert status.position_mm == pytest.approx((300.0, 20.0), abs=0.05)
    with pytest.raises(InputError) as err:
        controller.fly_to(case.config.horizontal.soft_max_mm + 50.0, 20.0, 50.0)
    assert "\n" not in str(err.value)
    assert controller.status().position_mm == pytest.approx((300.0, 20.0), abs=0.05)
    controller.fly_to(20.0, 20.0, 10.0)                        # slowly: STOP comes long before the end
    while controller.report().x_mm > 290.0:
        pass
    outcome: dict[str, Any] = {}

    def wait() -> None:
        try:
            outcome["status"] = controller.wait_arrival(20.0, 20.0, 60.0)
        except LfError as exc:
            outcome["error"] = exc

    waiter = threading.Thread(target=wait, daemon=True)
    waiter.start()
    controller.stop()
    waiter.join(30)
    assert not waiter.is_alive() and "error" in outcome, outcome
    deadline = time.monotonic() + 30
    while controller.status().state is RigState.MOVING:
        assert time.monotonic() < deadline
    assert controller.status().position_mm[0] > 40.0           # stopped well short of the target
