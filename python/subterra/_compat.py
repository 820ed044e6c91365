"""What differs between the Python versions subterra supports (3.10 and later)."""

from __future__ import annotations

import sys

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10: the same parser, as a package (a dependency there)
    import tomli as tomllib

__all__ = ["tomllib"]
