"""``lfstudio sim-rig``: run the simulated GRBL controller on a pseudo-terminal until Ctrl-C."""

from __future__ import annotations

import argparse
from lfstudio.cli.args import number_option, old_spelling
from lfstudio.cli.serving import serve_until_stopped
from lfstudio.errors import DeviceError
from lfstudio.numbers import SEED, TIME_SCALE

HELP = "start the simulated GRBL controller on a pseudo-terminal and print its port path"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rig-profile", default=None, metavar="NAME", help="rig profile (default: the reference gantry)")
    old_spelling(p, "--rig", "--rig-profile")
    p.add_argument("--time-scale", type=number_option(TIME_SCALE, "--time-scale"), default=1.0, metavar="X",
                   help="1 real time, 0.1 ten times faster, 0 instant (default 1)")
    p.add_argument("--seed", type=number_option(SEED, "--seed"), default=0, metavar="N",
                   help="seed of the start position and repeatability errors (default 0)")


def run(args: argparse.Namespace) -> int:
    from lfstudio.rig.profile import DEFAULT_RIG, load_rig
    from lfstudio.studio.simulated import serve_sim_rig

    rig = load_rig(args.rig_profile or DEFAULT_RIG)
    sim, truth = serve_sim_rig(rig, time_scale=args.time_scale, seed=args.seed)
    port = sim.port
    if port is None:                     # serve_sim_rig starts it, or raises
        raise DeviceError("the simulated GRBL controller did not open its serial port")
    return serve_until_stopped(
        port, f"simulated GRBL 1.1 controller for rig {rig.name!r} on {port}; connect with\n"
              f"  lfstudio rig --port {port} home status\n"
              f"  lfstudio scan --port {port} --home --camera sim ...   (the simulated camera follows it)\n"
              "or any serial terminal (115200 baud). Ctrl-C stops it.",
        sim, truth, "simulated controller", running=lambda: sim.running)
