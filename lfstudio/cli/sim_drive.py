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


def _objects(text: str) -> tuple[int, ...]:
    from lfstudio.studio.simulated import LEAVE_OUT_ALLOWED

    out = []
    for word in text.split(","):
        word = word.strip().upper().removesuffix("H")
        try:
            index = int(word, 16)
        except ValueError:
            index = -1
        if index not in LEAVE_OUT_ALLOWED:
            raise argparse.ArgumentTypeError(
                f"{text!r}: {word or 'nothing'} is not an object of the emulated drive (hex index, comma-separated: "
                f"{', '.join(f'{i:04X}' for i in LEAVE_OUT_ALLOWED)})")
        out.append(index)
    return tuple(out)


def _feed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= 0xFFFFFFFF:
        raise argparse.ArgumentTypeError(f"{text!r}: the feed constant 6092h:01 is a whole number of position units "
                                         "per revolution, 1 … 4294967295 (7000: 0.01 mm on a 70 mm/rev belt)")
    return value


def _delay(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0.0 <= value <= 10_000.0:
        raise argparse.ArgumentTypeError(f"{text!r}: the answer delay is 0 … 10000 ms")
    return value


def add_arguments(p: argparse.ArgumentParser) -> None:
    from lfstudio.studio.scan_options import PARAMS as SCAN

    described_option(p, SCAN["rig_profile"], None, said=f"{DEFAULT_DRIVE_RIG!r}; a CiA 402 profile")
    old_spelling(p, "--rig", "--rig-profile")
    p.add_argument("--ports", type=_ports, default=(0, 0), metavar="P1,P2",
                   help="TCP ports of the horizontal and vertical drive (default: any free ports)")
    described_option(p, SCAN["time_scale"], 1.0)
    described_option(p, SCAN["seed"], 0, said="0; it sets the carriage's position at power-up")
    p.add_argument("--leave-out", type=_objects, default=(), metavar="INDEX,...",
                   help="objects both drives lack (hex, e.g. 605A,607D,6085): the variety of real CiA 402 drives")
    p.add_argument("--feed-constant", type=_feed, default=None, metavar="N",
                   help="6092h:01 of both drives at power-up: position units per motor revolution (default: the "
                        "rig profile's increments_per_mm x feed_mm_per_rev, 7000; 70 makes them count mm); 60A8h "
                        "follows when the units are a power of ten of a mm")
    p.add_argument("--enabled-unhomed", action="store_true",
                   help="power up in operation enabled, profile position mode, never homed (as another program "
                        "would leave them)")
    p.add_argument("--touch-probe", action="store_true",
                   help="give both drives CiA 402 touch probe 1 (60B8h-60BBh) wired to the simulated camera's exposure "
                        "output, as a generic CiA 402 drive has it (the dryve D1 has none): fly scans then record the "
                        "positions the drives latch")
    p.add_argument("--answer-delay-ms", type=_delay, default=0.0, metavar="MS",
                   help="every answer of the drives comes this much later (a slow gateway or a busy bus; x the time "
                        "scale); default 0")
    p.add_argument("--canopen", metavar="CHANNEL", default=None,
                   help="serve the drives as CANopen nodes 1 and 2 on python-can's bus CHANNEL instead of Modbus TCP: "
                        "udp_multicast (between processes; its datagrams also reach the other computers of the local network, "
                        "which then see these drives), socketcan:can0, or virtual-NAME")
    p.epilog = ("The drives listen on 127.0.0.1 only. Connect with --port dryve:127.0.0.1:P1,127.0.0.1:P2 "
                "(the first line printed; with --canopen: canopen:CHANNEL:1,2); the simulated camera (--camera sim) "
                "follows them.")


def run(args: argparse.Namespace) -> int:
    from lfstudio.rig.profile import load_rig
    from lfstudio.studio.simulated import serve_sim_drive

    rig = load_rig(args.rig_profile or DEFAULT_DRIVE_RIG)
    if rig.driver != "cia402":
        raise InputError("--rig-profile", f"rig profile {rig.name!r} is for a GRBL controller, not CiA 402 drives",
                         f"a profile with driver = \"cia402\", e.g. {DEFAULT_DRIVE_RIG!r}")
    try:
        setup = {"leave_out": args.leave_out, "feed": args.feed_constant, "enabled_unhomed": args.enabled_unhomed,
                 "touch_probe": args.touch_probe, "answer_delay_s": args.answer_delay_ms / 1000.0}
        emulator, truth = serve_sim_drive(rig, time_scale=args.time_scale, seed=args.seed, ports=args.ports,
                                          setup=setup, canopen=args.canopen)
    except OSError as exc:
        if args.canopen:
            raise InputError("--canopen", f"cannot open the CAN bus {args.canopen!r} ({exc.strerror or exc})",
                             "udp_multicast, socketcan:CHANNEL of an interface that is up, or virtual-NAME") from None
        raise InputError("--ports", f"cannot listen on 127.0.0.1 ({exc.strerror or exc})",
                         "free TCP ports, or leave --ports out") from None
    except Exception as exc:  # noqa: BLE001 - python-can raises many kinds for a bus it cannot open
        if not args.canopen:
            raise
        raise InputError("--canopen", f"cannot open the CAN bus {args.canopen!r} ({exc})",
                         "udp_multicast, socketcan:CHANNEL of an interface that is up, or virtual-NAME") from None
    what = (f"CANopen nodes 1 and 2 on {args.canopen}" if args.canopen else "dryve D1 Modbus TCP gateway")
    return serve_until_stopped(
        emulator.word,
        f"two emulated CiA 402 drives ({what}) for rig {rig.name!r}; connect with\n"
        f"  lfstudio rig --port {emulator.word} --rig-profile '{rig.name}' home status\n"
        f"  lfstudio scan --port {emulator.word} --rig-profile '{rig.name}' --home --camera sim ...\n"
        "Ctrl-C stops them.", emulator, truth, "emulated drives")
