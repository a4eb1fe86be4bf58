"""``lfstudio gui``: open the application window (the default when no command is given)."""

from __future__ import annotations

import argparse
from lfstudio.cli.args import path_option

HELP = "open the application window (default)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--simulated", dest="simulated", action="store_true", default=True,
                      help="start on the built-in simulated studio: the simulated rig and camera are "
                           "connected at start (the default)")
    mode.add_argument("--hardware", dest="simulated", action="store_false",
                      help="start without the simulated studio; connect the real rig and camera in their panels")
    p.add_argument("--dataset", metavar="DIR", type=path_option("--dataset"), help="open this dataset folder on start")
    p.add_argument("--screenshot", metavar="PNG",
                   help="render the main window to this PNG file once it is shown, then quit")


def run(args: argparse.Namespace) -> int:
    from lfstudio.gui.app import run_app

    return run_app(simulated=args.simulated, dataset=args.dataset, screenshot=args.screenshot)
