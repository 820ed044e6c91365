"""Shared fixtures of the Python tests.

Nothing here imports the compiled ``subterra._core`` at collection time: the reference and
I/O tests also run in a checkout where the extension is not built. Fixtures that need it
import it when they are used.

* ``shared_data``: ``<repo>/../shared/data`` (the real sensor recordings); the test is
  skipped when the folder is absent.
* ``d435`` / ``d435_dict``: the simulated RealSense D435 depth camera
  (``subterra.PinholeCamera.d435()``: 640x480, fx = fy = 385 px) and the same intrinsics
  as the ``dict`` the NumPy reference takes.
* ``box_frame``: a factory of synthetic depth frames with a box of constant depth.
* ``config_from``: a factory of ``subterra.PerceptionConfig`` built from a preset with
  some fields changed (through the JSON round trip).
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
SHARED_DATA = (REPO_ROOT / ".." / "shared" / "data").resolve()


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``<repo>/../shared/data``; skips the test when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is absent: real-data tests need the shared sensor recordings")
    return SHARED_DATA


@pytest.fixture(scope="session")
def d435():
    """The simulated D435 depth stream: ``subterra.PinholeCamera.d435()``."""
    import subterra

    return subterra.PinholeCamera.d435()


def camera_dict(camera) -> dict:
    """A ``subterra.PinholeCamera`` as the ``dict`` the NumPy reference takes."""
    return {k: getattr(camera, k) for k in ("fx", "fy", "cx", "cy", "width", "height")}


@pytest.fixture(scope="session")
def d435_dict(d435) -> dict:
    """The D435 intrinsics as a ``dict`` (fx, fy, cx, cy [px], width, height [px])."""
    return camera_dict(d435)


def make_box_frame(
    depth_m: float = 0.8,
    rows: slice = slice(140, 340),
    cols: slice = slice(220, 420),
    *,
    shape: tuple[int, int] = (480, 640),
    dtype=np.uint16,
    scale: float = 0.001,
    background=0,
) -> np.ndarray:
    """A depth frame of ``shape`` (H, W) with a box ``depth_m`` metres away over ``rows x cols``.

    ``uint16``: raw units of ``scale`` metres (``round(depth_m / scale)``), 0 = no return;
    ``float32``: metres. ``background`` fills the rest (raw units or metres).
    """
    frame = np.full(shape, background, dtype=dtype)
    if np.dtype(dtype) == np.uint16:
        frame[rows, cols] = round(depth_m / scale)
    else:
        frame[rows, cols] = depth_m
    return frame


@pytest.fixture(scope="session")
def box_frame():
    """The factory :func:`make_box_frame`: ``box_frame(0.8, rows, cols, dtype=...)``."""
    return make_box_frame


def config_dict(preset: str = "flight", **sections) -> dict:
    """The preset as a nested dict (``PerceptionConfig.to_json``) with ``section={key: value}`` overrides."""
    import subterra

    d = json.loads(subterra.PerceptionConfig.preset(preset).to_json())
    for section, values in sections.items():
        d[section].update(values)
    return d


@pytest.fixture(scope="session")
def config_from():
    """Factory ``config_from("flight", filter={"mode": "histogram"})`` -> ``subterra.PerceptionConfig``."""
    import subterra

    def make(preset: str = "flight", **sections):
        return subterra.PerceptionConfig.from_json(json.dumps(config_dict(preset, **sections)))

    return make


def with_changes(cfg: dict, **sections) -> dict:
    """Deep copy of a config dict with ``section={key: value}`` overrides."""
    out = copy.deepcopy(cfg)
    for section, values in sections.items():
        out[section].update(values)
    return out
