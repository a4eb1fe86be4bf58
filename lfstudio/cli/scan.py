"""``lfstudio scan``: capture a grid of views into a dataset folder (crash-safe, resumable).

Ctrl+C stops the scan within about :data:`CTRL_C_GRACE_S` + a second: a move under way stops, the
view being exposed is stored if its file arrives within the grace time and otherwise left not done,
the journal holds every captured view, and the line printed last is the exact command that resumes
(:func:`resume_command`); exit status 130. A second Ctrl+C drops the grace time.
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import replace
import signal
import sys
import threading
import time

from lfstudio.cli.args import (bracket_option, described_option, grid_option, number_option, path_option,
                               refused_spelling)
from lfstudio.numbers import Number
from lfstudio.dataset.paths import view_label
from lfstudio.errors import DatasetError, InputError

HELP = "capture a grid of views into a dataset folder (meander order, pipelined, resumable)"

EXIT_FAULT = 3
#: Ctrl+C: how long a capture under way may still take to arrive before it is dropped
CTRL_C_GRACE_S = 1.0
#: options that shape a new scan's plan; a resume takes them from the dataset
_PLAN_OPTIONS = ("grid", "spacing_mm", "offset_mm", "plan", "origin_here", "home", "resume", "out")


#: what a FROM_PLAN option's default is, as --help says it
_UNSET_DEFAULT = {
    "port": "sim; with --resume the dataset's own rig", "camera": "sim; with --resume the dataset's own camera",
    "rig_profile": "the reference gantry, for sim-dryve/sim-canopen the preset dryve D1 pair; with --resume "
                   "the dataset's",
    "grid_columns": "from --plan or 101x21", "spacing_mm": "from --plan, else 4x6; with --resume the dataset's",
    "order": "row-meander", "settle_s": "from --plan, else the rig profile's",
    "bracket": "from --plan, else one picture per view; with --resume the dataset's", "sim_width_px": "2000"}


def _described(p, name: str) -> None:
    """The option of the scan option ``name``, made from its description
    (lfstudio.studio.scan_options.PARAMS: range, unit, choices, tip)."""
    from lfstudio.studio.scan_options import FROM_PLAN, PARAMS, ScanOptions

    param = PARAMS[name]
    reader = (grid_option(param.option) if name == "grid_columns" else
              bracket_option(param.option) if name == "bracket" else
              _secret_url if name == "notify" else _secret_token if name == "status_token" else None)
    if name in FROM_PLAN:
        described_option(p, param, None, said=_UNSET_DEFAULT[name], reader=reader)
    else:
        described_option(p, param, getattr(ScanOptions(), name), reader=reader)


def _secret_url(text: str):
    """A --notify URL, read as a Secret (its path, user and password are shown as …)."""
    from lfstudio.scan.notify import shown_url
    from lfstudio.support.secrets import Secret

    return Secret(text, shown_url(text))


def _secret_token(text: str):
    """A --status-token, read as a Secret ("new" asks for one to be made: no secret)."""
    from lfstudio.support.secrets import Secret

    return text if text in ("", "new") else Secret(text)


def add_arguments(p: argparse.ArgumentParser) -> None:
    _described(p, "port")
    refused_spelling(p, "--rig", "--rig: the axis controller is now --port (write --port {value}); "
                                 "a rig profile is --rig-profile NAME")
    _described(p, "camera")
    _described(p, "rig_profile")
    p.add_argument("--camera-option", action="append", default=[], metavar="NAME=VALUE",
                   help="a connection option of the camera's kind, e.g. --camera-option timeout_s=3 for genicam:ID "
                        "(lfstudio doctor lists each kind's options)")
    p.add_argument("--rig-option", action="append", default=[], metavar="NAME=VALUE",
                   help="a connection option of the rig's kind, e.g. --rig-option poll_hz=100 for dryve:HOST,HOST "
                        "(lfstudio doctor lists each kind's options)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="a camera setting before the first view, e.g. --set pixel_format=Mono16 --set exposure_s=0.01 "
                        "(the names 'lfstudio camera' prints under settings)")
    p.add_argument("--home", action="store_true",
                   help="home the rig ($H) before the first view (with --resume: before continuing)")
    p.add_argument("--origin-here", action="store_true",
                   help="rig without limit switches: make the carriage's current position the origin (0, 0) "
                        "before the first view (park it at the left/top end of its travel first)")
    p.add_argument("--keep-drive-reference", action="store_true",
                   help="CiA 402 drives: accept the position the drives report as their reference without homing "
                        "(e.g. to resume after a crash; logged). Without it drives are homed by lfstudio or refused")
    p.add_argument("--allow-device-change", action="store_true",
                   help="with --resume: continue with other devices than the dataset's own (recorded per view)")
    for name in ("grid_columns", "spacing_mm", "offset_mm", "order", "settle_s", "bracket"):
        _described(p, name)
    p.add_argument("--plan", metavar="PLAN", type=path_option("--plan"), help="a scene plan file saved by the planner (grid, spacing, camera, lens)")
    p.add_argument("--out", required=True, metavar="DATASET", type=path_option("--out"), help="the dataset folder to create (or resume)")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted scan in DATASET: captures only the views not done yet")
    for name in ("time_scale", "exposure_s", "transfer_s", "sim_width_px", "retries", "seed"):
        _described(p, name)
    g = p.add_argument_group("fly scanning (continuous motion)")
    g.add_argument("--fly", action="store_true",
                   help="fly scan: each row crossed at one constant speed, the camera triggered as the carriage "
                        "passes each view (needs a camera with triggers and a controller that reports its position); "
                        "the speed keeps motion blur within --blur-limit-px, refused with the numbers when none does")
    g.add_argument("--fly-speed-mm-s", metavar="MMS", type=number_option(Number("mm/s", 0, 100_000, low_open=True),
                                                                           "--fly-speed-mm-s"),
                   help="the row speed of --fly (default: the fastest the blur limit, camera, controller and axes allow)")
    g.add_argument("--blur-limit-px", metavar="PX", type=number_option(Number("px", 0, 100, low_open=True),
                                                                        "--blur-limit-px"), default=0.5,
                   help="the most motion blur a --fly frame may have at the near distance (default 0.5)")
    g.add_argument("--trigger", choices=("auto", "hardware", "software"), default="auto",
                   help="who fires the camera in a --fly scan: 'hardware' (the controller's output wired to the "
                        "camera's trigger input, switched as the carriage passes each view: GRBL's spindle output "
                        "with laser mode $32=1; refused with the numbers when it cannot), 'software' (this computer, "
                        "timed from the position reports), 'auto' (default: hardware where both devices can)")
    p.add_argument("--keep-on-card", action="store_true",
                   help="keep each picture on the camera's card and download it at the row changes and at the end "
                        "instead of after every shot (gphoto2 cameras); a view is done once its file is on disk "
                        "and verified; files a run left on the card are fetched when it resumes")
    p.add_argument("--check", action="store_true",
                   help="check each view as it arrives (lfstudio check's measurements, on a background thread the "
                        "scan never waits for) and name failing views at once; the full report: lfstudio check")
    _add_unattended_arguments(p)
    p.epilog = ("a second scan of the same DATASET, or of the same rig port or camera, is refused while this one "
                "runs; on a real rig add --home (or --origin-here for a rig without limit switches). "
                f"Exit code {EXIT_FAULT}: a device fault stopped the scan (the message says what to fix and the "
                "command that continues).")


def _add_unattended_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("unattended scans (docs/unattended.md)")
    from lfstudio.studio.unattended import DESCRIBED

    for name in DESCRIBED:
        _described(g, name)


def _unattended(args: argparse.Namespace):
    """The unattended-scan helpers the options ask for (checked before anything starts)."""
    from pathlib import Path

    from lfstudio.studio.unattended import DESCRIBED, Unattended, UnattendedOptions

    given = {name: getattr(args, name) for name in DESCRIBED}
    options = UnattendedOptions(**{**given, "notify": list(given["notify"] or ())})
    return Unattended.open(options, dataset_name=Path(args.out).name,
                           say=lambda text: print(f"lfstudio scan: {text}", file=sys.stderr))


def _build_plan(args: argparse.Namespace, rig_config, existing=None):
    """The scan plan and the scene plan (or None) from the options; with ``existing``, the dataset's grid."""
    from lfstudio.scan.scan_plan import ScanPlan
    from lfstudio.studio.session import resume_plan

    scene = None
    if args.plan:
        from lfstudio.planning.scene_plan import load_plan

        scene = load_plan(args.plan)
        try:
            scene.validate(check_travel=False)        # the rig's travel is checked by the scan plan below
        except InputError as exc:
            raise InputError(f"{args.plan}: {exc.field}", str(exc).split(": ", 1)[-1]) from None
    if existing is not None:
        base = ScanPlan.from_grid(existing.grid)
        grid = (base.columns, base.rows)
        spacing = base.spacing_mm
        if args.grid and args.grid != grid:
            raise InputError("--grid", f"{args.grid[0]}x{args.grid[1]} differs from the dataset's {grid[0]}x{grid[1]}",
                             "leave it out with --resume, or scan into a new --out folder")
        if args.spacing_mm and args.spacing_mm != spacing:
            raise InputError("--spacing-mm", f"{args.spacing_mm[0]:g}x{args.spacing_mm[1]:g} differs from the dataset's "
                             f"{spacing[0]:g}x{spacing[1]:g}", "leave it out with --resume")
        plan = resume_plan(existing, order=args.order, settle_s=args.settle_s)
        plan.check_limits(rig_config)
        return replace(plan, bracket=args.bracket), scene
    if scene is not None:
        grid = (scene.grid_columns, scene.grid_rows)
        spacing = (scene.spacing_mm[0], scene.spacing_mm[1])
    else:
        grid, spacing = (101, 21), (4.0, 6.0)
    if args.grid:
        grid = args.grid
    if args.spacing_mm:
        spacing = args.spacing_mm
    offset = args.offset_mm
    settle = args.settle_s
    if settle is None and scene is not None:
        settle = scene.settle_s
    try:
        plan = ScanPlan.centered(grid[0], grid[1], spacing, rig_config, offset_mm=offset,
                                 order=args.order or "row-meander", settle_s=settle)
    except InputError as exc:
        field = {"grid columns / horizontal spacing_mm": "--grid/--spacing-mm",
                 "grid rows / vertical spacing_mm": "--grid/--spacing-mm",
                 "horizontal origin/offset_mm": "--offset-mm", "vertical origin/offset_mm": "--offset-mm",
                 "grid columns": "--grid", "grid rows": "--grid", "grid": "--grid",
                 "horizontal spacing_mm": "--spacing-mm", "vertical spacing_mm": "--spacing-mm",
                 "settle_s": "--settle-s"}.get(exc.field, exc.field)
        raise InputError(field, str(exc).split(": ", 1)[-1]) from None
    bracket = args.bracket
    if bracket is None and scene is not None and scene.bracket:
        bracket = scene.bracket_value
    return replace(plan, bracket=bracket), scene


def resume_command(args: argparse.Namespace, root) -> str:
    """The exact command that continues this scan: ``lfstudio scan --resume --out ROOT`` with the
    devices and timings given to this one (not the plan's options: the dataset holds its grid). A
    secret (a --notify URL, --status-token) is shown redacted, with a note to give it again."""
    import shlex

    from lfstudio.dataset.bracket import Bracket
    from lfstudio.support.secrets import Secret

    hidden = 0
    defaults = argparse.ArgumentParser()
    add_arguments(defaults)
    words = ["lfstudio", "scan", "--resume", "--out", str(root)]
    for action in defaults._actions:
        if not action.option_strings or action.dest in _PLAN_OPTIONS or action.help == argparse.SUPPRESS:
            continue
        value = getattr(args, action.dest, None)
        if value is None or value == action.default:
            continue
        if action.nargs == 0:                    # a flag
            words.append(action.option_strings[0])
        elif isinstance(value, list):            # a repeatable option
            for item in value:
                words += [action.option_strings[0], str(item)]
                hidden += isinstance(item, Secret)
        else:
            text = value.text() if isinstance(value, Bracket) else str(value)    # a bracket as typed: -2,0,+9
            # a value starting with '-' would read as an option: joined to it (--bracket=-2,0,+9)
            words += [f"{action.option_strings[0]}={text}"] if text.startswith("-") else [action.option_strings[0], text]
            hidden += isinstance(value, Secret)
    return shlex.join(words) + ("  # give the …-shortened secrets (URLs, token) again as you gave them" if hidden
                                else "")


def _start_check(dataset, engine):
    """Scan-time check (:mod:`lfstudio.quality.live`): a failing view is named as soon as it is judged."""
    from lfstudio.quality.live import LiveChecker

    checker = LiveChecker(dataset)
    checker.subscribe(lambda e: e["verdict"] == "fail" and print(
        f"\nlfstudio scan: check: {e['view']} fails: " + "; ".join(e["reasons"]), file=sys.stderr))
    engine.subscribe(checker.on_event)
    return checker


def _finish_check(checker, dataset) -> None:
    checker.settle()                    # every view located together, as lfstudio check does
    checker.wait_idle()
    checker.close()
    flagged = checker.flagged()
    names = ", ".join(f"{e['view']} ({e['verdict']})" for e in flagged.values())
    print(f"lfstudio scan: check: {len(checker.results)} views checked, "
          + (f"{len(flagged)} flagged: {names}" if flagged else "none flagged")
          + f"; the full report: lfstudio check {dataset.root}", file=sys.stderr)


def _camera_options(args: argparse.Namespace) -> dict:
    """``--camera-option NAME=VALUE`` checked against the options of ``--camera``'s kind."""
    if not args.camera_option:
        return {}
    from lfstudio.errors import InputError
    from lfstudio.studio.devices import CameraSpec
    from lfstudio.studio.kinds import camera_kind, parse_options

    if args.camera is None:
        raise InputError("--camera-option", "names options of no camera", "give --camera KIND:ARGS with it")
    return parse_options(camera_kind(CameraSpec.parse(args.camera).kind), args.camera_option)


def _rig_options(args: argparse.Namespace) -> dict:
    """``--rig-option NAME=VALUE`` checked against the options of ``--port``'s kind."""
    if not args.rig_option:
        return {}
    from lfstudio.errors import InputError
    from lfstudio.studio.devices import RigSpec
    from lfstudio.studio.kinds import parse_options

    if args.port is None:
        raise InputError("--rig-option", "names options of no rig", "give --port with it")
    return parse_options(RigSpec.parse(args.port).info, args.rig_option, option="--rig-option")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from lfstudio.studio.kinds import parse_settings

    from lfstudio.jobs import TerminalProgress, format_duration
    from lfstudio.rig.profile import load_rig
    from lfstudio.scan.events import EventKind, ScanRequestRefused, ScanState
    from lfstudio.studio.session import ScanRequest, ScanSession

    request = ScanRequest(Path(args.out), resume=args.resume, rig=args.port, camera=args.camera,
                          rig_config=load_rig(args.rig_profile) if args.rig_profile else None, home=args.home,
                          origin_here=args.origin_here, allow_device_change=args.allow_device_change,
                          keep_drive_reference=args.keep_drive_reference,
                          retries=args.retries, time_scale=args.time_scale, exposure_s=args.exposure_s,
                          transfer_s=args.transfer_s, seed=args.seed, sim_width_px=args.sim_width_px,
                          camera_options=_camera_options(args), rig_options=_rig_options(args),
                          camera_settings=parse_settings(args.set), fly=args.fly, fly_speed_mm_s=args.fly_speed_mm_s,
                          keep_on_card=args.keep_on_card,
                          blur_limit_px=args.blur_limit_px, fly_trigger=args.trigger)
    request.engine_options["auto_resume"] = args.auto_resume
    unattended = _unattended(args)
    interrupts: list[int] = []          # Ctrl+C typed: the operator is here, the page does not linger
    session = ScanSession(request, doing="scanning",
                          log_line=lambda text: print(f"lfstudio scan: {text}", file=sys.stderr))
    try:
        engine = session.open(lambda existing, rig_config: _build_plan(args, rig_config, existing))
        if engine is None:                      # every view finished: no device was connected
            assert session.dataset is not None and session.plan is not None, "open() sets them"
            counts = session.dataset.status_counts()
            print(f"lfstudio scan: {session.dataset.root}: {session.plan.columns}x{session.plan.rows} grid, "
                  f"{counts['done']} done, {counts['skipped']} skipped; nothing to do, every view is captured "
                  "(no device connected)", file=sys.stderr)
            return 0
        dataset, plan, studio = session.dataset, session.plan, session.studio
        assert dataset is not None and plan is not None and studio is not None, "open() sets them or raises"
        unattended.attach(engine, dataset)
        todo = engine.remaining
        print(f"lfstudio scan: {studio.description}; {plan.columns}x{plan.rows} grid, "
              f"{dataset.status_counts()['done']} done, {todo} to capture into {dataset.root}", file=sys.stderr)
        if todo == 0:
            print("lfstudio scan: nothing to do, every view is captured", file=sys.stderr)
            return 0
        bar = TerminalProgress("scan")
        paused = threading.Event()

        def on_event(ev) -> None:
            if ev.kind is EventKind.VIEW_DONE:
                bar(ev.done, ev.total, view_label(ev.row, ev.column))
            elif ev.kind is EventKind.VIEW_FAILED:
                print(f"\nlfstudio scan: view {view_label(ev.row, ev.column)}: {ev.message}"
                      + (" (retrying)" if ev.will_retry else ""), file=sys.stderr)
            elif ev.kind is EventKind.STATE and ev.state is ScanState.PAUSED:
                if ev.extra.get("auto_resume"):
                    print(f"\nlfstudio scan: paused: {ev.message}", file=sys.stderr)
                paused.set()
            elif ev.kind is EventKind.STATE and ev.extra.get("auto_resumed"):
                print(f"lfstudio scan: {ev.message}", file=sys.stderr)
            elif ev.kind is EventKind.LOG:
                print(f"lfstudio scan: {ev.message}", file=sys.stderr)

        engine.subscribe(on_event)
        checker = _start_check(dataset, engine) if args.check else None
        if checker is not None:
            unattended.attach_checker(checker)
        def on_sigint(*_) -> None:
            interrupts.append(1)
            if len(interrupts) == 1:
                print(f"\nlfstudio scan: Ctrl+C: stopping (the view being exposed is kept if it arrives within "
                      f"{CTRL_C_GRACE_S:g} s)", file=sys.stderr, flush=True)
            try:
                engine.abort(grace_s=CTRL_C_GRACE_S if len(interrupts) == 1 else 0.0)
            except ScanRequestRefused:      # it has ended meanwhile
                pass

        previous = signal.signal(signal.SIGINT, on_sigint)
        try:
            engine.start()
            while engine.wait(0.2) not in (ScanState.FINISHED, ScanState.FAILED):
                if paused.is_set():
                    paused.clear()
                    if engine.state is not ScanState.PAUSED or engine.resumes_by_itself:
                        continue        # --auto-resume: it goes on by itself when the cause clears
                    # no operator at a terminal: a fault ends the run, --resume continues it
                    fault = engine.fault
                    engine.abort()
                    engine.wait()
                    if fault is not None and not getattr(fault, "resumable", True):   # its message says what to do
                        print(f"\nlfstudio scan: stopped: {fault}", file=sys.stderr)
                        return EXIT_FAULT
                    if fault is not None:
                        print(f"\nlfstudio scan: stopped: {fault}\nlfstudio scan: to continue, fix that and run: "
                              f"{resume_command(args, dataset.root)}", file=sys.stderr)
                        return EXIT_FAULT
                    paused.clear()
        finally:
            signal.signal(signal.SIGINT, previous)
        if checker is not None:
            _finish_check(checker, dataset)
        state = engine.state
        counts = dataset.status_counts()
        if state is ScanState.FAILED:         # said here (as lfstudio's main would) before the page lingers
            logging.getLogger("lfstudio.cli").info("scan failed: %s", engine.message)
            print(f"lfstudio scan: error: {DatasetError(engine.message)}", file=sys.stderr)
            return 1
        print(f"lfstudio scan: {engine.message} ({format_duration(engine.active_s)})", file=sys.stderr)
        if dataset.finished():
            return 0
        print(f"lfstudio scan: the {counts['done']} captured views are saved in {dataset.root}; resume with:\n"
              f"  {resume_command(args, dataset.root)}", file=sys.stderr)
        return 130 if engine.aborted else 1
    finally:
        session.close()
        _linger(unattended.close(linger=not interrupts))


def _linger(status) -> None:
    """The status page showing the scan's final state for --status-linger-s (Ctrl+C ends it sooner)."""
    if status is None:
        return
    try:
        print(f"lfstudio scan: the status page {status.url} shows the final state until "
              f"{time.strftime('%H:%M:%S', time.localtime(status.board.serving_until))} (--status-linger-s; Ctrl+C "
              "ends it now)", file=sys.stderr, flush=True)
        status.wait_closed()
    except KeyboardInterrupt:
        pass
    finally:
        status.close()
