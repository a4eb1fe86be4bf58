"""The scene plan: every input of SPEC "The optics" in one value, and everything it implies.

``ScenePlan`` holds the inputs (units in the names); :meth:`ScenePlan.validate` rejects impossible
input with an :class:`~lfstudio.errors.InputError` naming the field; :meth:`ScenePlan.derive`
returns a :class:`PlanResult` with every output and the soft problems as :class:`PlanWarning`
objects (each tied to the input field it concerns, so the GUI can show it next to that field).

The depth-of-field figures use the thin-lens approximation H ≈ f²/(N·c) throughout, so that the
aperture formula and the sharp-range formulas are exact inverses of each other (SPEC formulas
(3)–(6)); the exact hyperfocal distance f + f²/(N·c) is larger by one focal length.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from lfstudio import optics
from lfstudio.dataset.bracket import Bracket, parse_bracket
from lfstudio.dataset.grid import DEFAULT_ORDER, Grid
from lfstudio.errors import InputError
from lfstudio.optics import REFERENCE
from lfstudio.planning.fly import fly_inputs_of, plan_fly
from lfstudio.numbers import MAX_GRID_SIDE, Number, check_described, check_grid, described, params_of

PLAN_FORMAT = "lfstudio-plan"
PLAN_VERSION = 1

AXES = ("horizontal", "vertical")

#: the groups the plan's fields are listed in (the command line's --help; the window has its own layout)
CAMERA, SCENE, GRID, TARGETS = "camera and lens", "scene and optics", "grid and rig", "targets"
FLY = "fly scanning (continuous motion)"


@dataclass(frozen=True)
class PlanWarning:
    """A soft problem of a plan. ``field`` is the ScenePlan attribute it concerns; ``severity`` is
    "error" (the plan cannot be run as is), "warning" (it runs, but misses a goal) or "info"."""

    field: str
    message: str
    severity: str = "warning"

    def to_dict(self) -> dict[str, str]:
        return {"field": self.field, "message": self.message, "severity": self.severity}


@dataclass(frozen=True)
class ScenePlan:
    """Inputs of a scene plan. Defaults are the paper's setup (:data:`lfstudio.optics.REFERENCE`;
    :func:`presets.reference_plan` is the same from the shipped presets).

    Pairs are (horizontal, vertical), or (width, height) for sensors. ``pixel_pitch_um`` None means
    "derive from sensor_mm / sensor_px"; ``f_number`` None means "use the aperture the scene needs";
    ``focus_m`` None means "focus where the sharp range centres on the scene"; ``bytes_per_image``
    None means "an uncompressed raw frame of ``raw_bits`` per pixel".
    """

    camera_name: str = described("Sony A7R II (reference)", label="Camera", option="--camera-preset",
                                 metavar="NAME", group=CAMERA, tip="Camera preset (see --list-presets)")
    sensor_px: tuple[int, int] = described(
        REFERENCE.sensor_px, number=Number("px", 0, 100_000, low_open=True, integer=True), pair=True,
        label="Sensor", option="--sensor-px", metavar="WxH", group=CAMERA,
        tip="Sensor size in pixels (width × height), e.g. 7952x5304")
    sensor_mm: tuple[float, float] = described(
        REFERENCE.sensor_mm, number=Number("mm", 0, 200, low_open=True), pair=True, label="Sensor size",
        option="--sensor-mm", metavar="WxH", group=CAMERA, tip="Sensor size in mm (width × height), e.g. 35.9x24")
    pixel_pitch_um: float | None = described(
        REFERENCE.pixel_pitch_um, number=Number("µm", 0.1, 100, low_open=True), optional="auto",
        label="Pixel pitch", option="--pixel-pitch-um", metavar="UM", group=CAMERA,
        tip="The sensor's own pixel pitch; 'auto' derives it from sensor mm / px")
    lens_name: str = described("50 mm (reference)", label="Lens", option="--lens", metavar="NAME", group=CAMERA,
                               tip="Lens preset")
    focal_length_mm: float = described(
        REFERENCE.focal_length_mm, number=Number("mm", 1, 2000), label="Focal length",
        option="--focal-length-mm", metavar="MM", group=CAMERA, tip="Focal length f of the lens")
    near_m: float = described(
        REFERENCE.near_m, number=Number("m", 0, 10_000, low_open=True), label="Near", option="--near-m",
        metavar="M", group=SCENE, tip="Nearest scene point, measured from the plane the camera moves in")
    far_m: float = described(
        REFERENCE.far_m, number=Number("m", 0, 10_000, low_open=True), label="Far", option="--far-m",
        metavar="M", group=SCENE, tip="Farthest scene point (the back wall)")
    coc_mm: float = described(
        REFERENCE.coc_mm, number=Number("mm", 0.001, 1), label="Circle of confusion", option="--coc-mm",
        metavar="MM", group=SCENE, tip="Largest blur still counted as sharp (0.029 mm is usual for full frame)")
    f_number: float | None = described(
        None, number=Number("", 0.5, 128), optional="auto (needed)", label="f-number", option="--f-number",
        metavar="N", group=SCENE, tip="Aperture to evaluate; 'auto' uses the one the scene needs")
    focus_m: float | None = described(
        None, number=Number("m", 0, 10_000, low_open=True), optional="auto (centred)", label="Focus",
        option="--focus-m", metavar="M", group=SCENE,
        tip="Focus distance; 'auto' centres the sharp range on the scene")
    grid_columns: int = described(
        REFERENCE.grid[0], number=Number("", 1, MAX_GRID_SIDE, integer=True), label="Grid", option="--grid",
        metavar="CxR", group=GRID, tip="Columns × rows of camera positions, e.g. 101x21")
    grid_rows: int = described(
        REFERENCE.grid[1], number=Number("", 1, MAX_GRID_SIDE, integer=True), label="Grid", option="--grid",
        metavar="CxR", group=GRID, tip="Columns × rows of camera positions, e.g. 101x21")
    spacing_mm: tuple[float, float] = described(
        REFERENCE.spacing_mm, number=Number("mm", 0, 100_000, low_open=True), pair=True, label="Spacing",
        option="--spacing-mm", metavar="HxV", group=GRID,
        tip="Distance between neighbouring positions (horizontal × vertical)")
    rig_name: str = described("Reference gantry", label="Rig", option="--rig-profile", metavar="NAME", group=GRID,
                              tip="Rig profile: repeatability, travel, speed, acceleration, settle")
    repeatability_um: tuple[float, float] = described(
        REFERENCE.repeatability_um, number=Number("µm", 0, 100_000), pair=True, label="Repeatability",
        option="--repeatability-um", metavar="HxV", group=GRID,
        tip="Repositioning error of each axis (horizontal × vertical)")
    travel_mm: tuple[float, float] = described(
        REFERENCE.travel_mm, number=Number("mm", 0, 1_000_000, low_open=True), pair=True, label="Travel",
        option="--travel-mm", metavar="HxV", group=GRID, tip="Usable travel of each axis")
    max_speed_mm_s: tuple[float, float] = described(
        REFERENCE.max_speed_mm_s, number=Number("mm/s", 0, 100_000, low_open=True), pair=True, label="Speed",
        option="--max-speed-mm-s", metavar="HxV", group=GRID, tip="Maximum speed of each axis")
    acceleration_mm_s2: tuple[float, float] = described(
        REFERENCE.acceleration_mm_s2, number=Number("mm/s²", 0, 1_000_000, low_open=True), pair=True,
        label="Acceleration", option="--acceleration-mm-s2", metavar="HxV", group=GRID,
        tip="Acceleration of each axis")
    settle_s: float = described(
        REFERENCE.settle_s, number=Number("s", 0, 3600), label="Settle", option="--settle-s", metavar="S",
        group=GRID, tip="Wait after each move before exposing")
    exposure_s: float = described(
        REFERENCE.exposure_s, number=Number("s", 0, 3600), label="Exposure", option="--exposure-s", metavar="S",
        group=GRID, tip="Exposure time per view")
    transfer_s: float = described(
        REFERENCE.transfer_s, number=Number("s", 0, 3600), label="Transfer", option="--transfer-s", metavar="S",
        group=GRID, tip="Trigger + download time per image (overlaps the next move)")
    max_error_px: float = described(
        0.5, number=Number("px", 0, 100, low_open=True), label="Max. repositioning error",
        option="--max-error-px", metavar="PX", group=TARGETS,
        tip="Largest image shift the axes' repeatability may cause (SPEC: 0.5 px)")
    max_disparity_px: float = described(
        1.0, number=Number("px", 0, 100_000, low_open=True), label="Max. neighbour disparity",
        option="--max-disparity-px", metavar="PX", group=TARGETS,
        tip="Wanted disparity between neighbouring views over the scene depth: proposes the spacing")
    target_parallax_fraction: float | None = described(
        None, number=Number("", 0, 100, low_open=True), optional="off", label="Wanted parallax",
        option="--parallax-fraction", metavar="F", group=TARGETS,
        tip="Wanted parallax as a fraction of the image size: proposes the grid")
    raw_bits: int = described(
        14, number=Number("bit", 1, 64, integer=True), label="Raw depth", option="--raw-bits", metavar="BITS",
        group=GRID, tip="Bits per raw sample (for the disk estimate)")
    bytes_per_image: int | None = described(
        None, number=Number("B", 1, 1e12, integer=True), optional="uncompressed raw", label="Bytes per image",
        option="--bytes-per-image", metavar="B", group=GRID, tip="File size per image")
    #: exposure bracket per view as typed ("-2,0,+2" EV around exposure_s, or "1/500,1/125,1/30s");
    #: "" for one frame per view (lfstudio.dataset.bracket)
    bracket: str = described(
        "", label="Bracket", option="--bracket", metavar="EV,...", group=GRID,
        tip="Exposure bracket at every view: EV steps around the exposure (-2,0,+2) or shutter times "
            "(1/500,1/125,1/30s); empty: one picture per view. Time and disk count every frame")

    blur_limit_px: float = described(
        0.5, number=Number("px", 0, 100, low_open=True), label="Blur limit", option="--blur-limit-px",
        metavar="PX", group=FLY, tip="Fly scanning: the most motion blur a frame may have at the near distance")
    frame_rate_fps: float | None = described(
        None, number=Number("frames/s", 0, 100_000, low_open=True), optional="1 / transfer",
        label="Frame rate", option="--frame-rate-fps", metavar="FPS", group=FLY,
        tip="Fly scanning: frames per second the camera sustains on a trigger; 'auto': one per transfer time "
            "(a tethered camera downloads each picture before the next)")
    bandwidth_mb_s: float | None = described(
        None, number=Number("MB/s", 0, 1_000_000, low_open=True), optional="no limit", label="Camera bandwidth",
        option="--bandwidth-mb-s", metavar="MBPS", group=FLY,
        tip="Fly scanning: how fast frames leave the camera (USB, GigE link); 'no limit': not a limit")
    report_rate_hz: float | None = described(
        20.0, number=Number("reports/s", 0, 100_000, low_open=True), optional="no limit",
        label="Position reports", option="--report-rate-hz", metavar="HZ", group=FLY,
        tip="Fly scanning: how often the controller reports its position (each frame's position is "
            "interpolated between two reports, so one report per grid spacing crossed at least)")
    fly_speed_mm_s: float | None = described(
        None, number=Number("mm/s", 0, 100_000, low_open=True), optional="auto (fastest)", label="Fly speed",
        option="--fly-speed-mm-s", metavar="MMS", group=FLY,
        tip="Fly scanning: the row speed; 'auto': the fastest every limit allows")

    # -- derived inputs ----------------------------------------------------------------------------
    @property
    def pixel_pitch_used_um(self) -> float:
        """The pixel pitch the formulas use: the given one, else sensor width / pixels."""
        if self.pixel_pitch_um is not None:
            return float(self.pixel_pitch_um)
        return self.sensor_mm[0] / self.sensor_px[0] * 1000.0

    @property
    def images(self) -> int:
        """Views of the grid (each may have several frames: :attr:`frames`)."""
        return int(self.grid_columns) * int(self.grid_rows)

    @property
    def bracket_value(self) -> Bracket | None:
        """The parsed bracket (None: one frame per view); raises InputError naming ``bracket``."""
        return parse_bracket(self.bracket, "bracket")

    @property
    def frames_per_view(self) -> int:
        b = self.bracket_value
        return 1 if b is None else b.frames

    @property
    def frames(self) -> int:
        """Pictures the scan takes: views × frames per view."""
        return self.images * self.frames_per_view

    def frame_exposures_s(self) -> tuple[float, ...]:
        """The shutter time of each frame of a view (``exposure_s`` × 2^EV for EV steps)."""
        b = self.bracket_value
        return (float(self.exposure_s),) if b is None else b.shutter_times_s(float(self.exposure_s))

    def replace(self, **changes: Any) -> "ScenePlan":
        return dataclasses.replace(self, **changes)

    # -- validation --------------------------------------------------------------------------------
    def validate(self, check_travel: bool = True) -> None:
        """Raise :class:`InputError` (field = attribute name, with the valid range) for the first
        impossible input. With ``check_travel``, a grid wider than the rig's travel is one too."""
        check_described(self)             # each field's own rules (its Param: range, unit, pair, optional)
        if self.near_m * 1000.0 <= 4.0 * self.focal_length_mm:
            raise InputError("near_m", f"{self.near_m:g} m is too close for a {self.focal_length_mm:g} mm lens "
                             "(the formulas assume distances much larger than the focal length)",
                             f"> {4 * self.focal_length_mm / 1000:g} m (4 × focal length)")
        if self.far_m <= self.near_m:
            raise InputError("far_m", f"{self.far_m:g} m is not beyond the near distance {self.near_m:g} m",
                             f"> {self.near_m:g} m (the near distance) and ≤ 10000 m")
        if self.focus_m is not None and self.focus_m * 1000.0 <= self.focal_length_mm:
            raise InputError("focus_m", f"{self.focus_m:g} m is inside the focal length",
                             f"> {self.focal_length_mm / 1000:g} m")
        check_grid("grid_columns", self.grid_columns, self.grid_rows)
        self.frame_exposures_s()          # a bracket that cannot be read or taken: InputError("bracket")
        if check_travel:
            problem = self.travel_problem()
            if problem is not None:
                raise InputError(*problem)

    def travel_problem(self) -> tuple[str, str, str] | None:
        """(field, message, valid) when the grid does not fit the rig's travel, else None."""
        for i, (axis, count_field) in enumerate((("horizontal", "grid_columns"), ("vertical", "grid_rows"))):
            count = int(getattr(self, count_field))
            need = optics.baseline_mm(count, self.spacing_mm[i])
            if need > self.travel_mm[i] + 1e-9:
                most = int(math.floor(self.travel_mm[i] / self.spacing_mm[i] + 1e-9)) + 1
                noun = "columns" if i == 0 else "rows"
                return (count_field,
                        f"{count} {noun} at {self.spacing_mm[i]:g} mm span {need:g} mm, beyond the "
                        f"{self.travel_mm[i]:g} mm {axis} travel of the rig",
                        f"≤ {most} {noun} at this spacing")
        return None

    # -- outputs -----------------------------------------------------------------------------------
    def derive(self, check_travel: bool = True) -> "PlanResult":
        """Validate and compute every output. Soft problems become ``PlanResult.warnings``."""
        self.validate(check_travel=check_travel)
        return _derive(self)

    # -- files and manifests -----------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """A JSON- and TOML-safe dict (lists for pairs, unset optional values left out), versioned."""
        out: dict[str, Any] = {"format": PLAN_FORMAT, "version": PLAN_VERSION}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is None:
                continue
            out[f.name] = list(value) if isinstance(value, tuple) else value
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any], base: "ScenePlan | None" = None) -> "ScenePlan":
        """The plan ``data`` describes (missing fields from ``base``, else the defaults). Raises
        :class:`InputError` for a foreign format, a newer version or a field of the wrong shape."""
        if not isinstance(data, dict):
            raise InputError("plan", "is not a table of fields", "a plan file written by lfstudio")
        fmt = data.get("format", PLAN_FORMAT)
        if fmt != PLAN_FORMAT:
            raise InputError("plan", f"format {fmt!r} is not a scene plan", f"format = {PLAN_FORMAT!r}")
        version = data.get("version", PLAN_VERSION)
        if not isinstance(version, int) or version > PLAN_VERSION:
            raise InputError("plan", f"version {version!r} is newer than this lfstudio understands",
                             f"version ≤ {PLAN_VERSION}")
        base = base or cls()
        changes: dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            if f.name not in data:
                continue
            value = data[f.name]
            current = getattr(base, f.name)
            if isinstance(current, tuple) or f.name in _PAIR_FIELDS:
                if not isinstance(value, (list, tuple)) or len(value) != 2:
                    raise InputError(f.name, f"{value!r} is not a pair", "[horizontal, vertical]")
                kind = Number(integer=f.name == "sensor_px")
                value = (kind.check(f.name, value[0]), kind.check(f.name, value[1]))
            elif f.name in ("camera_name", "lens_name", "rig_name"):
                value = str(value)
            elif f.name == "bracket":
                b = parse_bracket(value if isinstance(value, (str, list, tuple)) else str(value), "bracket")
                value = "" if b is None else b.text()
            else:                                # finite (a plan file may say nan or inf), whole where it must be
                value = Number(integer=f.name in _INT_FIELDS).check(f.name, value)
            changes[f.name] = value
        return dataclasses.replace(base, **changes)

    def camera_dict(self) -> dict[str, Any]:
        """The dataset manifest's ``camera`` entry."""
        return {"name": self.camera_name, "sensor_px": [int(v) for v in self.sensor_px],
                "sensor_mm": [float(v) for v in self.sensor_mm], "pixel_pitch_um": self.pixel_pitch_used_um}

    def lens_dict(self) -> dict[str, Any]:
        """The dataset manifest's ``lens`` entry."""
        return {"name": self.lens_name, "focal_length_mm": float(self.focal_length_mm)}

    @property
    def grid(self) -> Grid:
        """The planned grid (the dataset's model), taken in meander order: left→right, then right→left."""
        return Grid(int(self.grid_columns), int(self.grid_rows), (float(self.spacing_mm[0]), float(self.spacing_mm[1])),
                    order=DEFAULT_ORDER)

    def grid_dict(self) -> dict[str, Any]:
        """The dataset manifest's ``grid`` entry."""
        return self.grid.to_manifest()


#: every field's description (range, unit, label, tip, command-line option), in field order
PARAMS = params_of(ScenePlan)
#: how each input is called on the command line (InputError names fields by their attribute name;
#: the CLI translates with this table)
CLI_OPTION = {name: p.option for name, p in PARAMS.items()}
_INT_FIELDS = {name for name, p in PARAMS.items() if p.number is not None and p.number.integer}
_PAIR_FIELDS = {name for name, p in PARAMS.items() if p.pair}


@dataclass(frozen=True)
class PlanResult:
    """Everything a plan implies. Distances in m, pairs as {"horizontal": h, "vertical": v} dicts.
    ``dof_far_m`` is ``math.inf`` when the sharp range reaches infinity (``None`` in JSON)."""

    pixel_pitch_um: float
    image_px: tuple[int, int]
    f_number_required: float
    focus_distance_m: float
    f_number_used: float
    focus_used_m: float
    hyperfocal_m: float
    dof_near_m: float
    dof_far_m: float
    scene_sharp: bool
    airy_disk_um: float
    diffraction_f_number: float          # where the Airy disk reaches 2 pixels
    min_distance_m: float
    min_distance_axis: str
    reposition_error_px: dict[str, float]
    neighbour_disparity_px: dict[str, float]        # between near and far (what "dense" is about)
    neighbour_disparity_near_px: dict[str, float]   # of the near distance against infinity
    neighbour_disparity_far_px: dict[str, float]    # of the far distance against infinity
    baseline_mm: dict[str, float]
    row_parallax_px: float
    row_parallax_fraction: float
    column_parallax_px: float
    column_parallax_fraction: float
    images: int                                     # views of the grid
    fits_travel: bool
    capture_time_s: float
    bytes_per_image: int
    storage_bytes: int                              # every frame of every view
    proposed_spacing_mm: dict[str, float]           # for max_disparity_px between near and far
    proposed_grid: Grid | None                      # for target_parallax_fraction, at the plan's spacing
    warnings: list[PlanWarning] = field(default_factory=list)
    frames_per_view: int = 1                        # the exposure bracket's frames (1: none)
    frames: int = 0                                 # pictures the scan takes: images × frames_per_view
    frame_exposures_s: tuple[float, ...] = ()       # each frame's shutter time
    fly: Any = None                                 # the fly scan (lfstudio.planning.fly.FlyResult)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe (infinity becomes None)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "warnings":
                value = [w.to_dict() for w in value]
            elif isinstance(value, Grid):
                value = value.to_manifest()
            elif hasattr(value, "to_dict"):
                value = value.to_dict()
            elif isinstance(value, tuple):
                value = list(value)
            elif isinstance(value, float) and not math.isfinite(value):
                value = None
            out[f.name] = value
        return out

    def warnings_for(self, field_name: str) -> list[PlanWarning]:
        return [w for w in self.warnings if w.field == field_name]


def capture_time_s(plan: ScenePlan) -> float:
    """Estimated capture time of the whole grid in meander order (:func:`optics.scan_duration_s`):
    a horizontal move between the views of a row, a vertical one at each row change."""
    (sp_h, sp_v), (v_h, v_v), (a_h, a_v) = plan.spacing_mm, plan.max_speed_mm_s, plan.acceleration_mm_s2
    cols, rows = int(plan.grid_columns), int(plan.grid_rows)
    moves = [(0.0, 1), (optics.move_time_s(sp_h, v_h, a_h), rows * (cols - 1)),
             (optics.move_time_s(sp_v, v_v, a_v), rows - 1)]
    return optics.scan_duration_s(moves, plan.settle_s, optics.bracket_camera_s(plan.frame_exposures_s(),
                                                                                plan.transfer_s), plan.transfer_s)


def _fmt_m(value_m: float) -> str:
    return "∞" if math.isinf(value_m) else f"{value_m:.2f} m"


def _derive(p: ScenePlan) -> PlanResult:
    warnings: list[PlanWarning] = []
    pitch = p.pixel_pitch_used_um
    f = float(p.focal_length_mm)
    near_mm, far_mm = p.near_m * 1000.0, p.far_m * 1000.0
    width_px, height_px = int(p.sensor_px[0]), int(p.sensor_px[1])

    if p.pixel_pitch_um is not None:
        derived = p.sensor_mm[0] / p.sensor_px[0] * 1000.0
        if abs(derived - p.pixel_pitch_um) > 0.05 * p.pixel_pitch_um:
            warnings.append(PlanWarning(
                "pixel_pitch_um", f"pixel pitch {p.pixel_pitch_um:g} µm does not match the sensor "
                f"({p.sensor_mm[0]:g} mm / {width_px} px = {derived:.2f} µm): check the camera data"))

    # depth of field
    n_required = optics.f_number_for_range(near_mm, far_mm, f, p.coc_mm)
    focus_mm = optics.focus_for_range_mm(near_mm, far_mm)
    n_used = float(p.f_number) if p.f_number is not None else n_required
    focus_used_mm = p.focus_m * 1000.0 if p.focus_m is not None else focus_mm
    h_mm = optics.hyperfocal_mm(f, n_used, p.coc_mm, exact=False)
    dof_near = optics.dof_near_mm(h_mm, focus_used_mm)
    dof_far = optics.dof_far_mm(h_mm, focus_used_mm)
    tol = 1e-6
    sharp = dof_near <= near_mm * (1 + tol) and dof_far >= far_mm * (1 - tol)
    if p.focus_m is not None and focus_used_mm >= h_mm:
        warnings.append(PlanWarning(
            "focus_m", f"focus {p.focus_m:g} m is at or beyond the hyperfocal distance {h_mm / 1000:.2f} m: "
            f"sharp from {dof_near / 1000:.2f} m to infinity; focusing at {h_mm / 1000:.2f} m reaches "
            f"closer ({h_mm / 2000:.2f} m)"))
    elif p.focus_m is None and p.f_number is not None and focus_used_mm >= h_mm:
        warnings.append(PlanWarning("f_number", f"at f/{n_used:g} the focus {focus_used_mm / 1000:.2f} m is beyond "
                                    f"the hyperfocal distance {h_mm / 1000:.2f} m: sharp to infinity", "info"))
    if not sharp:
        target = "f_number" if p.f_number is not None else "focus_m"
        fix = (f"the scene needs f/{n_required:.1f} focused at {focus_mm / 1000:.2f} m"
               if p.f_number is not None and n_used < n_required - 1e-9
               else f"focus at {focus_mm / 1000:.2f} m (or stop down further)")
        warnings.append(PlanWarning(
            target, f"f/{n_used:g} focused at {focus_used_mm / 1000:.2f} m keeps only "
            f"{dof_near / 1000:.2f} m – {_fmt_m(dof_far / 1000)} sharp, not the scene "
            f"{p.near_m:g} – {p.far_m:g} m: {fix}"))

    kind, airy_um = optics.diffraction_check(n_used, p.coc_mm, pitch)
    n_diffraction = optics.diffraction_limit_f_number(2.0 * pitch)
    n_name = "f_number"
    if kind == "coc":
        warnings.append(PlanWarning(
            n_name, f"at f/{n_used:.1f} the Airy disk ({airy_um:.0f} µm) is larger than the circle of confusion "
            f"({p.coc_mm * 1000:g} µm): diffraction, not focus, limits sharpness; reduce the scene depth "
            f"or accept a larger circle of confusion"))
    elif kind == "pixels":
        warnings.append(PlanWarning(
            n_name, f"at f/{n_used:.1f} the Airy disk ({airy_um:.0f} µm) spans more than 2 pixels "
            f"({2 * pitch:.1f} µm): images are diffraction-limited beyond f/{n_diffraction:.1f}", "info"))

    # repositioning error
    eps = {a: float(p.repeatability_um[i]) for i, a in enumerate(AXES)}
    worst_axis = max(AXES, key=lambda a: eps[a])
    z_min_mm = optics.min_distance_mm(eps[worst_axis], f, pitch, p.max_error_px)
    reposition = {a: optics.reposition_error_px(eps[a], near_mm, f, pitch) for a in AXES}
    if reposition[worst_axis] > p.max_error_px * (1 + 1e-9):
        warnings.append(PlanWarning(
            "near_m", f"the {worst_axis} axis' repeatability ({eps[worst_axis]:g} µm) shows as "
            f"{reposition[worst_axis]:.2f} px at {p.near_m:g} m (target {p.max_error_px:g} px): keep the scene "
            f"beyond {z_min_mm / 1000:.2f} m or use a shorter lens"))

    # disparity and parallax
    spacing = {a: float(p.spacing_mm[i]) for i, a in enumerate(AXES)}
    counts = {"horizontal": int(p.grid_columns), "vertical": int(p.grid_rows)}
    neighbour = {a: optics.disparity_px(spacing[a], near_mm, far_mm, f, pitch) for a in AXES}
    neighbour_near = {a: optics.disparity_px(spacing[a], near_mm, math.inf, f, pitch) for a in AXES}
    neighbour_far = {a: optics.disparity_px(spacing[a], far_mm, math.inf, f, pitch) for a in AXES}
    baseline = {a: optics.baseline_mm(counts[a], spacing[a]) for a in AXES}
    row_px = optics.disparity_px(baseline["horizontal"], near_mm, far_mm, f, pitch)
    col_px = optics.disparity_px(baseline["vertical"], near_mm, far_mm, f, pitch)
    proposed_spacing = {a: optics.spacing_for_disparity_mm(p.max_disparity_px, near_mm, far_mm, f, pitch)
                        for a in AXES}
    too_sparse = [a for a in AXES if counts[a] > 1 and neighbour[a] > p.max_disparity_px * (1 + 1e-9)]
    if too_sparse:
        what = " and ".join(f"{neighbour[a]:.1f} px {a}ly" for a in too_sparse)
        warnings.append(PlanWarning(
            "spacing_mm", f"neighbours differ by {what} (wanted ≤ {p.max_disparity_px:g} px for dense sampling): "
            f"a spacing of {proposed_spacing[too_sparse[0]]:.3g} mm would give it", "info"))
    proposed_grid = None
    if p.target_parallax_fraction is not None:
        proposed_grid = dataclasses.replace(p.grid, columns=optics.positions_for_parallax(
            p.target_parallax_fraction * width_px, spacing["horizontal"], near_mm, far_mm, f, pitch),
            rows=optics.positions_for_parallax(
            p.target_parallax_fraction * height_px, spacing["vertical"], near_mm, far_mm, f, pitch))

    travel = p.travel_problem()
    if travel is not None:
        warnings.append(PlanWarning(travel[0], f"{travel[1]} ({travel[2]})", "error"))

    per_image = int(p.bytes_per_image) if p.bytes_per_image is not None else \
        optics.raw_bytes_per_image(width_px, height_px, int(p.raw_bits))

    return PlanResult(
        pixel_pitch_um=pitch, image_px=(width_px, height_px),
        f_number_required=n_required, focus_distance_m=focus_mm / 1000.0,
        f_number_used=n_used, focus_used_m=focus_used_mm / 1000.0, hyperfocal_m=h_mm / 1000.0,
        dof_near_m=dof_near / 1000.0, dof_far_m=dof_far / 1000.0, scene_sharp=sharp,
        airy_disk_um=airy_um, diffraction_f_number=n_diffraction,
        min_distance_m=z_min_mm / 1000.0, min_distance_axis=worst_axis,
        reposition_error_px=reposition, neighbour_disparity_px=neighbour,
        neighbour_disparity_near_px=neighbour_near, neighbour_disparity_far_px=neighbour_far,
        baseline_mm=baseline,
        row_parallax_px=row_px, row_parallax_fraction=row_px / width_px,
        column_parallax_px=col_px, column_parallax_fraction=col_px / height_px,
        images=p.images, fits_travel=travel is None, capture_time_s=capture_time_s(p),
        bytes_per_image=per_image, storage_bytes=per_image * p.frames,
        proposed_spacing_mm=proposed_spacing, proposed_grid=proposed_grid, warnings=warnings,
        frames_per_view=p.frames_per_view, frames=p.frames, frame_exposures_s=p.frame_exposures_s(),
        fly=plan_fly(fly_inputs_of(p)))


# -- plan files ------------------------------------------------------------------------------------


def save_plan(path: "str | Any", plan: ScenePlan) -> None:
    """Write ``plan`` atomically: TOML for a ``.toml`` name, JSON otherwise."""
    from pathlib import Path

    from lfstudio.dataset.atomic import atomic_write_json, atomic_write_text

    path = Path(path)
    if path.suffix.lower() == ".toml":
        import tomli_w

        atomic_write_text(path, "# lfstudio scene plan\n" + tomli_w.dumps(plan.to_dict()))
    else:
        atomic_write_json(path, plan.to_dict())


def load_plan(path: "str | Any") -> ScenePlan:
    """Read a plan file (TOML or JSON, by content). Raises :class:`InputError` naming the file."""
    import json
    import tomllib
    from pathlib import Path

    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(str(path), f"cannot read the plan file: {exc}", "a .toml or .json plan file") from None
    try:
        data = json.loads(text) if text.lstrip().startswith("{") else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(str(path), f"not a plan file: {exc}", "a .toml or .json plan file") from None
    except RecursionError:
        raise InputError(str(path), "not a plan file: nested too deeply", "a .toml or .json plan file") from None
    try:
        return ScenePlan.from_dict(data)
    except InputError as exc:
        raise InputError(f"{path}: {exc.field}", str(exc).split(": ", 1)[-1]) from None
