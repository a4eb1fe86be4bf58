"""The processing profile: every step switchable and parameterised, stored as ``processing.toml``.

A profile is plain data (dataclasses of TOML-able values). :meth:`Profile.effective` drops the
parameters of disabled steps, and :meth:`Profile.sha256` hashes that canonical form, so changing a
parameter of a step that is switched off does not make finished views look stale.

Coordinates of picked points are in full-resolution captured pixels (OpenCV convention: the centre
of the top-left pixel is (0, 0)).

``processing.toml`` is a file of the dataset folder that more than the processing stage reads (an
export of raw views develops them with its ``[debayer]`` settings, the quality check reads the
de-flicker reference), so its model lives here, below every stage; the steps themselves are in
:mod:`lfstudio.processing`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import tomli_w

from lfstudio.dataset.atomic import atomic_write_text
from lfstudio.dataset.paths import relative_name_problem
from lfstudio.errors import InputError
from lfstudio.numbers import Number

PROFILE_NAME = "processing.toml"
#: any number in a profile: finite and of a sane size (each step checks its own range on top)
PROFILE_FLOAT = Number("", -1e9, 1e9)
PROFILE_INT = Number("", -1_000_000_000, 1_000_000_000, integer=True)
#: bump when the processing code changes its output for the same profile
PIPELINE_VERSION = 1


@dataclass
class OutputStep:
    format: str = "png"             # png | tiff
    png_compression: int = 1        # zlib level 0..9 (1: fast, files ~10 % larger than 9)
    png_strategy: str = "auto"      # auto (Huffman-only when not >2 % larger) | huffman (fastest) | deflate
    folder: str = "processed"


@dataclass
class ReferenceStep:
    row: int = -1                   # -1: the middle of the grid
    column: int = -1


@dataclass
class DebayerStep:
    enabled: bool = True
    white_balance: str = "camera"   # camera | fixed | daylight
    wb_multipliers: list[float] = field(default_factory=lambda: [2.0, 1.0, 1.5, 1.0])  # R G B G2 for "fixed"
    half_size: bool = False         # 2x2 Bayer block -> one pixel, no interpolation (fast)
    demosaic: str = "auto"          # auto (at the output's resolution, see debayer.py) | AHD | LINEAR | VNG | PPG | DHT | AAHD
    color_space: str = "srgb"       # srgb (camera matrix applied, linear) | raw (camera RGB, no matrix)


@dataclass
class LensStep:
    enabled: bool = False
    source: str = "lensfun"         # lensfun | opencv
    camera_maker: str = ""          # lensfun names; empty: from the dataset's camera/lens
    camera_model: str = ""
    lens_maker: str = ""
    lens_model: str = ""
    focal_length_mm: float = 0.0    # 0: the dataset's lens.focal_length_mm
    aperture: float = 8.0
    distance_m: float = 1000.0
    distortion: bool = True
    tca: bool = True                # lateral chromatic aberration
    # opencv: camera matrix in full-resolution pixels (0: from the dataset / image centre)
    fx_px: float = 0.0
    fy_px: float = 0.0
    cx_px: float = 0.0
    cy_px: float = 0.0
    dist_coeffs: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0, 0.0])  # k1 k2 p1 p2 k3
    tca_red_scale: float = 1.0      # radial magnification of red relative to green
    tca_blue_scale: float = 1.0


@dataclass
class ColorStep:
    enabled: bool = True
    mode: str = "auto"              # auto (percentiles) | points (picked pixels) | values
    black_percentile: float = 0.01
    white_percentile: float = 99.99
    black_point_px: list[float] = field(default_factory=lambda: [0.0, 0.0])
    white_point_px: list[float] = field(default_factory=lambda: [0.0, 0.0])
    patch_px: int = 5               # side of the square averaged around a picked point
    black_rgb: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])        # mode "values"
    white_rgb: list[float] = field(default_factory=lambda: [65535.0, 65535.0, 65535.0])
    white_output: float = 0.9       # the white point maps to this fraction of 65535 (headroom)


@dataclass
class ShadingStep:
    enabled: bool = False
    mode: str = "flat"              # flat (divide by a flat image) | model (radial polynomial)
    flat_file: str = ""             # relative to the dataset folder, or absolute; RAW or PNG/TIFF
    blur_px: float = 0.0            # Gaussian sigma applied to the flat (0: none; keeps dust spots)
    coefficients: list[float] = field(default_factory=list)  # k1 k2 k3 of 1+k1 r^2+k2 r^4+k3 r^6; empty: fit to flat_file


@dataclass
class DeflickerStep:
    enabled: bool = True
    statistic: str = "median_ratio"  # median_ratio (per pixel, robust) | median (ratio of medians)
    size_px: int = 256               # width of the downsampled luminance the gain is measured on
    low: float = 0.05                # mid-tone mask, as fractions of full scale
    high: float = 0.9


@dataclass
class RectifyStep:
    enabled: bool = True
    interpolation: str = "linear"    # linear | cubic | lanczos


@dataclass
class ResampleStep:
    enabled: bool = True
    scale: float = 0.5               # output size relative to the full-resolution capture


STEP_TYPES: dict[str, type] = {
    "output": OutputStep, "reference": ReferenceStep, "debayer": DebayerStep, "lens": LensStep,
    "color": ColorStep, "shading": ShadingStep, "deflicker": DeflickerStep, "rectify": RectifyStep,
    "resample": ResampleStep,
}
#: the seven steps of the paper, in its order (for display)
PAPER_STEPS = ("debayer", "lens", "color", "shading", "deflicker", "rectify", "resample")

_CHOICES = {
    ("output", "format"): ("png", "tiff"),
    ("debayer", "white_balance"): ("camera", "fixed", "daylight"),
    ("debayer", "demosaic"): ("auto", "AHD", "LINEAR", "VNG", "PPG", "DHT", "AAHD"),
    ("output", "png_strategy"): ("auto", "huffman", "deflate"),
    ("debayer", "color_space"): ("srgb", "raw"),
    ("lens", "source"): ("lensfun", "opencv"),
    ("color", "mode"): ("auto", "points", "values"),
    ("shading", "mode"): ("flat", "model"),
    ("deflicker", "statistic"): ("median_ratio", "median"),
    ("rectify", "interpolation"): ("linear", "cubic", "lanczos"),
}
_LENGTHS = {("debayer", "wb_multipliers"): 4, ("lens", "dist_coeffs"): (4, 5, 8), ("color", "black_point_px"): 2,
            ("color", "white_point_px"): 2, ("color", "black_rgb"): 3, ("color", "white_rgb"): 3}


#: ranges of the numeric settings: what :meth:`Profile.validate` accepts and what an editor lets one enter
LIMITS: dict[tuple[str, str], Number] = {
    ("output", "png_compression"): Number("", 0, 9, integer=True),
    ("reference", "row"): Number("", -1, integer=True), ("reference", "column"): Number("", -1, integer=True),
    ("lens", "focal_length_mm"): Number("mm", 0, 10_000), ("lens", "aperture"): Number("", 0, 1000, low_open=True),
    ("lens", "distance_m"): Number("m", 0, 1e9, low_open=True),
    ("lens", "fx_px"): Number("px", 0, 1e6), ("lens", "fy_px"): Number("px", 0, 1e6),
    ("lens", "cx_px"): Number("px", 0, 1e6), ("lens", "cy_px"): Number("px", 0, 1e6),
    ("lens", "tca_red_scale"): Number("", 0, 2, low_open=True),
    ("lens", "tca_blue_scale"): Number("", 0, 2, low_open=True),
    ("color", "black_percentile"): Number("%", 0, 100), ("color", "white_percentile"): Number("%", 0, 100),
    ("color", "patch_px"): Number("px", 1, 1001, integer=True),
    ("color", "white_output"): Number("", 0, 1, low_open=True),
    ("shading", "blur_px"): Number("px", 0, 10_000),
    ("deflicker", "size_px"): Number("px", 16, 16_384, integer=True),
    ("deflicker", "low"): Number("", 0, 1), ("deflicker", "high"): Number("", 0, 1),
    ("resample", "scale"): Number("", 0, 1, low_open=True),
}


def file_field(source: str) -> Callable[[str, str], str]:
    """How a profile file names a setting in messages: ``processing.toml: [color] white_output``."""
    return lambda step, key: f"{source}: [{step}] {key}"


@dataclass
class Profile:
    output: OutputStep = field(default_factory=OutputStep)
    reference: ReferenceStep = field(default_factory=ReferenceStep)
    debayer: DebayerStep = field(default_factory=DebayerStep)
    lens: LensStep = field(default_factory=LensStep)
    color: ColorStep = field(default_factory=ColorStep)
    shading: ShadingStep = field(default_factory=ShadingStep)
    deflicker: DeflickerStep = field(default_factory=DeflickerStep)
    rectify: RectifyStep = field(default_factory=RectifyStep)
    resample: ResampleStep = field(default_factory=ResampleStep)

    # -- conversion ----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, dict[str, Any]]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = PROFILE_NAME,
                  field: Callable[[str, str], str] | None = None) -> "Profile":
        """Build and validate a profile; unknown or mistyped keys raise :class:`InputError`.

        ``field(step, key)`` names a setting in messages (default: as in the file,
        ``processing.toml: [color] white_output``; an editor passes the labels it shows)."""
        if not isinstance(data, dict):
            raise InputError(source, "must be a table of steps")
        field = field or file_field(source)
        steps: dict[str, Any] = {}
        for name, values in data.items():
            if name not in STEP_TYPES:
                raise InputError(f"{source}: [{name}]", "unknown section", ", ".join(STEP_TYPES))
            if not isinstance(values, dict):
                raise InputError(f"{source}: [{name}]", "must be a table")
            steps[name] = _build_step(name, STEP_TYPES[name], values, field)
        profile = cls(**steps)
        profile.validate(source, field)
        return profile

    def validate(self, source: str = PROFILE_NAME, field: Callable[[str, str], str] | None = None) -> None:
        field = field or file_field(source)
        for name in STEP_TYPES:
            step = getattr(self, name)
            for f in dataclasses.fields(step):
                value = getattr(step, f.name)
                where = field(name, f.name)
                choices = _CHOICES.get((name, f.name))
                if choices and value not in choices:
                    raise InputError(where, f"{value!r} is not known", ", ".join(choices))
                length = _LENGTHS.get((name, f.name))
                if length is not None:
                    ok = len(value) in length if isinstance(length, tuple) else len(value) == length
                    if not ok:
                        raise InputError(where, f"has {len(value)} numbers", f"{length} numbers")
                limits = LIMITS.get((name, f.name))
                if limits is not None:
                    limits.check(where, value)
        folder_problem = relative_name_problem(self.output.folder) if self.output.folder else None
        if folder_problem:
            raise InputError(field("output", "folder"), f"{self.output.folder!r} {folder_problem}",
                             'a folder name such as "processed"')
        if not self.deflicker.low < self.deflicker.high:
            raise InputError(field("deflicker", "low/high"), "need low < high")
        if not self.color.black_percentile < self.color.white_percentile:
            raise InputError(field("color", "black_percentile/white_percentile"), "need black < white")
        if self.shading.enabled and self.shading.mode == "flat" and not self.shading.flat_file:
            raise InputError(field("shading", "flat_file"),
                             "shading mode 'flat' needs a flat image (a RAW or PNG of a uniformly lit white card)")
        if self.shading.coefficients and len(self.shading.coefficients) > 3:
            raise InputError(field("shading", "coefficients"), "too many", "up to 3 numbers k1 k2 k3")
        if self.shading.enabled and self.shading.mode == "model" and not self.shading.coefficients \
                and not self.shading.flat_file:
            raise InputError(field("shading", "coefficients"),
                             "mode 'model' needs coefficients or a flat_file to fit them to")

    # -- files ---------------------------------------------------------------------------------
    def to_toml(self) -> str:
        return ("# lfstudio processing profile: each [step] can be switched off with enabled = false\n"
                + tomli_w.dumps(self.to_dict()))

    @classmethod
    def from_toml(cls, text: str, source: str = PROFILE_NAME) -> "Profile":
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise InputError(source, f"is not valid TOML ({exc})") from None
        except RecursionError:
            raise InputError(source, "is not a processing profile: nested too deeply") from None
        return cls.from_dict(data, source)

    @classmethod
    def load(cls, path: str | Path) -> "Profile":
        path = Path(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise InputError(str(path), f"cannot be read ({exc.strerror}); give an existing profile file") from None
        except UnicodeDecodeError as exc:
            raise InputError(str(path), f"is not UTF-8 text (byte {exc.start}); save it as a UTF-8 TOML file") from None
        return cls.from_toml(text, str(path))

    def save(self, path: str | Path) -> Path:
        return atomic_write_text(path, self.to_toml())

    @classmethod
    def for_dataset(cls, root: str | Path) -> "Profile":
        """The dataset's ``processing.toml``, or the defaults if it has none."""
        path = Path(root) / PROFILE_NAME
        return cls.load(path) if path.is_file() else cls()

    # -- identity ------------------------------------------------------------------------------
    def effective(self) -> dict[str, Any]:
        """The profile as it acts: disabled steps reduced to ``{"enabled": False}``."""
        out: dict[str, Any] = {}
        for name, values in self.to_dict().items():
            if values.get("enabled", True) is False:
                out[name] = {"enabled": False}
            else:
                out[name] = values
        if not self.shading.enabled or self.shading.mode == "model" and self.shading.coefficients:
            out["shading"].pop("flat_file", None)
        out["output"].pop("png_compression", None)  # lossless either way: same pixels
        out["output"].pop("png_strategy", None)
        return out

    def sha256(self, extra: dict[str, Any] | None = None) -> str:
        """Stable hash of the effective profile (plus ``extra``, e.g. the calibration it used)."""
        doc = {"pipeline_version": PIPELINE_VERSION, "profile": self.effective(), "extra": extra or {}}
        text = json.dumps(doc, sort_keys=True, separators=(",", ":"), default=float)
        return hashlib.sha256(text.encode("utf-8")).hexdigest()

    def copy(self) -> "Profile":
        return Profile.from_dict(self.to_dict())


def _build_step(name: str, step_type: type, values: dict[str, Any], field: Callable[[str, str], str]) -> Any:
    defaults = step_type()
    kwargs: dict[str, Any] = {}
    known = {f.name for f in dataclasses.fields(step_type)}
    for key, value in values.items():
        where = field(name, key)
        if key not in known:
            raise InputError(where, "unknown setting", ", ".join(sorted(known)))
        default = getattr(defaults, key)
        kwargs[key] = _coerce(where, default, value)
    return step_type(**kwargs)


def _coerce(where: str, default: Any, value: Any) -> Any:
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise InputError(where, f"must be true or false, found {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise InputError(where, f"must be a whole number, found {value!r}")
        return PROFILE_INT.check(where, value)
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(where, f"must be a number, found {value!r}")
        return PROFILE_FLOAT.check(where, value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise InputError(where, f"must be a text, found {value!r}")
        return value
    if isinstance(default, list):
        if not isinstance(value, list) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                  for v in value):
            raise InputError(where, f"must be a list of numbers, found {value!r}")
        return [PROFILE_FLOAT.check(where, v) for v in value]
    return value
