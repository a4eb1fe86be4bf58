"""The options of a scan, described once: ``lfstudio scan``'s options (:mod:`lfstudio.cli.scan`) and
the Scan panel's editors (:mod:`lfstudio.gui.panels.scan`) are made from :class:`ScanOptions`'s field
descriptions (:func:`lfstudio.numbers.described`: range and unit, choices, label, tip, option), so the
window accepts exactly what the command line does.

The defaults here are a new scan's without a plan; the command line leaves some options unset
(None) so that ``--plan`` or the dataset being resumed can fill them in (:data:`FROM_PLAN`).
"""

from __future__ import annotations

from dataclasses import dataclass

from lfstudio.dataset.grid import ORDERS
from lfstudio.numbers import (EXPOSURE_S, MAX_GRID_SIDE, OFFSET_MM, RETRIES, SEED, SETTLE_S, SPACING_MM,
                              TIME_SCALE, TRANSFER_S, WIDTH_PX, Number, Param, described, params_of)
from lfstudio.optics import REFERENCE
from lfstudio.scan.status_http import LINGER_S

#: where the options are listed
DEVICES, GRID, SIMULATION, UNATTENDED = "devices", "grid", "simulated devices", "unattended scans"
_SIDE = Number("", 1, MAX_GRID_SIDE, integer=True)
ON_FINISH_TIMEOUT_S = Number("s", 1, 24 * 3600)
STATUS_LINGER_S = Number("s", 0, 7 * 24 * 3600)


@dataclass(frozen=True)
class ScanOptions:
    """Every setting of one scan that a person types."""

    port: str | None = described(
        None, optional="sim", label="Axis controller", option="--port", metavar="sim|PORT", group=DEVICES,
        tip="axis controller: 'sim' (simulated GRBL on a pseudo-terminal), 'instant' (no timing) or a serial port "
            "such as /dev/ttyUSB0 or COM3 (/dev/pts/N as printed by 'lfstudio sim-rig'); a pair of CiA 402 drives: "
            "dryve:HOST[:PORT],HOST[:PORT] (Modbus TCP, as printed by 'lfstudio sim-drive'), "
            "canopen:CHANNEL:NODE,NODE, or sim-dryve / sim-canopen (emulated here)")
    camera: str | None = described(
        None, optional="sim", label="Camera", option="--camera", metavar="sim|gphoto2|folder:PATH|genicam:ID|KIND:ARGS",
        group=DEVICES,
        tip="camera: 'sim' (renders the virtual studio), 'gphoto2' (tethered USB), 'folder:PATH' (hot folder), "
            "'genicam:ID' (GigE Vision / USB3 Vision through aravis), 'instant', or an installed plugin's "
            "KIND:ARGUMENTS ('lfstudio doctor' lists the kinds)")
    rig_profile: str | None = described(
        None, optional="the reference gantry", label="Rig profile", option="--rig-profile", metavar="NAME",
        group=DEVICES, tip="rig profile from the presets (real drives need theirs named)")
    grid_columns: int = described(
        REFERENCE.grid[0], number=_SIDE, label="Views (columns × rows)", option="--grid", metavar="CxR",
        group=GRID, tip="columns x rows of views, e.g. 101x21")
    grid_rows: int = described(
        REFERENCE.grid[1], number=_SIDE, label="Views (columns × rows)", option="--grid", metavar="CxR",
        group=GRID, tip="columns x rows of views, e.g. 101x21")
    spacing_mm: tuple[float, float] = described(
        REFERENCE.spacing_mm, number=SPACING_MM, pair=True, label="Spacing", option="--spacing-mm", metavar="HxV",
        group=GRID, tip="distance between neighbouring views in mm, horizontal x vertical, e.g. 4x6")
    offset_mm: tuple[float, float] = described(
        (0.0, 0.0), number=OFFSET_MM, pair=True, label="Offset from centre", option="--offset-mm", metavar="HxV",
        group=GRID, tip="shift of the grid from the centre of the travel in mm")
    order: str = described(
        ORDERS[0], choices=ORDERS, label="Order", option="--order", group=GRID,
        tip="capture order: row-meander: left→right, then right→left on the next row (fastest); column-meander: "
            "the same by columns; raster: every row left→right")
    settle_s: float | None = described(
        None, number=SETTLE_S, optional="the rig profile's", label="Settle", option="--settle-s", metavar="S",
        group=GRID, tip="wait after each move before the exposure, for vibrations to die down")
    bracket: str = described(
        "", label="Bracket", option="--bracket", metavar="EV,...|T,...", group=GRID,
        tip="an exposure bracket at every view: EV steps around the camera's shutter time (-2,0,+2) or shutter "
            "times (1/500,1/125,1/30s); empty: one picture per view. Each frame is stored under its view, the 0 EV "
            "(middle) frame is the view's file; processing merges them to linear HDR")
    time_scale: float = described(
        1.0, number=TIME_SCALE, label="Simulation time scale", option="--time-scale", metavar="X", group=SIMULATION,
        tip="multiply every simulated duration: 1 real time, 0.1 ten times faster, 0 as fast as possible")
    exposure_s: float = described(
        REFERENCE.exposure_s, number=EXPOSURE_S, label="Exposure", option="--exposure-s", metavar="S",
        group=SIMULATION, tip="simulated camera exposure time")
    transfer_s: float = described(
        REFERENCE.transfer_s, number=TRANSFER_S, label="Transfer", option="--transfer-s", metavar="S",
        group=SIMULATION, tip="simulated camera transfer time")
    sim_width_px: int | None = described(
        None, number=WIDTH_PX, optional="2000", label="Simulated image width", option="--sim-width-px",
        metavar="PX", group=SIMULATION, tip="simulated camera image width in pixels (smaller renders faster)")
    retries: int = described(
        2, number=RETRIES, label="Retries", option="--retries", metavar="RETRIES", group=DEVICES,
        tip="retries per view before the scan stops")
    seed: int = described(0, number=SEED, label="Seed", option="--seed", metavar="SEED", group=SIMULATION,
                          tip="seed of the simulated devices")
    notify: list[str] = described(
        [], repeat=True, label="Notify", option="--notify", metavar="URL", group=UNATTENDED,
        tip="tell URL when the scan starts, pauses (why), resumes, fails, finishes or is aborted, and (with --check) "
            "of flagged views; repeatable: https://… (JSON POST), ntfy+https://HOST/TOPIC, slack+https://…, "
            "matrix+https://… ({\"text\": …}), mailto:ADDRESS (with --smtp)")
    smtp: str = described(
        "", label="SMTP server", option="--smtp", metavar="smtp://[USER@]HOST[:PORT]", group=UNATTENDED,
        tip="the SMTP server for mailto: notifications: smtp:// (STARTTLS, 587), smtps:// (SSL, 465) or smtp+plain:// "
            "(a local relay); the password comes from $LFSTUDIO_SMTP_PASSWORD")
    status_http: str = described(
        "", label="Status page address", option="--status-http", metavar="[HOST:]PORT", group=UNATTENDED,
        tip="serve a read-only status page (state, progress, ETA, last thumbnails, live-check verdicts, log) and "
            "/status.json on PORT of 127.0.0.1, or of HOST (then with --status-token)")
    status_token: str = described(
        "", label="Status page token", option="--status-token", metavar="TOKEN|new", group=UNATTENDED,
        tip="the token every request to the status page must carry (?token=...); 'new' makes one and prints the "
            "page's address with it once; needed for any HOST but 127.0.0.1")
    status_linger_s: float = described(
        LINGER_S, number=STATUS_LINGER_S, label="Status page after the scan", option="--status-linger-s", metavar="S",
        group=UNATTENDED, tip="after the scan ends, the status page keeps showing its final state (finished, aborted "
                              "or failed, and when) this long; 0: it closes with the scan")
    auto_resume: int = described(
        0, number=RETRIES, label="Auto-resume", option="--auto-resume", metavar="N", group=UNATTENDED,
        tip="resume by itself, at most N times, when the cause of a pause clears (disk space freed, camera or "
            "controller connection back); STOP, limit switches, position errors and alarms that need homing always "
            "wait for a person (0: a fault ends the run, --resume continues it)")
    on_finish: str = described(
        "", label="When the scan ends", option="--on-finish", metavar="CMD", group=UNATTENDED,
        tip="a shell command run when the scan ends (finished, aborted or failed), e.g. lights and motors off; "
            "$LFSTUDIO_SCAN_OUTCOME, $LFSTUDIO_DATASET, $LFSTUDIO_DONE, $LFSTUDIO_TOTAL tell it how; its output is "
            "logged, a failure notified")
    on_finish_timeout_s: float = described(
        300.0, number=ON_FINISH_TIMEOUT_S, label="Time limit", option="--on-finish-timeout-s", metavar="S",
        group=UNATTENDED, tip="the --on-finish command is stopped after this long")


#: every scan option's description, by field
PARAMS: dict[str, Param] = params_of(ScanOptions)
#: options the command line leaves unset unless given, so that --plan (or the dataset resumed) decides
FROM_PLAN = frozenset({"port", "camera", "rig_profile", "grid_columns", "grid_rows", "spacing_mm", "order",
                       "settle_s", "bracket", "sim_width_px"})
