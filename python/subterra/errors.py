"""The exceptions subterra raises.

Every error the library raises on purpose is a :class:`SubterraError`. Errors caused by
a bad value (a wrong parameter, a malformed array, a corrupt file) are also
:class:`ValueError`, so code that already catches ``ValueError`` keeps working.

The Rust core raises the same classes: the binding crate maps each core error to one
of them, so ``except subterra.errors.InputError`` catches a bad depth image whether it
was found in Python or in Rust.
"""

from __future__ import annotations

__all__ = [
    "SubterraError",
    "ConfigError",
    "InputError",
    "FileFormatError",
    "MissingExtraError",
]


class SubterraError(Exception):
    """Base class of every error raised by subterra."""


class ConfigError(SubterraError, ValueError):
    """A configuration value or preset is invalid (negative, zero, NaN, unknown name, ...)."""


class InputError(SubterraError, ValueError):
    """An input array or value is invalid (wrong dtype or shape, NaN, empty, ...)."""


class FileFormatError(InputError):
    """A file could not be read: missing, truncated, corrupt or of an unknown format.

    The message ends with the path of the file.
    """


class MissingExtraError(SubterraError, ImportError):
    """An optional dependency is not installed; the message names the extra that brings it
    (``pip install 'subterra[io]'``)."""
