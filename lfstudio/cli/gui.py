"""``lfstudio gui``: open the application window (the default when no command is given)."""

from __future__ import annotations

import argparse

HELP = "open the application window (default)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--simulated", action="store_true", default=True,
                   help="use the built-in simulated studio (simulated rig and camera); the default")
    p.add_argument("--dataset", metavar="DIR", help="open this dataset folder on start")
    p.add_argument("--screenshot", metavar="PNG",
                   help="render the main window to this PNG file once it is shown, then quit")


def run(args: argparse.Namespace) -> int:
    from lfstudio.gui.app import run_app

    return run_app(simulated=args.simulated, dataset=args.dataset, screenshot=args.screenshot)
