"""``lfstudio doctor``: load every component, try the features that need native code, print versions.

Run it first on a new workstation (and from a bundle: ``dist/lfstudio/lfstudio doctor``). Exit
code 0 when every required part works, 1 otherwise; optional parts (gphoto2, dask) only warn.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

HELP = "check this installation: versions of every component, RAW decoding, HEVC encoding, resources"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quick", action="store_true", help="only print versions (skip the functional checks)")


def _check_raw(tmp: Path) -> str:
    """A small Bayer DNG written by our writer, recognised and decoded by LibRaw (lfstudio's image reader)."""
    import numpy as np

    from lfstudio.dataset import images
    from lfstudio.studio.simulated import write_dng

    mosaic = np.full((64, 96), 4000, np.uint16)
    path = write_dng(tmp / "doctor.dng", mosaic)
    if images.kind(path) != "raw":
        raise RuntimeError("LibRaw does not recognise the DNG")
    rgb = images.develop(path)
    if rgb.shape[:2] != mosaic.shape:
        raise RuntimeError(f"decoded {rgb.shape}, wrote {mosaic.shape}")
    return f"DNG {mosaic.shape[1]}x{mosaic.shape[0]} decoded to {rgb.dtype} RGB"


def _check_hevc(tmp: Path) -> str:
    """Four 12-bit 4:4:4 HEVC frames encoded and decoded back (the export's codec)."""
    import av
    import numpy as np

    path = tmp / "doctor.mkv"
    with av.open(str(path), "w") as out:
        stream = out.add_stream("libx265", rate=4)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv444p12le"
        stream.options = {"x265-params": "log-level=error"}
        for i in range(4):
            frame = av.VideoFrame.from_ndarray(np.full((48, 64, 3), 1000 * (i + 1), np.uint16), format="rgb48le")
            out.mux(stream.encode(frame))
        out.mux(stream.encode(None))
    with av.open(str(path)) as inp:
        frames = sum(1 for _ in inp.decode(video=0))
    if frames != 4:
        raise RuntimeError(f"decoded {frames} of 4 frames")
    return "HEVC 12-bit 4:4:4: 4 frames encoded and decoded"


def _check_lensfun(tmp: Path) -> str:
    import lensfunpy

    db = lensfunpy.Database()  # pyright: ignore[reportAttributeAccessIssue]  # compiled lensfunpy._lensfun, re-exported
    cams = db.find_cameras("Sony", "ILCE-7RM2")
    if not cams:
        raise RuntimeError("the lens database has no Sony ILCE-7RM2 (database files missing?)")
    return f"lens database loaded ({len(db.lenses)} lenses; finds {cams[0].maker} {cams[0].model})"


def _check_resources(tmp: Path) -> str:
    from lfstudio.resources import RESOURCES_DIR, load_presets
    from lfstudio.support.userguide import user_guide_markdown

    missing = [p for p in ("style.qss", "presets/rigs.toml", "icons/lfstudio.svg") if not (RESOURCES_DIR / p).is_file()]
    if missing:
        raise RuntimeError(f"{RESOURCES_DIR}: missing {', '.join(missing)}")
    guide = user_guide_markdown()
    if "User guide" not in guide:
        raise RuntimeError("the user guide (docs/tutorial, docs/how-to or README.md) is not shipped")
    n = sum(len(load_presets(k)) for k in ("cameras", "lenses", "rigs"))
    return f"{RESOURCES_DIR} ({n} presets, icons, user guide)"


def _check_simulator(tmp: Path) -> str:
    """The simulated GRBL controller on a pty, as the simulated studio starts it."""
    from lfstudio.rig.profile import load_rig
    from lfstudio.studio.devices import open_rig

    link = open_rig("sim", load_rig(), doing="doctor check", time_scale=0.01, seed=1, timeout_s=2.0)
    try:
        link.controller.home()
        state = link.controller.status().state
    finally:
        link.close()
    return f"simulated rig homed over a pty ({state.name})"


def _check_dask(tmp: Path) -> str:
    """A one-worker local dask cluster in its own process (processing on a cluster uses dask)."""
    import time

    from distributed import Client, LocalCluster

    t0 = time.monotonic()
    cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                           dashboard_address=None)  # pyright: ignore[reportArgumentType]  # None: no dashboard (documented; annotated str)
    with cluster, Client(cluster) as client:
        total = client.submit(sum, [1, 2, 3]).result(timeout=60)
    if total != 6:
        raise RuntimeError(f"the worker computed {total}, not 6")
    return f"local cluster with one worker process ran a task ({time.monotonic() - t0:.1f} s)"


def _print_kinds() -> int:
    """The device kinds (built-in and plugins), each with where it came from and its options; a plugin
    that did not load is a warning naming it (the others still load). Returns 0 (plugins are optional)."""
    from lfstudio.studio.kinds import camera_kinds, options_text, problems, rig_kinds

    print("device kinds (--camera WORD, --port WORD; plugins: entry points lfstudio.cameras / lfstudio.rigs):")
    for what, kinds in (("camera", camera_kinds()), ("rig", rig_kinds())):
        for kind in kinds.values():
            ok, runs_on = kind.check() if kind.check is not None else (True, "")
            print(f"{'  ' if ok else 'warn'}{what} {kind.word:<20} {kind.label or kind.name}  [{kind.origin}]"
                  + (f"  {runs_on}" if runs_on else ""))
            for line in options_text(kind):
                print(f"  {'':<27} option {line}")
    for line in problems():
        print(f"warn {line}")
    return 0


#: (name, check, required)
CHECKS = (("RAW decoding", _check_raw, True), ("HEVC encoding", _check_hevc, True),
          ("lens database", _check_lensfun, True), ("resources", _check_resources, True),
          ("simulated rig", _check_simulator, True), ("dask cluster", _check_dask, False))


def run(args: argparse.Namespace) -> int:
    from lfstudio.support.logs import log_file
    from lfstudio.support.versions import COMPONENTS, check_component, versions

    failed = 0
    rows = versions(())
    statuses = [check_component(c) for c in COMPONENTS]
    width = max(len(r[0]) for r in rows + [(s.name, "") for s in statuses] + [(c[0], "") for c in CHECKS])
    for name, text in rows:
        print(f"  {name:<{width}}  {text}")
    for s in statuses:
        mark = "ok  " if s.ok else ("FAIL" if s.required else "warn")
        failed += not s.ok and s.required
        print(f"{mark} {s.name:<{width}}  {s.version}")
    if not args.quick:
        with tempfile.TemporaryDirectory(prefix="lfstudio-doctor-") as tmp:
            for name, check, required in CHECKS:
                try:
                    text, ok = check(Path(tmp)), True
                except Exception as exc:  # noqa: BLE001 - every failure is reported, the rest still run
                    text, ok = f"{type(exc).__name__}: {exc}", False
                failed += not ok and required
                print(f"{'ok  ' if ok else 'FAIL' if required else 'warn'} {name:<{width}}  {text}")
    failed += _print_kinds()
    print(f"  {'log file':<{width}}  {log_file()}")
    print("doctor: all required parts work" if not failed else f"doctor: {failed} problem(s)")
    return 0 if not failed else 1
