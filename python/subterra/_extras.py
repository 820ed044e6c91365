"""Optional dependencies: the core needs NumPy only; the rest comes with extras.

=============  ==================================================  ============================
extra          packages                                            for
=============  ==================================================  ============================
``io``         rosbags, mcap, pillow, pyyaml, scipy                bags, MCAP, PNG depth, YAML,
                                                                   odometry and tf rotations
``viz``        matplotlib, rerun-sdk, foxglove-sdk                 plots, Rerun, the live view
``sim``        matplotlib, tqdm                                    run folders with plots, bars
``ros``        cyclonedds, rosbags, scipy                          ``subterra node``, ``sil``
``mavlink``    pymavlink, pyserial                                 the MAVLink offboard bridge
``cluster``    ray                                                 ``--engine ray``
``bench``      scipy, scikit-image, mujoco                         the peers of ``subterra bench``
``all``        all of the above
=============  ==================================================  ============================

:func:`require` imports a module of an extra or raises
:class:`~subterra.errors.MissingExtraError` naming the ``pip install`` that brings it.
Progress bars are the exception: without tqdm they are simply not shown.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterable, Iterator
from typing import Any

from subterra.errors import MissingExtraError

__all__ = ["require", "tqdm"]


def require(module: str, extra: str, what: str) -> Any:
    """``module`` imported, or :class:`MissingExtraError`: "<what> needs the <package>
    package: pip install 'subterra[<extra>]'"."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        package = module.split(".")[0]
        raise MissingExtraError(f"{what} needs the {package} package: pip install 'subterra[{extra}]'") from exc


class _NoBar:
    """What :func:`tqdm` gives without tqdm: the same calls, nothing shown."""

    disable = True

    def __init__(self, iterable: Iterable[Any] | None = None, *args: Any, total: float | None = None, initial: float = 0, **kwargs: Any) -> None:
        self.iterable, self.total, self.n = iterable, total, initial

    def __iter__(self) -> Iterator[Any]:
        return iter(self.iterable if self.iterable is not None else ())

    def update(self, n: float = 1) -> None:
        self.n += n

    def set_postfix_str(self, *args: Any, **kwargs: Any) -> None:
        pass

    def set_description(self, *args: Any, **kwargs: Any) -> None:
        pass

    def refresh(self) -> None:
        pass

    def close(self) -> None:
        pass

    def __enter__(self) -> _NoBar:
        return self

    def __exit__(self, *exc: object) -> None:
        pass


def tqdm(*args: Any, **kwargs: Any) -> Any:
    """A ``tqdm`` progress bar, or a silent stand-in when tqdm is not installed."""
    try:
        from tqdm import tqdm as bar
    except ImportError:
        return _NoBar(*args, **kwargs)
    return bar(*args, **kwargs)
