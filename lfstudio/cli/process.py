"""``lfstudio process DATASET``: RAW captures → rectified 16-bit views in DATASET/processed/; for a
bracketed dataset also each view's frames merged to linear radiance in DATASET/hdr/
(:mod:`lfstudio.processing.hdr`)."""

from __future__ import annotations

import argparse
import sys
from typing import Any, Callable

from lfstudio.numbers import WORKERS
from lfstudio.cli.args import as_option, number_option, path_option

HELP = "process the captured views (debayer, lens, colour, shading, de-flicker, rectify, downsample)"


def _cluster_address(text: str) -> str:
    from lfstudio.processing.executors import check_cluster_address

    check_cluster_address(text)
    return text.strip()


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dataset", metavar="DATASET", type=path_option("DATASET"), help="the dataset folder (holding dataset.json)")
    p.add_argument("--profile", metavar="FILE", type=path_option("--profile"),
                   help="processing profile (TOML); default: DATASET/processing.toml, or built-in defaults. "
                        "The profile used is saved as DATASET/processing.toml")
    p.add_argument("--cluster", metavar="ADDR", type=as_option("--cluster", _cluster_address),
                   help="Dask scheduler address, e.g. tcp://10.0.0.5:8786 (workers must see the dataset "
                        "folder at the same path); default: a local process pool")
    p.add_argument("--workers", metavar="N", type=number_option(WORKERS, "--workers"),
                   help="local worker processes (default: one per core; 0: run in this process)")
    p.add_argument("--force", action="store_true",
                   help="process every view again, even those already done with the same profile")
    p.add_argument("--write-profile", metavar="FILE", type=path_option("--write-profile"),
                   help="write the effective profile (defaults or --profile) to FILE and exit")
    _add_merge_arguments(p)
    add_profile_arguments(p)


def _add_merge_arguments(p: argparse.ArgumentParser) -> None:
    """The --hdr* options, made from the merge settings' descriptions (lfstudio.processing.hdr.MERGE_PARAMS)."""
    from lfstudio.processing.hdr import MERGE_PARAMS, MergeOptions

    defaults = MergeOptions()
    g = p.add_argument_group("exposure brackets (scan --bracket)")
    for name, param in MERGE_PARAMS.items():
        if not param.option:
            continue
        said = param.to_text(getattr(defaults, name))
        if name == "format":
            g.add_argument(param.option, choices=(*param.choices, "none"), default=None,
                           help="a bracketed dataset: merge each view's frames to linear radiance in DATASET/hdr/ ("
                                f"{param.tip}), with a tone-mapped 16-bit PNG in hdr/preview/ (default {said}); 'none': "
                                "only the 16-bit views (the bracket's reference frame)")
        elif param.flag:
            g.add_argument(param.option, action="store_true", help=param.tip)
        else:
            assert param.number is not None
            g.add_argument(param.option, metavar=param.metavar, type=number_option(param.number, param.option),
                           default=getattr(defaults, name), help=f"{param.tip} (default {said})")


def profile_option(step: str, key: str) -> str:
    """The option of a profile setting: ``--resample-scale``; a step's switch is ``--STEP``/``--no-STEP``."""
    return f"--{step}" if key == "enabled" else f"--{step}-{key.replace('_', '-')}"


def _dest(step: str, key: str) -> str:
    return f"profile__{step}__{key}"


def _list_reader(option: str, param) -> Callable[[str], list]:
    """A list setting typed as ``1,0,0`` or ``"1 0 0"`` (empty: no numbers), each checked."""
    def read(text: str) -> list:
        words = text.replace(",", " ").split()
        return param.check(option, [param.number.parse(option, w) for w in words])
    return as_option(option, read)


def add_profile_arguments(p: argparse.ArgumentParser) -> None:
    """One option per setting of the processing profile, made from its description
    (lfstudio.dataset.profile.PARAMS: range, choices, unit, tip), grouped by step."""
    from lfstudio.dataset.profile import PARAMS, Profile

    defaults = Profile()
    groups: dict[str, argparse._ArgumentGroup] = {}
    for (step, key), param in PARAMS.items():
        if step not in groups:
            groups[step] = p.add_argument_group(
                f"processing profile [{step}]", None if groups else
                "each option overrides one setting of the profile (--profile, else DATASET/processing.toml, else "
                "the defaults) for this run; the profile used is saved as DATASET/processing.toml")
        option = profile_option(step, key)
        default = getattr(getattr(defaults, step), key)
        shown = param.to_text(default) if default not in ("", []) else "none"
        unit = f" {param.number.unit}" if param.number is not None and param.number.unit and not param.lengths else ""
        help_text = f"{param.tip} (default {shown}{unit})".replace("%", "%%")
        kwargs: dict[str, Any] = {"dest": _dest(step, key), "default": None, "help": help_text}
        if param.flag:
            kwargs["action"] = argparse.BooleanOptionalAction
        elif param.choices:
            kwargs["choices"] = param.choices
        elif param.lengths:
            kwargs.update(type=_list_reader(option, param), metavar="A,B,...")
        elif param.number is not None:
            kwargs.update(type=number_option(param.number, option), metavar="N" if param.number.integer else "X")
        else:
            kwargs["metavar"] = "TEXT"
        groups[step].add_argument(option, **kwargs)


def profile_with_options(profile, args: argparse.Namespace):
    """``profile`` with the settings given as options, checked as a whole (a message names the option)."""
    from lfstudio.dataset.profile import PARAMS, Profile

    data = profile.to_dict()
    given = False
    for step, key in PARAMS:
        value = getattr(args, _dest(step, key), None)
        if value is not None:
            data[step][key] = value
            given = True
    if not given:
        return profile
    return Profile.from_dict(data, "command line", field=profile_option)


def run(args: argparse.Namespace) -> int:
    from lfstudio.errors import InputError
    from lfstudio.jobs import TerminalProgress
    from lfstudio.processing.pipeline import process_dataset
    from lfstudio.dataset.profile import Profile

    if args.workers is not None and args.workers < 0:
        raise InputError("--workers", f"{args.workers} is negative", "0 (in this process) or more")
    if args.cluster and args.workers is not None:
        raise InputError("--workers", "cannot be combined with --cluster (the cluster has its own workers)")
    profile = Profile.load(args.profile) if args.profile else Profile.for_dataset(args.dataset)
    profile = profile_with_options(profile, args)
    if args.write_profile:
        profile.save(args.write_profile)
        print(f"profile written to {args.write_profile}")
        return 0
    from lfstudio.dataset import Dataset

    bracketed = bool(Dataset.open(args.dataset).manifest.get("bracket"))
    if args.hdr not in (None, "none") and not bracketed:
        raise InputError("--hdr", f"{args.dataset} has no exposure bracket (scan it with --bracket)",
                         "leave --hdr out for a dataset of one picture per view")
    bar = TerminalProgress("process")
    report = process_dataset(args.dataset, profile, workers=args.workers, cluster=args.cluster,
                             force=args.force, progress=bar)
    print(report.summary())
    for row, column, error in report.failed:
        print(f"FAILED row {row}, column {column}: {error}", file=sys.stderr)
    failed = bool(report.failed)
    if bracketed and args.hdr != "none":
        from lfstudio.processing.hdr import MergeOptions, merge_dataset

        options = MergeOptions(format=args.hdr or "exr", half=args.hdr_half, clip_fraction=args.hdr_clip,
                               noise_floor=args.hdr_noise_floor)
        merged = merge_dataset(args.dataset, options, profile, workers=args.workers, cluster=args.cluster,
                               force=args.force, progress=TerminalProgress("merge"))
        print(merged.summary())
        for row, column, error in merged.failed:
            print(f"FAILED (HDR) row {row}, column {column}: {error}", file=sys.stderr)
        failed = failed or bool(merged.failed)
    return 1 if failed else 0
