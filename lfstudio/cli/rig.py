"""``lfstudio rig``: run rig commands in order on one connection and print the state after each."""

from __future__ import annotations

import argparse
import logging
import sys
import time

from lfstudio.cli.args import described_option, number_option, old_spelling
from lfstudio.errors import DeviceError, InputError
from lfstudio.numbers import TIMEOUT_S, Number

log = logging.getLogger(__name__)

HELP = "talk to the axis controller: status, home, unlock, origin, move X Y, jog DX DY (in order)"

#: command word -> names of its numeric arguments
#: a move or jog argument: any finite number of mm (the soft limits are checked against the rig profile)
POSITION_MM = Number("mm", -1e6, 1e6)
BAUD = Number("baud", 300, 4_000_000, integer=True)
COMMAND_ARGS = {"status": (), "home": (), "unlock": (), "origin": (), "reset": (), "units": (),
                "move": ("X", "Y"), "jog": ("DX", "DY")}


def add_arguments(p: argparse.ArgumentParser) -> None:
    from lfstudio.studio.scan_options import PARAMS as SCAN

    described_option(p, SCAN["port"], None, required=True)
    described_option(p, SCAN["rig_profile"], None, said="the reference gantry; for sim-dryve/sim-canopen the preset "
                                                         "dryve D1 pair")
    old_spelling(p, "--rig", "--rig-profile")
    p.add_argument("--baud", type=number_option(BAUD, "--baud"), default=115200, help="baud rate (default 115200)")
    described_option(p, SCAN["time_scale"], 1.0, said="1; only for a simulated controller")
    p.add_argument("--timeout-s", type=number_option(TIMEOUT_S, "--timeout-s"), default=3.0,
                   help="longest wait for any answer (default 3 s)")
    p.add_argument("--keep-drive-reference", action="store_true",
                   help="CiA 402 drives: accept the position the drives report as their reference without homing "
                        "(logged; the status says 'reference kept from the drive'). Without it a drive is homed "
                        "only when lfstudio homed it on this connection")
    p.add_argument("--rig-option", action="append", default=[], metavar="NAME=VALUE",
                   help="a connection option of the rig's kind, e.g. --rig-option poll_hz=100 (lfstudio doctor lists "
                        "each kind's options; --baud and --timeout-s are baudrate and timeout_s)")
    p.add_argument("commands", nargs=argparse.REMAINDER, metavar="COMMAND [ARGS]",
                   help="status | home | unlock | origin | reset | units | move X Y | jog DX DY  (mm; several in a "
                        "row). units (CiA 402 drives, stopped): write the rig profile's position units (60A8h) and "
                        "feed constant (6092h) to both drives")
    p.epilog = ("example: lfstudio rig --port sim home move 10 5 status. A port in use by another lfstudio "
                "process (a running scan, the window) is refused, naming it")


def parse_commands(words: list[str]) -> list[tuple[str, tuple[float, ...]]]:
    """``["home", "move", "10", "5"]`` -> ``[("home", ()), ("move", (10.0, 5.0))]``; InputError if malformed."""
    if not words:
        raise InputError("COMMAND", "no command given", " | ".join(COMMAND_ARGS))
    out: list[tuple[str, tuple[float, ...]]] = []
    i = 0
    while i < len(words):
        word = words[i].lower()
        if word not in COMMAND_ARGS:
            raise InputError("COMMAND", f"unknown command {words[i]!r}", ", ".join(COMMAND_ARGS))
        names = COMMAND_ARGS[word]
        values = words[i + 1:i + 1 + len(names)]
        if len(values) < len(names):
            raise InputError(word, f"needs {' '.join(names)} (mm)", f"{word} {' '.join(names)}")
        numbers = [POSITION_MM.parse(f"{word} {name}", text) for name, text in zip(names, values)]
        out.append((word, tuple(numbers)))
        i += 1 + len(names)
    return out


def describe(status) -> str:
    pos = ("x=? y=?" if status.position_mm is None
           else f"x={status.position_mm[0]:.3f} y={status.position_mm[1]:.3f} mm")
    reference = status.extra.get("reference") if isinstance(status.extra, dict) else None
    homed = ("reference kept from the drive" if reference == "kept" else "homed") if status.homed else "not homed"
    text = f"{status.state.value:<12} {pos}  {homed}"
    if status.message:
        text += f"  — {status.message}"
    power = status.extra.get("power_state") if isinstance(status.extra, dict) else None
    if isinstance(power, dict):                 # CiA 402 drives: power state and error code of each
        codes = status.extra.get("fault_code", {})
        text += "  [" + ", ".join(f"{axis}: {state.lower()} {codes.get(axis, '')}".rstrip()
                                  for axis, state in power.items()) + "]"
    return text


def _wait_idle(controller, timeout_s: float = 600.0):
    from lfstudio.rig.motion import RigState

    deadline = time.monotonic() + timeout_s
    status = controller.status()
    while status.state in (RigState.JOGGING, RigState.MOVING):
        if time.monotonic() > deadline:
            raise DeviceError("the jog did not end in time; motion stopped")
        time.sleep(0.05)
        status = controller.status()
    return status


def run(args: argparse.Namespace) -> int:
    from lfstudio.rig.profile import load_rig
    from lfstudio.rig.motion import ReportsProgress, check_target
    from lfstudio.studio.devices import RigSpec, implied_rig_profile, open_rig
    from lfstudio.studio.kinds import parse_options

    commands = parse_commands(args.commands)
    rig = load_rig(args.rig_profile or implied_rig_profile(args.port))     # a drive pair: named or refused
    for word, values in commands:           # a target outside the soft limits is refused before connecting
        if word == "move":
            check_target(rig, *values)
    drives_only = [w for w, _ in commands if w == "units"] + (["--keep-drive-reference"] if args.keep_drive_reference
                                                              else [])
    if drives_only and rig.driver != "cia402":
        raise InputError(drives_only[0], f"rig profile {rig.name!r} is a GRBL controller, not CiA 402 drives",
                         "leave it out")
    options: dict = {"baudrate": args.baud, "timeout_s": args.timeout_s}
    if args.keep_drive_reference:
        options["accept_reference"] = True
    options.update(parse_options(RigSpec.parse(args.port).info, args.rig_option, option="--rig-option"))
    link = open_rig(args.port, rig, doing="rig commands: " + " ".join(args.commands), time_scale=args.time_scale,
                    **options)
    controller = link.controller
    try:
        if link.simulator is not None:
            print(f"{link.describe()} (rig {rig.name!r})" if link.spec.drives else
                  f"simulated GRBL controller on {link.port} (rig {rig.name!r})", flush=True)
        for word, values in commands:
            if word == "status":
                status = controller.status()
            elif word == "home":
                reports = link.controller
                if isinstance(reports, ReportsProgress):     # a drive pair: a line as each drive is homed
                    reports.progress = lambda line: print(line, flush=True)
                controller.home()
                status = controller.status()
            elif word == "unlock":
                controller.unlock()
                status = controller.status()
            elif word == "reset":
                controller.reset()
                status = controller.status()
            elif word == "origin":
                controller.set_origin()
                status = controller.status()
            elif word == "units":
                for line in controller.write_units():
                    print(f"units: {line}", flush=True)
                status = controller.status()
            elif word == "move":
                status = controller.move_to(*values)
            else:  # jog
                controller.jog(*values)
                status = _wait_idle(controller)
            label = word + ("" if not values else " " + " ".join(f"{v:g}" for v in values))
            print(f"{label:<20} {describe(status)}", flush=True)
    except KeyboardInterrupt:
        # as 'lfstudio scan' does: feed hold, then (once the axes are at rest) a soft reset that drops
        # the rest of the move; a hold alone leaves it queued (a Cycle Start would finish it) and the
        # held controller answers no later connection
        print("lfstudio rig: Ctrl+C: stopping the rig", file=sys.stderr, flush=True)
        controller.stop()
        try:
            complete = getattr(controller, "complete_stop", None)
            complete() if complete is not None else controller.status()   # the hold, then the reset
        except Exception as exc:  # noqa: BLE001 - the interrupt is what the operator asked for
            log.warning("completing the stop after Ctrl+C: %s", exc)
            try:
                controller.reset()
            except Exception as reset_exc:  # noqa: BLE001
                log.warning("resetting the controller after Ctrl+C: %s", reset_exc)
        raise
    finally:
        link.close()
    return 0
