"""Depth images from files: 16-bit PNG, 16-bit binary PGM, ``.npy`` and ``.npz``.

A depth image is an ``(H, W)`` array in one of the two forms docs/conventions.md fixes for the
whole library:

* ``uint16`` raw units with a scale in metres per unit (``metres = raw * scale``);
  the default scale is 0.001 (millimetres: RealSense, Kinect v1 via OpenNI). TUM RGB-D
  PNGs hold 5000 units per metre: read them with ``scale=1 / 5000``.
* ``float32`` metres (scale 1.0).

In both forms 0, NaN and inf mean "no return"; this module decodes files and leaves
the values as they are.

Formats
-------
``.png``
    16-bit single-channel PNG (Pillow modes ``I;16``, ``I;16B``, ``I``). 8-bit and
    colour PNGs are rejected: 8 bits cannot hold a depth in millimetres.
``.pgm``
    Binary PGM (``P5``, Netpbm spec) with ``maxval`` > 255: two bytes per sample, most
    significant byte first. The raw samples are returned as they are (not rescaled by
    ``maxval``). An 8-bit PGM (``maxval`` <= 255) is rejected. Only the first image of
    a multi-image file is read.
``.npy``
    A 2-D ``uint16`` or ``float32`` array; ``float64`` is converted to ``float32``.
``.npz``
    The array named ``depth``, or the only array in the archive; same dtypes as
    ``.npy``.

Only regular files are read (a FIFO, a device or a folder is refused at once), and an
image over :data:`MAX_DEPTH_PIXELS` pixels or :data:`MAX_DEPTH_BYTES` bytes is refused
before it is decoded (a ``.npz`` or PNG whose header declares a huge image is a
decompression bomb, not a depth image).
"""

from __future__ import annotations

import math
import numbers
import os
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Union

import numpy as np

from .._extras import require
from .._files import (
    MAX_BINARY_BYTES,
    check_regular_file,
    open_for_writing,
    open_regular,
    read_regular_bytes,
)
from ..errors import ConfigError, FileFormatError, InputError

__all__ = [
    "DEFAULT_UINT16_SCALE_M_PER_UNIT",
    "DEPTH_EXTENSIONS",
    "MAX_DEPTH_BYTES",
    "MAX_DEPTH_PIXELS",
    "DepthImage",
    "list_depth_files",
    "read_depth",
    "write_depth_png",
]

PathLike = Union[str, "os.PathLike[str]"]

#: File extensions :func:`read_depth` understands (lower case, with the dot).
DEPTH_EXTENSIONS: tuple[str, ...] = (".png", ".pgm", ".npy", ".npz")

#: Default scale of ``uint16`` depth [m/unit]: millimetres (docs/conventions.md).
DEFAULT_UINT16_SCALE_M_PER_UNIT = 0.001

#: The most pixels a depth image file may declare (64 megapixels; a 4K sensor has 8).
MAX_DEPTH_PIXELS = 64 * 1024 * 1024
#: The most bytes of samples a depth image file may declare (1 GiB).
MAX_DEPTH_BYTES = 1024 * 1024 * 1024

# Pillow modes of a 16-bit single-channel image. "I" (32-bit signed) is what older
# Pillow versions return for 16-bit PNGs; its values are checked to fit uint16.
_PNG_16BIT_MODES = ("I;16", "I;16B", "I;16L", "I")

_PIL_MODE_NAMES = {
    "1": "1-bit bilevel",
    "L": "8-bit grayscale",
    "LA": "8-bit grayscale with alpha",
    "La": "8-bit grayscale with alpha",
    "P": "8-bit palette",
    "PA": "8-bit palette with alpha",
    "RGB": "8-bit colour",
    "RGBA": "8-bit colour with alpha",
    "F": "32-bit float",
}

_NPY_MAGIC = b"\x93NUMPY"
_ZIP_MAGIC = b"PK"
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"

# Netpbm header bytes: whitespace as the spec defines it (blank, TAB, CR, LF, VT, FF).
_PNM_WHITESPACE = b" \t\n\r\v\f"
_PNM_DIGITS = b"0123456789"
# A header number with more digits than this is not a plausible image dimension.
_PNM_MAX_DIGITS = 9
_PGM_MAX_MAXVAL = 65535
_PGM_8BIT_MAXVAL = 255
# Room for the header (and its comments) of a PGM of MAX_DEPTH_BYTES samples.
_PGM_MAX_HEADER_BYTES = 1024 * 1024


@dataclass(frozen=True, eq=False)
class DepthImage:
    """A depth image and how to turn its values into metres.

    Attributes:
        data: C-contiguous ``(H, W)`` array, either ``uint16`` raw units
            (``metres = raw * scale_m_per_unit``) or ``float32`` metres. 0, NaN and inf
            mean "no return".
        scale_m_per_unit: metres per raw unit [m/unit]; 1.0 for ``float32`` data.
        path: the file the image was read from (as given), or a label.

    Equality is identity (comparing arrays element-wise is left to the caller).
    """

    data: np.ndarray
    scale_m_per_unit: float
    path: str

    def __post_init__(self) -> None:
        if not isinstance(self.path, (str, os.PathLike)):
            raise InputError(f"path: expected a str or os.PathLike, got {type(self.path).__name__}")
        data = self.data
        if not isinstance(data, np.ndarray):
            raise InputError(
                f"data: expected a numpy.ndarray, got {type(data).__name__}"
                + _path_suffix(self.path)
            )
        data = _checked_depth_array(data, "data", InputError, self.path)
        scale = _checked_scale(self.scale_m_per_unit, "scale_m_per_unit")
        if data.dtype == np.float32 and scale != 1.0:
            raise InputError(
                "scale_m_per_unit: expected 1.0 for float32 depth (metres), "
                f"got {scale!r}" + _path_suffix(self.path)
            )
        object.__setattr__(self, "data", data)
        object.__setattr__(self, "scale_m_per_unit", scale)
        object.__setattr__(self, "path", os.fspath(self.path))

    @classmethod
    def _trusted(cls, data: np.ndarray, scale_m_per_unit: float, path: str) -> DepthImage:
        """Builds the image without the checks, for decoders that have made them already
        (a non-empty, C-contiguous, native ``(H, W)`` ``uint16`` array with a positive
        finite scale, or ``float32`` with 1.0): per message, the checks cost more than the
        decode itself."""
        image = object.__new__(cls)
        object.__setattr__(image, "data", data)
        object.__setattr__(image, "scale_m_per_unit", scale_m_per_unit)
        object.__setattr__(image, "path", path)
        return image

    @property
    def height(self) -> int:
        """Number of rows [px]."""
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        """Number of columns [px]."""
        return int(self.data.shape[1])

    def to_metres(self) -> np.ndarray:
        """The depth in metres as a new ``float32`` ``(H, W)`` array.

        Raw 0 stays 0 ("no return"); NaN and inf stay as they are.
        """
        if self.data.dtype == np.float32:
            return self.data.copy()
        return self.data.astype(np.float32) * np.float32(self.scale_m_per_unit)


def read_depth(path: PathLike, *, scale: float | None = None) -> DepthImage:
    """Read a depth image from a ``.png``, ``.pgm``, ``.npy`` or ``.npz`` file.

    Args:
        path: the file; the format is chosen by its extension (case-insensitive).
        scale: metres per raw unit [m/unit] for ``uint16`` images; ``None`` means
            0.001 (millimetres). Must be finite and > 0. For ``float32`` images (metres)
            only ``None`` or 1.0 are accepted.

    Returns:
        A :class:`DepthImage` with native-byte-order, C-contiguous, writable ``data``.

    Raises:
        ConfigError: ``scale`` is not a finite number > 0.
        FileFormatError: the file is missing, empty, truncated, corrupt, of an unknown
            extension, not 2-D, of an unsupported dtype or bit depth.
        InputError: ``path`` is not a path, or ``scale`` is given for a float image.
    """
    checked_scale = None if scale is None else _checked_scale(scale, "scale")
    file_path = _as_path(path, "path")
    suffix = file_path.suffix.lower()
    if suffix not in DEPTH_EXTENSIONS:
        raise FileFormatError(
            f"path: expected a depth image with extension {', '.join(DEPTH_EXTENSIONS)}, "
            f"got {file_path.suffix or 'no extension'!r}: {file_path}"
        )
    _check_readable_file(file_path, "depth image")

    if suffix == ".png":
        data = _read_png(file_path)
    elif suffix == ".pgm":
        data = _read_pgm(file_path)
    elif suffix == ".npy":
        data = _read_npy(file_path)
    else:
        data = _read_npz(file_path)

    if data.dtype == np.float32:
        if checked_scale is not None and checked_scale != 1.0:
            raise InputError(
                "scale: expected None or 1.0 for a float32 depth image (already in "
                f"metres), got {checked_scale!r}: {file_path}"
            )
        scale_m_per_unit = 1.0
    else:
        scale_m_per_unit = (
            DEFAULT_UINT16_SCALE_M_PER_UNIT if checked_scale is None else checked_scale
        )
    return DepthImage(data=data, scale_m_per_unit=scale_m_per_unit, path=os.fspath(path))


def list_depth_files(directory: PathLike) -> list[Path]:
    """The depth image files directly inside ``directory``, in natural order.

    Files with the extensions in :data:`DEPTH_EXTENSIONS` (case-insensitive) count;
    sub-folders and hidden files (name starting with ``.``, such as macOS ``._*``
    metadata) do not. Natural order compares digit runs as numbers, so ``2.pgm``
    comes before ``10.pgm`` and zero-padded names keep their order.

    Raises:
        InputError: ``directory`` is missing, not a folder, or holds no depth file.
    """
    folder = _as_path(directory, "directory")
    if not folder.exists():
        raise InputError(f"directory: expected an existing folder, got a missing path: {folder}")
    if not folder.is_dir():
        raise InputError(f"directory: expected a folder, got a file: {folder}")
    try:
        entries = list(folder.iterdir())
    except OSError as exc:
        raise InputError(
            f"directory: expected a readable folder, got {type(exc).__name__} ({exc.strerror}): "
            f"{folder}"
        ) from exc
    files = [
        entry
        for entry in entries
        if entry.suffix.lower() in DEPTH_EXTENSIONS
        and not entry.name.startswith(".")
        and entry.is_file()
    ]
    if not files:
        raise InputError(
            f"directory: expected at least one depth file ({', '.join(DEPTH_EXTENSIONS)}), "
            f"got none: {folder}"
        )
    files.sort(key=lambda p: _natural_key(p.name))
    return files


def write_depth_png(path: PathLike, data: np.ndarray) -> None:
    """Write a ``uint16`` ``(H, W)`` array as a 16-bit grayscale PNG.

    The file reads back with :func:`read_depth` to the same values. The scale is not
    stored: PNG has no standard place for it.

    Raises:
        InputError: ``path`` is not a path, or ``data`` is not a non-empty 2-D uint16
            array.
        OSError: the file cannot be written (missing folder, no permission, ...).
    """
    file_path = _as_path(path, "path")
    if not isinstance(data, np.ndarray):
        raise InputError(
            f"data: expected a numpy.ndarray of dtype uint16, got {type(data).__name__}: "
            f"{file_path}"
        )
    if not _is_uint16(data.dtype):
        raise InputError(
            f"data: expected dtype uint16 (a 16-bit PNG holds raw units), got {data.dtype}: "
            f"{file_path}"
        )
    array = _checked_depth_array(data, "data", InputError, file_path)
    # Pillow maps a little-endian uint16 array to mode "I;16" and writes it as a
    # 16-bit grayscale PNG (big-endian on disk, as the PNG spec requires).
    Image = require("PIL.Image", "io", "Writing PNG depth images")
    image = Image.fromarray(np.ascontiguousarray(array, dtype="<u2"))
    with open_for_writing(file_path, "depth image") as handle:
        image.save(handle, format="PNG")


# --------------------------------------------------------------------------- helpers


def _path_suffix(path: object) -> str:
    return f": {os.fspath(path)}" if path not in (None, "") else ""


def _as_path(value: object, name: str) -> Path:
    if isinstance(value, (str, os.PathLike)):
        try:
            return Path(value)
        except TypeError:
            pass
    raise InputError(f"{name}: expected a str or os.PathLike, got {type(value).__name__}")


# Metres per raw unit accepted [m/unit]: the core's DEPTH_SCALE_RANGE_M_PER_UNIT (1 µm to 1 m;
# cameras use 0.1 mm to 1 mm, and a denormal scale puts every pixel at 0 m).
_SCALE_RANGE_M_PER_UNIT = (1e-6, 1.0)


def _checked_scale(value: object, name: str) -> float:
    lo, hi = _SCALE_RANGE_M_PER_UNIT
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ConfigError(
            f"{name}: expected a finite number in [{lo:g}, {hi:g}] [m/unit], got {type(value).__name__} {value!r}"
        )
    scale = float(value)
    if not (math.isfinite(scale) and lo <= scale <= hi):
        raise ConfigError(f"{name}: expected a finite number in [{lo:g}, {hi:g}] [m/unit], got {scale!r}")
    return scale


def _check_readable_file(path: Path, what: str) -> None:
    """``path`` is an existing, non-empty regular file (not a FIFO, device or folder)."""
    check_regular_file(path, what, allow_empty=False)


def _read_bytes(path: Path, what: str = "file", max_bytes: int = MAX_BINARY_BYTES) -> bytes:
    """The whole file (a regular file of at most ``max_bytes`` bytes)."""
    return read_regular_bytes(path, what, max_bytes=max_bytes)


def _read_head(path: Path, count: int, what: str = "file") -> bytes:
    """The first ``count`` bytes of a regular file."""
    with open_regular(path, what) as handle:
        try:
            return handle.read(count)
        except OSError as exc:
            raise FileFormatError(
                f"cannot read {what}: {exc.strerror or exc}: {path}"
            ) from exc


def _check_depth_size(shape: tuple[int, ...], itemsize: int, what: str, path: object) -> None:
    """Refuse an image whose declared size is over :data:`MAX_DEPTH_PIXELS` / ``_BYTES``."""
    pixels = math.prod(int(n) for n in shape)
    nbytes = pixels * int(itemsize)
    if pixels > MAX_DEPTH_PIXELS or nbytes > MAX_DEPTH_BYTES:
        raise FileFormatError(
            f"{what}: declares shape {tuple(int(n) for n in shape)} ({pixels} pixels, {nbytes} "
            f"bytes), over the limit of {MAX_DEPTH_PIXELS} pixels and {MAX_DEPTH_BYTES} bytes "
            f"(a corrupt header or a decompression bomb){_path_suffix(path)}"
        )


def _is_uint16(dtype: np.dtype) -> bool:
    return dtype.kind == "u" and dtype.itemsize == 2


def _checked_depth_array(
    array: np.ndarray, what: str, error: type[InputError], path: object
) -> np.ndarray:
    """Check shape and dtype; return a native-order, C-contiguous array.

    ``float64`` is converted to ``float32``; other dtypes are rejected with ``error``.
    """
    suffix = _path_suffix(path)
    if array.ndim != 2:
        raise error(f"{what}: expected a 2-D (H, W) depth array, got shape {array.shape}{suffix}")
    if array.size == 0:
        raise error(
            f"{what}: expected a non-empty (H, W) depth array, got shape {array.shape}{suffix}"
        )
    # Checked on the view, before the copy: a broadcast view of 10^10 pixels is refused,
    # not materialised.
    pixels = math.prod(int(n) for n in array.shape)
    if pixels > MAX_DEPTH_PIXELS:
        raise error(
            f"{what}: shape {array.shape} has {pixels} pixels, over the limit of "
            f"{MAX_DEPTH_PIXELS}{suffix}"
        )
    dtype = array.dtype
    if _is_uint16(dtype):
        target = np.uint16
    elif dtype.kind == "f" and dtype.itemsize in (4, 8):
        target = np.float32
    else:
        raise error(
            f"{what}: expected dtype uint16 (raw units) or float32 (metres; float64 is "
            f"converted), got {dtype}{suffix}"
        )
    # float64 beyond float32's range becomes inf, which the core reads as "no return",
    # like every other depth past its range: no overflow warning for it.
    with np.errstate(over="ignore"):
        return np.ascontiguousarray(array, dtype=target)


def _natural_key(name: str) -> tuple:
    parts = re.split(r"(\d+)", name)
    key = []
    for index, part in enumerate(parts):
        if index % 2:  # a digit run
            key.append((0, int(part), part))
        elif part:
            key.append((1, part.lower(), part))
    return (tuple(key), name)


# ------------------------------------------------------------------------------ PNG


def _read_png(path: Path) -> np.ndarray:
    with open_regular(path, "depth image") as handle:
        return _decode_png(handle, path)


def _decode_png(handle: object, path: Path) -> np.ndarray:
    Image = require("PIL.Image", "io", "Reading PNG depth images")
    try:
        head = handle.read(len(_PNG_MAGIC))  # type: ignore[attr-defined]
        handle.seek(0)  # type: ignore[attr-defined]
    except OSError as exc:
        raise FileFormatError(f"cannot read depth image: {exc.strerror or exc}: {path}") from exc
    if head != _PNG_MAGIC[: len(head)] or len(head) < len(_PNG_MAGIC):
        raise FileFormatError(
            f"depth PNG: expected the PNG signature {_PNG_MAGIC!r}, got {head!r} "
            f"(not a PNG file, or truncated): {path}"
        )
    try:
        with Image.open(handle, formats=["PNG"]) as image:
            width, height = image.size
            _check_depth_size((height, width), 2, "depth PNG", path)
            image.load()
            mode = image.mode
            if mode not in _PNG_16BIT_MODES:
                raise FileFormatError(
                    "depth PNG: expected a 16-bit single-channel image (Pillow mode "
                    f"'I;16', 'I;16B' or 'I'), got mode {mode!r} "
                    f"({_PIL_MODE_NAMES.get(mode, 'not 16-bit grayscale')}); 8-bit and "
                    f"colour PNGs cannot hold depth: {path}"
                )
            array = np.array(image)
    except FileFormatError:
        raise
    except Image.DecompressionBombError as exc:  # Pillow's own limit, checked in open()
        raise FileFormatError(
            f"depth PNG: declares an image over the limit of {MAX_DEPTH_PIXELS} pixels "
            f"(a corrupt header or a decompression bomb; {exc}): {path}"
        ) from exc
    except Exception as exc:  # Pillow signals corrupt data with many exception types
        raise FileFormatError(
            f"depth PNG: expected a valid PNG, got a corrupt or truncated file "
            f"({type(exc).__name__}: {exc}): {path}"
        ) from exc
    return _png_array_to_uint16(array, mode, path)


def _png_array_to_uint16(array: np.ndarray, mode: str, path: object) -> np.ndarray:
    """Turn the array of a 16-bit Pillow image into native uint16."""
    if array.ndim != 2:
        raise FileFormatError(
            f"depth PNG: expected a single-channel image, got array shape {array.shape} "
            f"(mode {mode!r}): {path}"
        )
    if not _is_uint16(array.dtype):
        # Mode "I" is 32-bit signed; a 16-bit PNG decoded to it lies in 0..65535.
        if array.dtype.kind not in "iu":
            raise FileFormatError(
                f"depth PNG: expected integer samples, got dtype {array.dtype} "
                f"(mode {mode!r}): {path}"
            )
        low, high = int(array.min()), int(array.max())
        if low < 0 or high > np.iinfo(np.uint16).max:
            raise FileFormatError(
                f"depth PNG: expected 16-bit samples in 0..65535, got values in "
                f"{low}..{high} (mode {mode!r}): {path}"
            )
    return np.ascontiguousarray(array, dtype=np.uint16)


# ------------------------------------------------------------------------------ PGM


def _read_pgm(path: Path) -> np.ndarray:
    raw = _read_bytes(path, "depth image", MAX_DEPTH_BYTES + _PGM_MAX_HEADER_BYTES)
    width, height, maxval, offset = _parse_pgm_header(raw, path)
    _check_depth_size((height, width), 2, "depth PGM", path)
    if maxval <= _PGM_8BIT_MAXVAL:
        raise FileFormatError(
            f"depth PGM: expected a 16-bit PGM (maxval > {_PGM_8BIT_MAXVAL}), got maxval "
            f"{maxval} (8-bit samples cannot hold depth): {path}"
        )
    count = width * height
    needed = 2 * count
    available = len(raw) - offset
    if available < needed:
        raise FileFormatError(
            f"depth PGM: expected {needed} bytes of pixel data for {width}x{height} 16-bit "
            f"samples, got {available} (truncated file): {path}"
        )
    # Netpbm: two bytes per sample when maxval > 255, most significant byte first.
    samples = np.frombuffer(raw, dtype=">u2", count=count, offset=offset)
    data = samples.astype(np.uint16).reshape(height, width)
    if maxval < _PGM_MAX_MAXVAL:
        high = int(data.max())
        if high > maxval:
            raise FileFormatError(
                f"depth PGM: expected samples <= maxval {maxval}, got {high} (corrupt file): {path}"
            )
    return data


def _parse_pgm_header(raw: bytes, path: Path) -> tuple[int, int, int, int]:
    """Parse a P5 header; return ``(width, height, maxval, raster offset)``."""
    magic = raw[:2]
    if magic != b"P5":
        kinds = {
            b"P2": "a plain (ASCII) PGM, P2",
            b"P1": "a bitmap (PBM)",
            b"P4": "a bitmap (PBM)",
            b"P3": "a colour pixmap (PPM)",
            b"P6": "a colour pixmap (PPM)",
            b"P7": "a PAM file",
        }
        found = kinds.get(magic, f"magic {magic!r}")
        raise FileFormatError(
            f"depth PGM: expected a binary PGM (magic b'P5'), got {found}: {path}"
        )
    pos = 2
    if pos >= len(raw) or (raw[pos] not in _PNM_WHITESPACE and raw[pos] != ord("#")):
        got = repr(raw[pos : pos + 1]) if pos < len(raw) else "end of file (truncated header)"
        raise FileFormatError(
            f"depth PGM: expected whitespace after the magic b'P5', got {got}: {path}"
        )
    values = []
    for field in ("width", "height", "maxval"):
        pos = _skip_pnm_space(raw, pos)
        start = pos
        while pos < len(raw) and raw[pos] in _PNM_DIGITS:
            pos += 1
        token = raw[start:pos]
        if not token:
            got = repr(raw[pos : pos + 1]) if pos < len(raw) else "end of file (truncated header)"
            raise FileFormatError(f"depth PGM: expected a decimal {field}, got {got}: {path}")
        if len(token) > _PNM_MAX_DIGITS:
            raise FileFormatError(
                f"depth PGM: expected a {field} of at most {_PNM_MAX_DIGITS} digits, "
                f"got {token[:20]!r}: {path}"
            )
        values.append(int(token))
    width, height, maxval = values
    if width <= 0 or height <= 0:
        raise FileFormatError(
            f"depth PGM: expected width and height > 0, got {width}x{height}: {path}"
        )
    if not 0 < maxval <= _PGM_MAX_MAXVAL:
        raise FileFormatError(
            f"depth PGM: expected maxval in 1..{_PGM_MAX_MAXVAL}, got {maxval}: {path}"
        )
    # Exactly one whitespace byte separates maxval from the raster; a comment there
    # ends with its newline, which is then the separator.
    if pos >= len(raw):
        raise FileFormatError(
            f"depth PGM: expected a whitespace byte after maxval, got end of file "
            f"(truncated header): {path}"
        )
    if raw[pos] == ord("#"):
        pos = _skip_pnm_comment(raw, pos)
        if pos > len(raw) or raw[pos - 1] not in b"\r\n":
            raise FileFormatError(
                f"depth PGM: expected a newline ending the comment after maxval, got end "
                f"of file (truncated header): {path}"
            )
    elif raw[pos] in _PNM_WHITESPACE:
        pos += 1
    else:
        raise FileFormatError(
            f"depth PGM: expected a whitespace byte after maxval, got {raw[pos : pos + 1]!r}: "
            f"{path}"
        )
    return width, height, maxval, pos


def _skip_pnm_space(raw: bytes, pos: int) -> int:
    """Skip whitespace and ``#`` comments (to the end of their line)."""
    while pos < len(raw):
        byte = raw[pos]
        if byte in _PNM_WHITESPACE:
            pos += 1
        elif byte == ord("#"):
            pos = _skip_pnm_comment(raw, pos)
        else:
            break
    return pos


def _skip_pnm_comment(raw: bytes, pos: int) -> int:
    """Return the index just after the CR or LF ending the comment at ``pos``."""
    while pos < len(raw) and raw[pos] not in b"\r\n":
        pos += 1
    return pos + 1


# ------------------------------------------------------------------------ npy / npz


def _read_npy(path: Path) -> np.ndarray:
    head = _read_head(path, len(_NPY_MAGIC), "depth image")
    if head != _NPY_MAGIC:
        raise FileFormatError(
            f"depth .npy: expected the NumPy magic {_NPY_MAGIC!r}, got {head!r} "
            f"(not a .npy file): {path}"
        )
    try:
        # Memory-mapping checks the header's shape against the file size before any
        # data is read, so a truncated file fails without allocating the full array.
        mapped = np.load(path, mmap_mode="r", allow_pickle=False)
        if not isinstance(mapped, np.ndarray):
            raise FileFormatError(
                f"depth .npy: expected a single array, got {type(mapped).__name__}: {path}"
            )
        try:
            _check_depth_size(mapped.shape, mapped.dtype.itemsize, "depth .npy", path)
            data = _checked_depth_array(mapped, "depth .npy", FileFormatError, path)
            if np.may_share_memory(data, mapped):
                data = data.copy()  # own the pixels; do not keep the file mapped
        finally:
            del mapped
    except FileFormatError:
        raise
    except Exception as exc:  # NumPy reports bad headers with several exception types
        raise FileFormatError(
            f"depth .npy: expected a valid .npy file, got a corrupt or truncated one "
            f"({type(exc).__name__}: {exc}): {path}"
        ) from exc
    return data


def _read_npz(path: Path) -> np.ndarray:
    with open_regular(path, "depth image") as handle:
        try:
            head = handle.read(len(_ZIP_MAGIC))
            handle.seek(0)
        except OSError as exc:
            raise FileFormatError(f"cannot read depth image: {exc.strerror or exc}: {path}") from exc
        if head != _ZIP_MAGIC:
            raise FileFormatError(
                f"depth .npz: expected a zip archive (magic b'PK'), got {head!r} "
                f"(not a .npz file): {path}"
            )
        try:
            with zipfile.ZipFile(handle) as archive:
                # The names np.load gives the arrays: the member names without ".npy".
                members = {
                    (name[: -len(".npy")] if name.endswith(".npy") else name): name
                    for name in archive.namelist()
                }
                names = list(members)
                if "depth" in members:
                    key = "depth"
                elif len(names) == 1:
                    key = names[0]
                else:
                    raise FileFormatError(
                        "depth .npz: expected an array named 'depth' or exactly one array, "
                        f"got {len(names)} arrays {names}: {path}"
                    )
                array = _read_npz_member(archive, members[key], f"depth .npz array {key!r}", path)
        except FileFormatError:
            raise
        except Exception as exc:  # zipfile / zlib / NumPy errors for corrupt archives
            raise FileFormatError(
                f"depth .npz: expected a valid .npz archive, got a corrupt or truncated one "
                f"({type(exc).__name__}: {exc}): {path}"
            ) from exc
    return _checked_depth_array(array, f"depth .npz array {key!r}", FileFormatError, path)


def _read_npz_member(archive: zipfile.ZipFile, member: str, what: str, path: Path) -> np.ndarray:
    """One ``.npy`` member of an archive, its declared size checked before it is inflated.

    A few kilobytes of deflated zeros can declare gigabytes: the shape in the member's
    ``.npy`` header is checked against :data:`MAX_DEPTH_PIXELS` / :data:`MAX_DEPTH_BYTES`
    and against the member's uncompressed size in the zip directory before any sample
    is read.
    """
    info = archive.getinfo(member)
    with archive.open(info) as entry:
        magic = entry.read(len(_NPY_MAGIC))
        if magic != _NPY_MAGIC:
            raise FileFormatError(
                f"{what}: expected a .npy member (magic {_NPY_MAGIC!r}), got {magic!r}: {path}"
            )
        version = tuple(entry.read(2))
        if version == (1, 0):
            shape, fortran_order, dtype = np.lib.format.read_array_header_1_0(entry)
        elif version == (2, 0):
            shape, fortran_order, dtype = np.lib.format.read_array_header_2_0(entry)
        else:
            raise FileFormatError(
                f"{what}: expected .npy format version 1.0 or 2.0, got {version}: {path}"
            )
        if dtype.hasobject:
            raise FileFormatError(f"{what}: expected numbers, got object dtype {dtype}: {path}")
        if any(n < 0 for n in shape):
            raise FileFormatError(f"{what}: expected a shape of sizes >= 0, got {shape}: {path}")
        _check_depth_size(shape, dtype.itemsize, what, path)
        nbytes = math.prod(shape) * dtype.itemsize
        available = info.file_size - entry.tell()
        if available < nbytes:
            raise FileFormatError(
                f"{what}: shape {shape} of {dtype} needs {nbytes} bytes, the archive member "
                f"holds {max(available, 0)} (truncated or corrupt): {path}"
            )
        buffer = np.empty(nbytes, np.uint8)
        view = memoryview(buffer)
        filled = 0
        while filled < nbytes:
            count = entry.readinto(view[filled:])
            if not count:
                raise FileFormatError(
                    f"{what}: expected {nbytes} bytes of samples, got {filled} (truncated or "
                    f"corrupt archive): {path}"
                )
            filled += count
    return buffer.view(dtype).reshape(shape, order="F" if fortran_order else "C")
