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
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any, Callable

import tomli_w

from lfstudio.dataset.atomic import atomic_write_text
from lfstudio.dataset.paths import relative_name_problem
from lfstudio.errors import InputError
from lfstudio.numbers import MAX_GRID_SIDE, PARAM, Number, Param, check_described, described, load_described

PROFILE_NAME = "processing.toml"
#: bump when the processing code changes its output for the same profile
PIPELINE_VERSION = 1


def _on(default: bool, tip: str) -> Any:
    """A step's ``enabled`` switch."""
    return described(default, flag=True, label="enabled", tip=tip)


def _setting(default: Any, tip: str, number: Number | None = None, **more: Any) -> Any:
    """One setting of a step, described once; its label is its key in words (filled in below)."""
    return described(default, number=number, tip=tip, **more)


_COORD = Number("px", -1e9, 1e9)
_LEVEL = Number("", 0, 1e9)


@dataclass
class OutputStep:
    format: str = _setting("png", "File format of the processed views: 16-bit PNG or 16-bit TIFF",
                           choices=("png", "tiff"))
    png_compression: int = _setting(1, "zlib level 0..9: 1 is fast, 9 is ~10 % smaller (the pixels are the same)",
                                    Number("", 0, 9, integer=True))
    png_strategy: str = _setting("auto", "auto: zlib's fast Huffman-only coding unless it makes bigger files; "
                                         "huffman: fastest; deflate: smallest. The pixels are the same",
                                 choices=("auto", "huffman", "deflate"))
    folder: str = _setting("processed", "Folder of the dataset the processed views go to (a plain folder name)")


@dataclass
class ReferenceStep:
    row: int = _setting(-1, "Row of the reference view (-1: middle of the grid)",
                        Number("", -1, MAX_GRID_SIDE - 1, integer=True))
    column: int = _setting(-1, "Column of the reference view (-1: middle of the grid)",
                           Number("", -1, MAX_GRID_SIDE - 1, integer=True))


@dataclass
class DebayerStep:
    enabled: bool = _on(True, "Develop the RAW captures to linear 16-bit RGB")
    white_balance: str = _setting("camera", "camera: as shot; fixed: the multipliers below; daylight: LibRaw's "
                                            "daylight balance", choices=("camera", "fixed", "daylight"))
    wb_multipliers: list[float] = _setting([2.0, 1.0, 1.5, 1.0], "R G B G2 multipliers for fixed white balance",
                                           Number("", 0, 1e9), lengths=(4,))
    half_size: bool = _setting(False, "Each 2x2 Bayer block becomes one pixel: 4x faster, half resolution "
                                      "(no demosaicing)", flag=True)
    demosaic: str = _setting("auto", "auto: at the output's resolution (luminance full size, colour at half; fast, "
                                     "at least AHD's quality for half-size output); or one of LibRaw's algorithms "
                                     "at full size", choices=("auto", "AHD", "LINEAR", "VNG", "PPG", "DHT", "AAHD"))
    color_space: str = _setting("srgb", "srgb: the camera's colour matrix is applied (linear); raw: camera RGB",
                                choices=("srgb", "raw"))


@dataclass
class LensStep:
    enabled: bool = _on(False, "Correct lens distortion and lateral chromatic aberration")
    source: str = _setting("lensfun", "lensfun: database by camera and lens name; opencv: the coefficients below",
                           choices=("lensfun", "opencv"))
    camera_maker: str = _setting("", "Lensfun's name of the camera maker; empty: from the dataset's camera")
    camera_model: str = _setting("", "Lensfun's name of the camera; empty: from the dataset's camera")
    lens_maker: str = _setting("", "Lensfun's name of the lens maker; empty: from the dataset's lens")
    lens_model: str = _setting("", "Lensfun's name of the lens; empty: from the dataset's lens")
    focal_length_mm: float = _setting(0.0, "Focal length; 0: the dataset's lens.focal_length_mm",
                                      Number("mm", 0, 10_000))
    aperture: float = _setting(8.0, "f-number the captures were taken at", Number("", 0, 1000, low_open=True))
    distance_m: float = _setting(1000.0, "Focus distance of the captures", Number("m", 0, 1e9, low_open=True))
    distortion: bool = _setting(True, "Correct the geometric distortion", flag=True)
    tca: bool = _setting(True, "Correct lateral chromatic aberration (colour fringes towards the corners)", flag=True)
    # opencv: camera matrix in full-resolution pixels (0: from the dataset / image centre)
    fx_px: float = _setting(0.0, "opencv: focal length in x (full-resolution pixels; 0: from the dataset)",
                            Number("px", 0, 1e6))
    fy_px: float = _setting(0.0, "opencv: focal length in y (full-resolution pixels; 0: from the dataset)",
                            Number("px", 0, 1e6))
    cx_px: float = _setting(0.0, "opencv: principal point x (full-resolution pixels; 0: the image centre)",
                            Number("px", 0, 1e6))
    cy_px: float = _setting(0.0, "opencv: principal point y (full-resolution pixels; 0: the image centre)",
                            Number("px", 0, 1e6))
    dist_coeffs: list[float] = _setting([0.0, 0.0, 0.0, 0.0, 0.0], "OpenCV k1 k2 p1 p2 [k3 [k4 k5 k6]] in "
                                        "full-resolution pixels", Number("", -1e9, 1e9), lengths=(4, 5, 8))
    tca_red_scale: float = _setting(1.0, "Radial magnification of red relative to green",
                                    Number("", 0, 2, low_open=True))
    tca_blue_scale: float = _setting(1.0, "Radial magnification of blue relative to green",
                                     Number("", 0, 2, low_open=True))


@dataclass
class ColorStep:
    enabled: bool = _on(True, "Map a black and a white point to the output's range")
    mode: str = _setting("auto", "How the step gets its numbers: auto (percentiles), points (picked pixels) or "
                                 "values", choices=("auto", "points", "values"))
    black_percentile: float = _setting(0.01, "auto: this percentile of the pixels becomes black", Number("%", 0, 100))
    white_percentile: float = _setting(99.99, "auto: this percentile of the pixels becomes white", Number("%", 0, 100))
    black_point_px: list[float] = _setting([0.0, 0.0], "x y of a black patch in the capture (full-resolution "
                                                       "pixels); use Pick black", _COORD, lengths=(2,))
    white_point_px: list[float] = _setting([0.0, 0.0], "x y of a white patch in the capture (full-resolution "
                                                       "pixels); use Pick white", _COORD, lengths=(2,))
    patch_px: int = _setting(5, "Side of the square averaged around a picked point", Number("px", 1, 1001, integer=True))
    black_rgb: list[float] = _setting([0.0, 0.0, 0.0], "values: R G B of black (0 … 65535)", _COORD, lengths=(3,))
    white_rgb: list[float] = _setting([65535.0, 65535.0, 65535.0], "values: R G B of white (0 … 65535)", _COORD,
                                      lengths=(3,))
    white_output: float = _setting(0.9, "The white point maps to this fraction of 65535 (headroom for highlights)",
                                   Number("", 0, 1, low_open=True))


@dataclass
class ShadingStep:
    enabled: bool = _on(False, "Divide out vignetting and uneven lighting (flat field)")
    mode: str = _setting("flat", "flat: divide by a flat image; model: a radial polynomial", choices=("flat", "model"))
    flat_file: str = _setting("", "A RAW or PNG of a uniformly lit white card, relative to the dataset folder "
                                  "(or absolute)")
    blur_px: float = _setting(0.0, "Gaussian sigma applied to the flat (0: none; keeps dust spots)",
                              Number("px", 0, 10_000))
    coefficients: list[float] = _setting([], "k1 k2 k3 of V(r) = 1 + k1 r² + k2 r⁴ + k3 r⁶; empty: fitted to the "
                                             "flat file", Number("", -1e9, 1e9), lengths=(0, 1, 2, 3))


@dataclass
class DeflickerStep:
    enabled: bool = _on(True, "Match each view's brightness to the reference view's")
    statistic: str = _setting("median_ratio", "How the gain to the reference is measured: the median of the "
                                              "per-pixel ratios (robust to moving highlights) or the ratio of the "
                                              "two images' medians", choices=("median_ratio", "median"))
    size_px: int = _setting(256, "Width of the reduced luminance image the gain is measured on",
                            Number("px", 16, 16_384, integer=True))
    low: float = _setting(0.05, "Mid-tone mask: darkest share of full scale counted", Number("", 0, 1))
    high: float = _setting(0.9, "Mid-tone mask: brightest share of full scale counted", Number("", 0, 1))


@dataclass
class RectifyStep:
    enabled: bool = _on(True, "Warp each view onto the rectified grid (needs a calibration)")
    interpolation: str = _setting("linear", "Interpolation of the warp", choices=("linear", "cubic", "lanczos"))


@dataclass
class ResampleStep:
    enabled: bool = _on(True, "Downsample the views (area averaging)")
    scale: float = _setting(0.5, "Output size relative to the full-resolution capture (0.5: half, as in the paper)",
                            Number("", 0, 1, low_open=True))


STEP_TYPES: dict[str, type] = {
    "output": OutputStep, "reference": ReferenceStep, "debayer": DebayerStep, "lens": LensStep,
    "color": ColorStep, "shading": ShadingStep, "deflicker": DeflickerStep, "rectify": RectifyStep,
    "resample": ResampleStep,
}
#: the seven steps of the paper, in its order (for display)
PAPER_STEPS = ("debayer", "lens", "color", "shading", "deflicker", "rectify", "resample")


def _labelled() -> dict[tuple[str, str], Param]:
    """Every setting's description, ``{(step, key): Param}``, its label its key in words (the dialog's
    rows and messages say "white output")."""
    out = {}
    for step, cls in STEP_TYPES.items():
        for f in dataclasses.fields(cls):
            param = f.metadata[PARAM]
            if not param.label:
                param = replace(param, label=f.name.replace("_", " "))
                f.metadata = MappingProxyType({**f.metadata, PARAM: param})
            out[(step, f.name)] = param
    return out


#: the one description of every setting of a profile (validator, loader, the dialog's editors and
#: ``lfstudio process``'s options come from it)
PARAMS: dict[tuple[str, str], Param] = _labelled()
#: the numeric settings' ranges (what an editor lets one enter), from the descriptions
LIMITS: dict[tuple[str, str], Number] = {k: p.number for k, p in PARAMS.items()
                                         if p.number is not None and not p.lengths}


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
            check_described(step, lambda key, step_name=name: field(step_name, key))
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
    """One step from its table, through the one loader of described settings."""
    return step_type(**load_described(step_type, values, lambda key: field(name, key)))
