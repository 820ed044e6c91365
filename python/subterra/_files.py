"""Reading input files safely: regular files only, never blocking, bounded in size.

Every file entry point of subterra (configs, worlds, sweeps, depth images, clouds,
intrinsics, poses, recordings) reads through these helpers, so that a path naming a
FIFO, a device (``/dev/zero``, a tty) or a folder fails at once with a
:class:`~subterra.errors.FileFormatError` instead of blocking forever or filling the
memory, and a file larger than the reader's limit is refused before it is read.

The helpers ``stat`` the path first (which never blocks and has no side effect on a
device), then open it with ``O_NONBLOCK`` and check the opened file again with
``fstat``, so a path swapped for a FIFO between the two checks cannot block either.

Every error is a :class:`~subterra.errors.FileFormatError` whose message starts with
``cannot read <what>:``, gives the reason and ends with the path.
"""

from __future__ import annotations

import errno
import os
import stat
from typing import BinaryIO, Union

from .errors import FileFormatError, InputError

__all__ = [
    "MAX_BINARY_BYTES",
    "MAX_TEXT_BYTES",
    "check_regular_file",
    "open_for_writing",
    "open_regular",
    "read_regular_bytes",
    "read_regular_text",
]

PathLike = Union[str, "os.PathLike[str]"]

#: The largest text file read (configs, worlds, sweeps, intrinsics) [bytes].
MAX_TEXT_BYTES = 16 * 1024 * 1024
#: The largest binary file read whole into memory (point clouds, PGM images) [bytes].
MAX_BINARY_BYTES = 4 * 1024 * 1024 * 1024

_OPEN_FLAGS = (
    os.O_RDONLY
    | getattr(os, "O_NONBLOCK", 0)
    | getattr(os, "O_CLOEXEC", 0)
    | getattr(os, "O_BINARY", 0)  # Windows: no newline translation
)


def _describe(mode: int) -> str:
    """What a non-regular file is, for a message."""
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "a special file"


def _os_error(exc: OSError, path: PathLike, what: str) -> FileFormatError:
    reason = exc.strerror or str(exc) or type(exc).__name__
    if exc.errno == errno.ENOENT:
        reason = f"missing path ({reason})"
    return FileFormatError(f"cannot read {what}: {reason}: {os.fspath(path)}")


def _check_stat(
    st: os.stat_result, path: PathLike, what: str, allow_empty: bool, max_bytes: int | None
) -> None:
    if not stat.S_ISREG(st.st_mode):
        raise FileFormatError(
            f"cannot read {what}: not a regular file (got {_describe(st.st_mode)}): {os.fspath(path)}"
        )
    if max_bytes is not None and st.st_size > max_bytes:
        raise FileFormatError(
            f"cannot read {what}: the file holds {st.st_size} bytes, over the limit of "
            f"{max_bytes} bytes: {os.fspath(path)}"
        )
    if not allow_empty and st.st_size == 0:
        raise FileFormatError(f"cannot read {what}: empty file (0 bytes): {os.fspath(path)}")


def check_regular_file(
    path: PathLike, what: str, *, allow_empty: bool = True, max_bytes: int | None = None
) -> os.stat_result:
    """``os.stat`` of ``path`` (symlinks followed), which must be a regular file.

    Use it before handing a path to a library that opens it itself (NumPy, Pillow,
    rosbags). It never opens the file, so it never blocks.

    Args:
        path: the file.
        what: what the file is, for messages (``"world file"``, ``"depth image"``).
        allow_empty: False: a file of 0 bytes is an error.
        max_bytes: the largest size accepted [bytes]; None: no limit.

    Raises:
        FileFormatError: the path is missing, unreadable, not a regular file (a FIFO,
            a device, a folder), empty (with ``allow_empty=False``) or too large.
    """
    if not isinstance(path, (str, bytes, os.PathLike)):  # an int would be taken as a file descriptor
        raise FileFormatError(f"cannot read {what}: not a path (got {type(path).__name__} {path!r:.40})")
    try:
        st = os.stat(path)
    except OSError as exc:
        raise _os_error(exc, path, what) from exc
    except (TypeError, ValueError) as exc:  # not a path, or a NUL byte in it
        raise FileFormatError(f"cannot read {what}: not a valid path ({exc}): {path!s}") from exc
    _check_stat(st, path, what, allow_empty, max_bytes)
    return st


def open_regular(
    path: PathLike, what: str, *, allow_empty: bool = True, max_bytes: int | None = None
) -> BinaryIO:
    """Open a regular file for binary reading, without ever blocking.

    The file is checked with ``stat`` before it is opened (a device is never opened)
    and with ``fstat`` after (``O_NONBLOCK``, so opening a FIFO does not wait for a
    writer). The returned file object is in blocking mode, as libraries expect; reads
    from a regular file do not block.

    Raises:
        FileFormatError: as :func:`check_regular_file`.
    """
    check_regular_file(path, what, allow_empty=allow_empty, max_bytes=max_bytes)
    try:
        fd = os.open(path, _OPEN_FLAGS)
    except OSError as exc:
        raise _os_error(exc, path, what) from exc
    try:
        _check_stat(os.fstat(fd), path, what, allow_empty, max_bytes)
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def check_writable(path: PathLike, what: str, *, new: bool = False) -> None:
    """Errors unless ``path`` can be written as a new or replaced regular file: its parent
    folder exists, and it does not exist (``new``) or is a regular file.

    Raises:
        FileFormatError: the path exists and is not a regular file.
        InputError: the parent folder is missing, or (``new``) the path exists, or ``stat``
            fails (a symlink loop, no permission).
    """
    shown = os.fspath(path)
    parent = os.path.dirname(os.path.abspath(shown))
    if not os.path.isdir(parent):
        raise InputError(f"cannot write {what}: the folder {parent} does not exist (writers do not create folders): {shown}")
    try:
        st = os.stat(path)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise InputError(f"cannot write {what}: {exc.strerror or exc}: {shown}") from None
    if st is not None and new:
        raise InputError(f"cannot write {what}: the path exists already (give a new one): {shown}")
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise FileFormatError(f"cannot write {what}: not a regular file (got {_describe(st.st_mode)}): {shown}")


def open_for_writing(path: PathLike, what: str) -> BinaryIO:
    """Open ``path`` for binary writing (created or truncated), never blocking.

    A path that exists and is not a regular file (a FIFO nobody reads, a device, a folder)
    is refused before it is opened; the open itself uses ``O_NONBLOCK`` (a FIFO swapped in
    meanwhile fails at once instead of waiting for a reader) and is checked with ``fstat``.

    The parent folder must exist: every writer refuses to create folders (a typo in a
    folder name is an error, not a new tree).

    Raises:
        FileFormatError: ``cannot write <what>: not a regular file ...: <path>``.
        InputError: ``cannot write <what>: ...: <path>`` when the parent folder is missing or
            the file cannot be created (no permission, a symlink loop, ...).
    """
    check_writable(path, what)
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags, 0o666)
    except OSError as exc:
        raise InputError(f"cannot write {what}: {exc.strerror or exc}: {os.fspath(path)}") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise FileFormatError(f"cannot write {what}: not a regular file (got {_describe(mode)}): {os.fspath(path)}")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "wb")
    except BaseException:
        os.close(fd)
        raise


def read_regular_bytes(
    path: PathLike, what: str, *, max_bytes: int = MAX_BINARY_BYTES, allow_empty: bool = True
) -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` bytes.

    Raises:
        FileFormatError: as :func:`check_regular_file`; also when the file grows past
            ``max_bytes`` while it is read.
    """
    with open_regular(path, what, allow_empty=allow_empty, max_bytes=max_bytes) as handle:
        try:
            # Read what the file holds (one byte more, to see growth), not `max_bytes`: a read
            # of n bytes reserves n bytes first, and under an address-space limit a 4 GiB
            # reservation fails for a one-point cloud.
            size = os.fstat(handle.fileno()).st_size
            parts, total = [], 0
            while total <= max_bytes:
                chunk = handle.read(min(max_bytes + 1 - total, max(size + 1 - total, 1 << 20)))
                if not chunk:
                    break
                parts.append(chunk)
                total += len(chunk)
            data = b"".join(parts)
        except OSError as exc:
            raise _os_error(exc, path, what) from exc
    if len(data) > max_bytes:
        raise FileFormatError(
            f"cannot read {what}: the file holds more than {max_bytes} bytes, over the limit: "
            f"{os.fspath(path)}"
        )
    if not allow_empty and not data:
        raise FileFormatError(f"cannot read {what}: empty file (0 bytes): {os.fspath(path)}")
    return data


def read_regular_text(path: PathLike, what: str, *, max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of a regular file of at most ``max_bytes`` bytes.

    Raises:
        FileFormatError: as :func:`read_regular_bytes`, or the bytes are not UTF-8
            (the message gives the byte offset and the line of the first bad byte).
    """
    data = read_regular_bytes(path, what, max_bytes=max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise FileFormatError(
            f"cannot read {what}: not UTF-8 text (byte offset {exc.start}, line {line}: "
            f"{exc.reason}): {os.fspath(path)}"
        ) from exc


def read_toml(path: PathLike, what: str) -> dict:
    """The table of a TOML file, read by :func:`read_regular_text`.

    Raises:
        FileFormatError: the file cannot be read (see :func:`read_regular_text`).
        ConfigError: the text is not TOML (the message gives the parser's reason, or says it
            is nested too deeply, and ends with the path).
    """
    from ._compat import tomllib
    from .errors import ConfigError

    text = read_regular_text(path, what)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        reason = str(exc)
    except RecursionError:  # tomllib parses nested arrays and tables recursively
        reason = "nested too deeply"
    except ValueError as exc:  # e.g. an integer of more than 4300 digits
        reason = str(exc)
    raise ConfigError(f"{what} is not valid TOML ({reason}): {os.fspath(path)}")
