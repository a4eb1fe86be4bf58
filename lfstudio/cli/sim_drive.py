"""``lfstudio sim-drive``: two emulated CiA 402 drives (igus dryve D1 gateway telegrams over Modbus
TCP, one port per axis on 127.0.0.1) until Ctrl-C."""

from __future__ import annotations

import argparse

from lfstudio.cli.args import described_option, old_spelling
from lfstudio.cli.serving import serve_until_stopped
from lfstudio.errors import InputError
from lfstudio.rig.profile import DEFAULT_DRIVE_RIG

HELP = "start two emulated CiA 402 axis drives (dryve D1, Modbus TCP on 127.0.0.1) and print their device word"


def _ports(text: str) -> tuple[int, int]:
    parts = text.split(",")
    try:
        ports = tuple(int(p) for p in parts)
    except ValueError:
        ports = ()
    if len(ports) != 2 or not all(1 <= p <= 65535 for p in ports) or ports[0] == ports[1]:
        raise argparse.ArgumentTypeError(f"{text!r}: two different TCP ports, horizontal first (e.g. 5020,5021)")
    return ports[0], ports[1]


def add_arguments(p: argparse.ArgumentParser) -> None:
    from lfstudio.studio.scan_options import PARAMS as SCAN

    described_option(p, SCAN["rig_profile"], None, said=f"{DEFAULT_DRIVE_RIG!r}; a CiA 402 profile")
    old_spelling(p, "--rig", "--rig-profile")
    p.add_argument("--ports", type=_ports, default=(0, 0), metavar="P1,P2",
                   help="TCP ports of the horizontal and vertical drive (default: any free ports)")
    described_option(p, SCAN["time_scale"], 1.0)
    described_option(p, SCAN["seed"], 0, said="0; it sets the carriage's position at power-up")
    p.epilog = ("The drives listen on 127.0.0.1 only. Connect with --port dryve:127.0.0.1:P1,127.0.0.1:P2 "
                "(the first line printed); the simulated camera (--camera sim) follows them.")


def run(args: argparse.Namespace) -> int:
    from lfstudio.rig.profile import load_rig
    from lfstudio.studio.simulated import serve_sim_drive

    rig = load_rig(args.rig_profile or DEFAULT_DRIVE_RIG)
    if rig.driver != "cia402":
        raise InputError("--rig-profile", f"rig profile {rig.name!r} is for a GRBL controller, not CiA 402 drives",
                         f"a profile with driver = \"cia402\", e.g. {DEFAULT_DRIVE_RIG!r}")
    try:
        emulator, truth = serve_sim_drive(rig, time_scale=args.time_scale, seed=args.seed, ports=args.ports)
    except OSError as exc:
        raise InputError("--ports", f"cannot listen on 127.0.0.1 ({exc.strerror or exc})",
                         "free TCP ports, or leave --ports out") from None
    return serve_until_stopped(
        emulator.word,
        f"two emulated CiA 402 drives (dryve D1 Modbus TCP gateway) for rig {rig.name!r}; connect with\n"
        f"  lfstudio rig --port {emulator.word} --rig-profile '{rig.name}' home status\n"
        f"  lfstudio scan --port {emulator.word} --rig-profile '{rig.name}' --home --camera sim ...\n"
        "Ctrl-C stops them.", emulator, truth, "emulated drives")
