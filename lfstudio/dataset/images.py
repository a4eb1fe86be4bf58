"""Reading a capture: the one place lfstudio decodes an image file.

What a file is, is decided by trying it, never by its name: a file LibRaw opens is a camera RAW
(every format LibRaw reads, whatever its suffix: a Canon ``.CRW``, a Minolta ``.MRW``, a DNG named
``.nef``), unless its own structure says it is an ordinary TIFF picture (:func:`plain_tiff`: LibRaw
opens an uncompressed 16-bit grey TIFF as a mosaic); otherwise a file OpenCV has a decoder for (PNG,
TIFF, JPEG, ...) is an ordinary image;
anything else is not a capture (:class:`NotACapture`, naming the file). The answer is remembered
per file, size and modification time.

- :func:`kind`, :func:`is_raw`: ``"raw"`` or ``"image"``;
- :func:`full_size_px`: (width, height) the file decodes to at full resolution, from its headers
  (RAW: LibRaw's size with the orientation tag applied); :func:`check_raw_data`: a RAW's image data
  is all there (LibRaw unpacks it);
- :func:`read_image`: an ordinary image as (h, w, 3) uint16 RGB (16-bit kept, 8-bit scaled by 257);
- :func:`develop`: any capture as (h, w, 3) uint16 linear RGB: a RAW developed by LibRaw with the
  ``[debayer]`` settings of a processing profile (:class:`lfstudio.dataset.profile.DebayerStep`),
  an ordinary image as :func:`read_image`;
- :func:`read_bayer`: a RAW's Bayer mosaic with LibRaw's black level, white balance and scaling
  (the processing demosaics it at the output's resolution; the quality check reads luminance from it);
- :func:`read_grey`: a capture as a grey 8-bit working image for feature detection;
- :func:`thumbnail_array`, :func:`thumbnail_from_array`: small BGR pictures for the grid
  (:mod:`lfstudio.dataset.thumbs` writes and caches them); :func:`preview_rgb8`: an 8-bit picture to
  look at (test shots, a view at full size); :func:`read_picture`: a picture lfstudio wrote itself
  (a cached thumbnail, a quality map).

Linear output: ``gamma=(1, 1)``, ``no_auto_bright``, ``output_bps=16``; the RAW's white level maps
to 65535. The RAW's orientation tag is applied.
"""

from __future__ import annotations

import functools
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from lfstudio.dataset.paths import RENAME_UTF8_FIX, is_utf8_name, shown_name
from lfstudio.dataset.profile import DebayerStep
from lfstudio.errors import DatasetError

#: the LibRaw algorithm a full-resolution develop uses for each profile choice that is not one
FULL_SIZE_DEMOSAIC = {"auto": "AHD"}
#: what :func:`develop` and :func:`read_bayer` use when no profile is given
DEFAULT_DEBAYER = DebayerStep()


class NotACapture(DatasetError):
    """A file that is neither a RAW LibRaw reads nor an image OpenCV reads; ``reason`` says so."""

    kind = "not-a-capture"

    def __init__(self, path: str | os.PathLike, reason: str = "neither LibRaw (camera RAW) nor OpenCV (PNG, "
                                                               "TIFF, JPEG) reads it"):
        self.path, self.reason = Path(path), reason
        super().__init__(f"{shown_name(self.path)}: not an image: {reason}")


#: why a file whose name is not UTF-8 is no capture lfstudio can read (:func:`cv_path`)
NOT_UTF8_REASON = f"its name is not valid UTF-8, which the image libraries cannot open; {RENAME_UTF8_FIX}"


def cv_path(path: str | os.PathLike) -> str:
    """``path`` as the text OpenCV and LibRaw are given; :class:`NotACapture` naming it (escaped) when
    it is not valid UTF-8: OpenCV crashes the whole process on such a name (a segmentation fault),
    so no name from outside reaches it unchecked."""
    text = os.fspath(path)
    if not is_utf8_name(text):
        raise NotACapture(text, NOT_UTF8_REASON)
    return text


# -- what a file is ----------------------------------------------------------------------------------
@functools.lru_cache(maxsize=4096)
def _kind(path: str, size: int, mtime_ns: int) -> str | None:
    import rawpy

    try:
        with rawpy.imread(path):
            opened = True
    except Exception:   # LibRaw raises several error types for a file it does not read
        opened = False
    if opened and not plain_tiff(path):
        return "raw"
    return "image" if cv2.haveImageReader(path) else None


#: TIFF tags and values that only a camera RAW has (DNG, or a maker's TIFF-based RAW)
_DNG_VERSION, _SUB_IFDS, _MAKER_NOTE = 50706, 330, 37500
#: photometric interpretations of an ordinary picture (not 32803 CFA, 34892 LinearRaw, ...)
_PICTURE_PHOTOMETRIC = {0, 1, 2, 3, 5, 6, 8}
#: compressions an ordinary TIFF writer uses (not a maker's own, e.g. 34713 NEF, 32767 Sony ARW)
_PICTURE_COMPRESSION = {1, 2, 3, 4, 5, 7, 8, 32773, 32946, 34925, 50000, 50001}


def plain_tiff(path: str | os.PathLike) -> bool:
    """True for an ordinary TIFF picture (what an image program or OpenCV writes): every directory an
    ordinary picture (grey, RGB, palette, CMYK, YCbCr or Lab, a standard compression), no DNG version,
    no sub-directories, no maker note, not a Canon CR2. LibRaw opens an uncompressed 16-bit grey TIFF
    as if it were a RAW mosaic; such a file is an image, whatever LibRaw says. Any doubt (another
    format, a header tifffile cannot read, anything a RAW has): False, and LibRaw decides."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(10)
        if head[:4] not in (b"II*\x00", b"MM\x00*") or head[8:10] == b"CR":
            return False
        import tifffile

        with tifffile.TiffFile(path) as tif:
            for page in tif.pages:
                if not isinstance(page, tifffile.TiffPage):
                    return False
                tags = page.tags
                if any(t in tags for t in (_DNG_VERSION, _SUB_IFDS, _MAKER_NOTE)):
                    return False
                if int(page.photometric) not in _PICTURE_PHOTOMETRIC or \
                        int(page.compression) not in _PICTURE_COMPRESSION:
                    return False
        return True
    except Exception:  # noqa: BLE001 - a header tifffile does not read: not known to be a plain picture
        return False


def kind(path: str | os.PathLike) -> str:
    """``"raw"`` (LibRaw opens it) or ``"image"`` (OpenCV has a decoder for it); :class:`NotACapture`
    otherwise, or when the file cannot be opened at all."""
    path = Path(path)
    try:
        st = path.stat()
    except OSError as exc:
        raise NotACapture(path, exc.strerror or "cannot be opened") from None
    found = _kind(cv_path(path), st.st_size, st.st_mtime_ns)
    if found is None:
        raise NotACapture(path)
    return found


def is_text(path: str | os.PathLike) -> bool:
    """A text file (notes, XMP sidecars, JSON): its first 4 KiB are UTF-8 without a NUL byte. Every
    image and RAW format starts with binary data; an empty file is not text."""
    import codecs

    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return False
    if not head or b"\x00" in head:
        return False
    try:
        codecs.getincrementaldecoder("utf-8")().decode(head, final=False)
    except UnicodeDecodeError:
        return False
    return True


def is_raw(path: str | os.PathLike) -> bool:
    """True for a file LibRaw reads; False for anything else (an image, or no capture at all)."""
    try:
        return kind(path) == "raw"
    except NotACapture:
        return False


# -- sizes -------------------------------------------------------------------------------------------
def full_size_px(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) of the full-resolution image the file decodes to, read cheaply (LibRaw's
    sizes, the PNG/JPEG/TIFF header); :class:`DatasetError` naming the file if unreadable
    (:class:`NotACapture` when it is no image at all)."""
    path = Path(path)
    if kind(path) == "raw":
        import rawpy

        try:
            with rawpy.imread(str(path)) as raw:
                w, h = int(raw.sizes.width), int(raw.sizes.height)
                return (h, w) if raw.sizes.flip in (5, 6) else (w, h)  # portrait orientation tag
        except Exception as exc:
            raise DatasetError(f"{path}: cannot be read as a RAW file ({exc}); re-capture or remove the view") from None
    size = _header_size_px(path)
    if size is not None:
        return size
    img = read_image(path)
    return int(img.shape[1]), int(img.shape[0])


def check_raw_data(path: str | os.PathLike) -> None:
    """For a RAW: LibRaw unpacks its image data (a file cut short or damaged after its headers opens,
    and fails only here); :class:`DatasetError` naming the file when it does not. For a PNG or a JPEG:
    the file is all there (:func:`cut_short`, from its structure, without decoding: a decoder would
    print libpng's own error line on stderr). Costs one read of a RAW (and LibRaw's decompression)."""
    path = Path(path)
    if kind(path) != "raw":
        why = cut_short(path)
        if why:
            raise DatasetError(f"{shown_name(path)}: {why}; the file is cut short or damaged")
        return
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:
            raw.unpack()
    except Exception as exc:
        raise DatasetError(f"{path}: LibRaw cannot read its image data ({type(exc).__name__}: {exc}); "
                           "the file is cut short or damaged") from None


def cut_short(path: str | os.PathLike) -> str | None:
    """Why a PNG or JPEG file is not all there, or None (complete, or another format): a PNG's chunks
    are walked by their lengths to its IEND chunk (only the 12-byte chunk headers are read); a JPEG
    must hold its end-of-image marker (FF D9) in its last 64 KiB (cameras may pad after it)."""
    try:
        with open(path, "rb", buffering=0) as fh:    # unbuffered: 12 bytes a chunk, not 8 KiB after each seek
            size = os.fstat(fh.fileno()).st_size
            head = fh.read(8)
            if head == b"\x89PNG\r\n\x1a\n":
                pos = 8
                while True:
                    chunk = os.pread(fh.fileno(), 8, pos)
                    if len(chunk) < 8:
                        return f"its PNG data ends after {size} bytes, before the IEND chunk"
                    length = int.from_bytes(chunk[:4], "big")
                    pos += 12 + length
                    if pos > size:
                        return f"its PNG chunk {chunk[4:8].decode('latin-1')!r} needs {pos} bytes, the file has {size}"
                    if chunk[4:8] == b"IEND":
                        return None
            if head[:2] == b"\xff\xd8":
                fh.seek(max(0, size - 65536))
                if b"\xff\xd9" not in fh.read():
                    return "its JPEG data has no end (no end-of-image marker)"
    except OSError as exc:
        return exc.strerror or "it cannot be read"
    return None


def png_header(path: str | os.PathLike) -> tuple[int, int, int, int] | None:
    """(width, height, bit depth, colour type) of a PNG from its IHDR, or None if not a PNG."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(26)
    except OSError:
        return None
    if len(head) < 26 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big"), head[24], head[25]


def _header_size_px(path: Path) -> tuple[int, int] | None:
    """(width, height) from a PNG, JPEG or TIFF header, or None (another format, or not readable so)."""
    png = png_header(path)
    if png is not None:
        return png[0], png[1]
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
            if head[:2] == b"\xff\xd8":
                fh.seek(0)
                return _jpeg_size(fh)
        if head[:4] in (b"II*\x00", b"MM\x00*"):
            import tifffile

            with tifffile.TiffFile(path) as tif:
                page = tif.pages[0]
                if isinstance(page, tifffile.TiffPage):     # the first page always is (not a TiffFrame)
                    return int(page.imagewidth), int(page.imagelength)
    except Exception:  # a truncated or odd header: the decoder decides
        return None
    return None


def _jpeg_size(fh) -> tuple[int, int] | None:
    fh.read(2)
    while True:
        b = fh.read(1)
        while b and b != b"\xff":
            b = fh.read(1)
        while b == b"\xff":
            b = fh.read(1)
        if not b:
            return None
        marker = b[0]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            continue
        length_bytes = fh.read(2)
        if len(length_bytes) < 2:
            return None
        length = int.from_bytes(length_bytes, "big")
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            data = fh.read(5)
            if len(data) < 5:
                return None
            return int.from_bytes(data[3:5], "big"), int.from_bytes(data[1:3], "big")
        fh.seek(length - 2, os.SEEK_CUR)


# -- decoding ----------------------------------------------------------------------------------------
def read_image(path: str | os.PathLike) -> np.ndarray:
    """A PNG/TIFF/JPEG as (h, w, 3) uint16 RGB (8-bit images scaled by 257, 16-bit kept)."""
    img = cv2.imread(cv_path(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DatasetError(f"{path}: cannot be read as an image; check the file or re-capture the view")
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    else:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    if img.dtype == np.uint8:
        img = img.astype(np.uint16) * 257
    elif img.dtype != np.uint16:
        img = np.clip(img.astype(np.float64) * (65535.0 if img.dtype.kind == "f" else 1.0), 0, 65535) \
            .astype(np.uint16)
    return img


def _params(step: DebayerStep):
    import rawpy

    # adjust_maximum_thr=0: scale by the RAW's white level, never by the image's own maximum (LibRaw's
    # default rescales images with clipped pixels: a brightness jump between views of one scene)
    kw: dict[str, Any] = dict(gamma=(1, 1), no_auto_bright=True, output_bps=16, adjust_maximum_thr=0.0,
              half_size=step.half_size,
              output_color=rawpy.ColorSpace.raw if step.color_space == "raw" else rawpy.ColorSpace.sRGB,
              demosaic_algorithm=getattr(rawpy.DemosaicAlgorithm, FULL_SIZE_DEMOSAIC.get(step.demosaic, step.demosaic)))
    if step.white_balance == "camera":
        kw["use_camera_wb"] = True
    elif step.white_balance == "fixed":
        kw["user_wb"] = [float(v) for v in step.wb_multipliers]
    return rawpy.Params(**kw)


def develop(path: str | os.PathLike, step: DebayerStep = DEFAULT_DEBAYER) -> np.ndarray:
    """(h, w, 3) uint16 linear RGB of one capture: a RAW developed by LibRaw with ``step``'s settings
    (``half_size``: one pixel per 2 x 2 block), an ordinary image as it is."""
    path = Path(path)
    if not is_raw(path):
        return read_image(path)
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:
            return raw.postprocess(_params(step))
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot be decoded as a RAW file ({type(exc).__name__}: {exc}); "
                           "re-capture the view or remove it from the dataset") from None


# -- the mosaic itself (demosaic at the resolution the output needs) ---------------------------------
#: OpenCV's edge-aware Bayer conversion to RGB for each 2 x 2 pattern (top-left colours, R G B);
#: OpenCV names a pattern by its second row's second and third pixels
_EA_CODES = {"RGGB": cv2.COLOR_BayerBG2RGB_EA, "BGGR": cv2.COLOR_BayerRG2RGB_EA,
             "GRBG": cv2.COLOR_BayerGB2RGB_EA, "GBRG": cv2.COLOR_BayerGR2RGB_EA}
#: LibRaw's orientation codes we turn the mosaic for (3: 180 degrees, 5: 90 counter-clockwise, 6: 90 clockwise)
_ROTATIONS = {3: cv2.ROTATE_180, 5: cv2.ROTATE_90_COUNTERCLOCKWISE, 6: cv2.ROTATE_90_CLOCKWISE}


@dataclass
class Bayer:
    """An RGB Bayer mosaic in display orientation, black level subtracted, white-balanced and
    scaled as LibRaw scales its 16-bit output (uint16, saturated), plus what it takes to finish it."""

    mosaic: np.ndarray       # (h, w) uint16
    pattern: str             # colours of the top-left 2 x 2 block, row by row: "RGGB", "GRBG", ...
    rgb_cam: np.ndarray      # 3 x 3: camera RGB -> output RGB (identity for color_space "raw")

    def site(self, colour: str) -> tuple[int, int]:
        """(dy, dx) of ``colour`` ("R" or "B") in the 2 x 2 block."""
        return divmod(self.pattern.index(colour), 2)

    @property
    def ea_code(self) -> int:
        return _EA_CODES[self.pattern]


def _white_balance(raw, step: DebayerStep) -> np.ndarray:
    """LibRaw's channel multipliers (R G B G2) for the profile's white balance setting."""
    if step.white_balance == "fixed":
        mul = np.array(step.wb_multipliers, np.float64)
    else:
        mul = np.array(raw.daylight_whitebalance, np.float64)
        if step.white_balance == "camera":
            cam = np.array(raw.camera_whitebalance, np.float64)
            if cam[0] > 0 and cam[1] > 0 and cam[2] > 0:
                mul = cam
    if mul[1] <= 0:
        mul[1] = 1.0
    if mul[3] <= 0:
        mul[3] = mul[1]
    return mul


def read_bayer(path: str | os.PathLike, step: DebayerStep = DEFAULT_DEBAYER,
               out: np.ndarray | None = None) -> Bayer | None:
    """The capture's :class:`Bayer` mosaic, written into ``out`` when it has the right shape (a
    buffer reused across views); None when the file is not an RGB Bayer RAW this can handle (then
    develop it with LibRaw, :func:`develop`)."""
    path = Path(path)
    if not is_raw(path):
        return None
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:
            desc = raw.color_desc.decode("ascii", "replace")
            pattern_idx = np.asarray(raw.raw_pattern)
            if raw.raw_type != rawpy.RawType.Flat or desc not in ("RGBG", "RGB") or pattern_idx.shape != (2, 2) \
                    or raw.sizes.pixel_aspect != 1.0 or raw.sizes.flip not in (0, *_ROTATIONS):
                return None
            pattern = "".join("RGBG"[int(i)] for i in pattern_idx.ravel())
            if pattern not in _EA_CODES:
                return None
            visible = raw.raw_image_visible
            h, w = visible.shape
            if h % 2 or w % 2:
                return None
            black = np.asarray(raw.black_level_per_channel, np.float64)
            white = float(raw.white_level)
            mul = _white_balance(raw, step)
            # LibRaw's scale_colors (highlight mode clip): (raw - black_c) * mul_c / min(mul) * 65535 / (white - black)
            scale = mul / mul.min() * 65535.0 / max(white - black.min(), 1.0)
            rgb_cam = np.eye(3) if step.color_space == "raw" else np.asarray(raw.color_matrix, np.float64)[:, :3]
            flip = raw.sizes.flip
            mosaic = out if flip == 0 and out is not None and out.shape == (h, w) and out.dtype == np.uint16 \
                else np.empty((h, w), np.uint16)
            pairs_in = visible.reshape(h, w // 2, 2)          # (even column, odd column) as two channels
            pairs_out = mosaic.reshape(h, w // 2, 2)
            for dy in (0, 1):
                c0, c1 = (int(pattern_idx[dy, dx]) for dx in (0, 1))
                M = np.array([[scale[c0], 0.0, -black[c0] * scale[c0]], [0.0, scale[c1], -black[c1] * scale[c1]]])
                cv2.transform(pairs_in[dy::2], M, dst=pairs_out[dy::2])   # rounded, saturated to 0..65535
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot be decoded as a RAW file ({type(exc).__name__}: {exc}); "
                           "re-capture the view or remove it from the dataset") from None
    if flip:
        mosaic = cv2.rotate(mosaic, _ROTATIONS[flip])
        pattern = _rotate_pattern(pattern, flip)
    return Bayer(mosaic, pattern, rgb_cam)


def _rotate_pattern(pattern: str, flip: int) -> str:
    block = np.array(list(pattern)).reshape(2, 2)
    turned = {3: np.rot90(block, 2), 5: np.rot90(block, 1), 6: np.rot90(block, -1)}[flip]
    return "".join(turned.ravel())


# -- small 8-bit pictures: thumbnails and previews -----------------------------------------------------
_JPEG_REDUCED = ((8, cv2.IMREAD_REDUCED_COLOR_8), (4, cv2.IMREAD_REDUCED_COLOR_4), (2, cv2.IMREAD_REDUCED_COLOR_2))


def shrink(rgb_or_bgr: np.ndarray, width_px: int) -> np.ndarray:
    """The image at most ``width_px`` wide (area interpolation), aspect kept; as it is when narrower."""
    h, w = rgb_or_bgr.shape[:2]
    if w <= width_px:
        return rgb_or_bgr
    height = max(1, round(h * width_px / w))
    return cv2.resize(rgb_or_bgr, (width_px, height), interpolation=cv2.INTER_AREA)


def _to_uint8(img: np.ndarray) -> np.ndarray:
    """8-bit for display: the 99.5th percentile of a deeper image becomes white."""
    if img.dtype == np.uint8:
        return img
    a = img.astype(np.float32)
    hi = float(np.percentile(a, 99.5)) or 1.0
    return np.clip(a * (255.0 / hi), 0, 255).astype(np.uint8)


def _reduced_jpeg(read, width_px: int) -> np.ndarray | None:
    """A JPEG decoded at the smallest of 1/8, 1/4, 1/2 that is still ``width_px`` wide (libjpeg
    scales while decoding); ``read(flags)`` decodes with OpenCV's flags."""
    try:
        small = read(cv2.IMREAD_REDUCED_COLOR_8)
    except cv2.error:
        return None
    if small is None:
        return None
    if small.shape[1] >= width_px:
        return small
    full_w = small.shape[1] * 8
    for factor, flags in _JPEG_REDUCED[1:]:
        if full_w // factor >= width_px:
            return read(flags)
    return read(cv2.IMREAD_COLOR)


def is_jpeg(path: str | os.PathLike) -> bool:
    """The file starts like a JPEG (SOI marker), whatever its name."""
    try:
        with open(path, "rb") as fh:
            return fh.read(2) == b"\xff\xd8"
    except OSError:
        return False


# PNG: filter types (PNG spec 9.2) and colour types this module unfilters itself
_PNG_NONE, _PNG_SUB, _PNG_UP = 0, 1, 2
_PNG_CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}      # grey, RGB, grey + alpha, RGBA


def _png_small(path: Path, width_px: int) -> np.ndarray | None:
    """A non-interlaced 8/16-bit grey or RGB(A) PNG as a BGR array at most ``width_px`` wide, in the
    file's bit depth; None when this fast path does not apply (then OpenCV decodes the file).

    The file is read once, its IDAT chunks joined, and the zlib stream inflated in one call by libdeflate into a buffer of the known size (about twice as fast
    as zlib's streaming inflate, which libpng uses). Only the rows the thumbnail needs are
    unfiltered, in numpy: rows filtered with None or Sub stand alone (a Sub row is a running sum of
    its bytes), rows filtered with Up are running sums down the column. Average and Paeth filters
    (a pixel depends on its left neighbour's *result*) are left to libpng: None.
    """
    import deflate

    with open(path, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        buf = bytearray(size)
        if fh.readinto(buf) != size:
            return None
    if size < 33 or buf[:8] != b"\x89PNG\r\n\x1a\n" or buf[12:16] != b"IHDR":
        return None
    w, h, depth, colour, _, _, interlace = struct.unpack_from(">IIBBBBB", buf, 16)
    channels = _PNG_CHANNELS.get(colour)
    if channels is None or depth not in (8, 16) or interlace != 0 or w == 0 or h == 0:
        return None
    bpp = channels * depth // 8                       # bytes per pixel
    row_bytes = 1 + w * bpp                           # a filter byte, then the row
    parts, pos, mv = [], 8, memoryview(buf)
    while pos + 8 <= size:
        n, kind_ = struct.unpack_from(">I4s", buf, pos)
        if kind_ == b"IDAT":
            parts.append(mv[pos + 8:pos + 8 + n])
        elif kind_ == b"IEND":
            break
        pos += 12 + n
    stream = b"".join(parts)
    del parts, mv, buf
    try:                                              # a writer that filters adaptively shows it early:
        head = zlib.decompressobj().decompress(stream[: 1 << 16], 8 * row_bytes)   # leave it to libpng
    except zlib.error:
        return None
    if any(b > _PNG_UP for b in head[::row_bytes]):
        return None
    try:
        raw = deflate.zlib_decompress(stream, h * row_bytes)
    except Exception:  # libdeflate: a corrupt or short stream; libpng says what is wrong
        return None
    if len(raw) != h * row_bytes:
        return None
    rows = np.frombuffer(raw, np.uint8).reshape(h, row_bytes)
    filters = rows[:, 0]
    if int(filters.max()) > _PNG_UP:
        return None
    out_w = min(width_px, w)
    out_h = max(1, round(h * out_w / w))
    up = np.flatnonzero(filters == _PNG_UP)
    # Up rows need every row above them; otherwise >= 4 source rows per thumbnail row are enough
    pick = slice(None) if up.size else slice(None, None, max(1, h // (4 * out_h)))
    sel = rows[pick, 1:].reshape(-1, w, bpp)
    sub = filters[pick] == _PNG_SUB
    if sub.all():
        sel = np.cumsum(sel, axis=1, dtype=np.uint8)  # wraps modulo 256, as the filter does
    else:
        sel = sel.copy()
        if sub.any():
            sel[sub] = np.cumsum(sel[sub], axis=1, dtype=np.uint8)
    for a, b in zip(up[np.r_[True, np.diff(up) > 1]], up[np.r_[np.diff(up) > 1, True]]) if up.size else ():
        lo = max(int(a) - 1, 0)                       # a run of Up rows adds onto the row above it
        sel[lo: b + 1] = np.cumsum(sel[lo: b + 1], axis=0, dtype=np.uint8)
    img = sel.reshape(sel.shape[0], w, channels, depth // 8)
    img = img.view(">u2")[..., 0].astype(np.uint16) if depth == 16 else img[..., 0]
    img = img[..., : 3 if channels >= 3 else 1]       # alpha is not shown
    if img.shape[:2] != (out_h, out_w):
        img = cv2.resize(img if img.shape[2] == 3 else img[..., 0], (out_w, out_h), interpolation=cv2.INTER_AREA)
    if img.ndim == 2 or img.shape[2] == 1:
        return cv2.cvtColor(img.reshape(img.shape[:2]), cv2.COLOR_GRAY2BGR)
    return np.ascontiguousarray(img[..., ::-1])     # RGB -> BGR, as OpenCV returns it


def _thumb_from_image(path: Path, width_px: int) -> np.ndarray | None:
    """BGR uint8, decoded at reduced size where the format allows it, made small before measuring."""
    if is_jpeg(path):
        img = _reduced_jpeg(lambda flags: cv2.imread(cv_path(path), flags), width_px)
        if img is not None:
            return img
    elif png_header(path) is not None:
        try:
            img = _png_small(path, width_px)
        except OSError:
            img = None
        if img is not None:
            return _to_uint8(img)
    img = cv2.imread(cv_path(path), cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
    if img is None:
        return None
    return _to_uint8(shrink(img, width_px))


def _thumb_from_raw(path: Path, width_px: int) -> np.ndarray | None:
    """BGR uint8 from a RAW file: the embedded JPEG preview if large enough, else a strided decode."""
    import rawpy

    try:
        raw = rawpy.imread(str(path))
    except Exception:
        return None
    with raw:
        try:
            thumb = raw.extract_thumb()
            if thumb.format == rawpy.ThumbFormat.JPEG:
                data = np.frombuffer(thumb.data, np.uint8)
                img = _reduced_jpeg(lambda flags: cv2.imdecode(data, flags), width_px)
                if img is not None and img.shape[1] >= width_px:
                    return img
            elif thumb.format == rawpy.ThumbFormat.BITMAP and isinstance(thumb.data, np.ndarray) \
                    and thumb.data.shape[1] >= width_px:
                return cv2.cvtColor(np.ascontiguousarray(thumb.data), cv2.COLOR_RGB2BGR)
        except Exception:
            pass
        try:
            mosaic = raw.raw_image_visible
            colors = raw.raw_colors_visible
            black = float(np.mean(raw.black_level_per_channel))
            white = float(raw.white_level)
        except Exception:
            return None
        h, w = mosaic.shape
        step = max(1, (w // 2) // (width_px * 2)) * 2     # even stride keeps the Bayer phase
        # one RGB pixel per 2x2 block, blocks taken every `step` pixels
        out = np.zeros((len(range(0, h - 1, step)), len(range(0, w - 1, step)), 3), np.float32)
        count = np.zeros_like(out)
        for dy in (0, 1):
            for dx in (0, 1):
                vals = mosaic[dy:h - 1 + dy:step, dx:w - 1 + dx:step][: out.shape[0], : out.shape[1]]
                ch = int(colors[dy, dx])
                ch = 1 if ch == 3 else ch      # second green
                out[..., ch] += vals
                count[..., ch] += 1
        rgb = out / np.maximum(count, 1)
        rgb = (rgb - black) / max(white - black, 1.0)
        # a rough grey-world balance and gamma: this is a thumbnail, not a rendering
        means = rgb.reshape(-1, 3).mean(axis=0) + 1e-6
        rgb = rgb * (means.mean() / means)
        rgb = np.clip(rgb / max(float(np.percentile(rgb, 99)), 1e-6), 0, 1) ** (1 / 2.2)
        return cv2.cvtColor((rgb * 255).astype(np.uint8), cv2.COLOR_RGB2BGR)


def thumbnail_array(path: str | os.PathLike, width_px: int) -> np.ndarray | None:
    """A BGR uint8 thumbnail of one capture, at most ``width_px`` wide (None if undecodable): an image
    decoded at reduced size where its format allows it, a RAW's embedded preview, else a strided
    decode of its mosaic (each 2 x 2 Bayer block one pixel, only every n-th block read). Made small
    first, measured (8-bit scaling) after."""
    path = Path(path)
    try:
        found = kind(path)
    except NotACapture:
        return None
    img = _thumb_from_image(path, width_px) if found == "image" else _thumb_from_raw(path, width_px)
    return None if img is None else shrink(img, width_px)


def thumbnail_from_array(rgb: np.ndarray, width_px: int) -> np.ndarray:
    """A BGR uint8 thumbnail of an RGB (or grey) array, uint8 or 16-bit at any size (a camera's
    preview, a decoded video frame): made small first, then scaled to 8 bits."""
    small = shrink(np.asarray(rgb), width_px)
    return cv2.cvtColor(_to_uint8(small), cv2.COLOR_RGB2BGR) if small.ndim == 3 else _to_uint8(small)


def decode_frame(data: bytes | memoryview) -> np.ndarray | None:
    """A camera's live-view frame (JPEG, or any format OpenCV decodes, in memory) as (h, w, 3) uint8
    RGB; None when it cannot be decoded."""
    img = cv2.imdecode(np.frombuffer(memoryview(data), np.uint8), cv2.IMREAD_COLOR)
    return None if img is None else cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def read_picture(path: str | os.PathLike) -> np.ndarray | None:
    """A picture lfstudio wrote itself (a cached or stored JPEG thumbnail, a quality map PNG) as
    (h, w, 3) BGR uint8; None when it is missing or unreadable (the caller makes it again). Not for
    captures: no LibRaw probe, no bit depth kept."""
    return cv2.imread(cv_path(path), cv2.IMREAD_COLOR)


def preview_rgb8(path: str | os.PathLike, max_width_px: int | None = None, stretch: bool = False) -> np.ndarray:
    """An 8-bit sRGB picture of a capture to look at (test shots, a view at full size): a RAW
    developed by LibRaw at half size with the camera's white balance and no automatic brightening
    (clipping stays visible), an ordinary image as it is (16-bit divided by 257, or with ``stretch``
    scaled so that its brightest pixel is white: linear views); at most ``max_width_px`` wide."""
    path = Path(path)
    if kind(path) == "raw":
        import rawpy

        try:
            with rawpy.imread(str(path)) as raw:
                rgb = raw.postprocess(half_size=True, use_camera_wb=True, no_auto_bright=True, output_bps=8,
                                      adjust_maximum_thr=0.0)
        except Exception as exc:  # LibRaw raises several error types
            raise DatasetError(f"{path}: cannot be decoded as a RAW file ({type(exc).__name__}: {exc})") from None
    else:
        img = cv2.imread(cv_path(path), cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
        if img is None:
            raise DatasetError(f"{path}: cannot be read as an image; check the file")
        if img.dtype != np.uint8:
            scale = 255.0 / max(float(img.max()), 1.0) if stretch else 1.0 / 257.0
            img = np.clip(img.astype(np.float32) * scale, 0, 255).round().astype(np.uint8)
        rgb = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    if max_width_px is not None:
        rgb = shrink(rgb, max_width_px)
    return np.ascontiguousarray(rgb)


# -- grey for features -------------------------------------------------------------------------------
def _normalise_to_u8(grey: np.ndarray) -> np.ndarray:
    if grey.dtype == np.uint8:
        return grey
    g = grey.astype(np.float32)
    lo, hi = np.percentile(g[::4, ::4], (0.5, 99.8))
    if hi <= lo:
        hi = lo + 1.0
    return np.clip((g - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)


def read_grey(path: str | os.PathLike, max_width_px: int | None) -> tuple[np.ndarray, tuple[int, int], float]:
    """A capture as a grey uint8 image for feature detection, at most ``max_width_px`` wide (a RAW
    developed at half size with the camera's white balance and a gamma; the 0.5 … 99.8 percentiles
    stretched to 0 … 255); also the full-resolution size and the scale (full-resolution pixels per
    returned pixel)."""
    path = Path(path)
    if is_raw(path):
        import rawpy
        try:
            with rawpy.imread(str(path)) as raw:
                sizes = raw.sizes   # read before postprocess: half_size changes them
                full = (int(sizes.width), int(sizes.height))
                if sizes.flip in (5, 6):
                    full = (full[1], full[0])
                rgb = raw.postprocess(half_size=True, use_camera_wb=True, no_auto_bright=True, output_bps=16,
                                      gamma=(2.222, 4.5))
        except Exception as exc:  # rawpy raises several LibRaw error types
            raise DatasetError(f"{path}: cannot be read as a RAW file ({exc}); re-copy it from the camera") from None
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    else:
        img = cv2.imread(cv_path(path), cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH)
        if img is None:
            raise DatasetError(f"{path}: cannot be read as an image (missing or corrupt); re-copy it or "
                               "exclude the view")
        if img.ndim == 3:
            img = cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2GRAY)
        grey = img
        full = (int(img.shape[1]), int(img.shape[0]))
    grey = _normalise_to_u8(grey)
    if max_width_px:
        grey = shrink(grey, int(max_width_px))
    return grey, full, full[0] / grey.shape[1]
