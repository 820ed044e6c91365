"""Properties of the terrain mapper on arbitrary input: every risk layer stays in [0, 1],
the variance and CVaR are finite and ordered, NaN points are dropped and counted, and
nothing crashes the process (hypothesis draws the clouds, poses and confidences)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

subterra = pytest.importorskip("subterra")
from subterra.terrain import translation  # noqa: E402

RISK_LAYERS = ("collision", "step", "negative", "tilt", "roughness", "unknown", "mission", "risk")

coordinates = st.floats(min_value=-30.0, max_value=30.0, allow_nan=False, width=32)
clouds = hnp.arrays(np.float32, st.tuples(st.integers(1, 400), st.just(3)), elements=coordinates)


def _pose(yaw: float, x: float, y: float) -> np.ndarray:
    m = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    m[:2, :2] = [[c, -s], [s, c]]
    m[:2, 3] = (x, y)
    return m


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    clouds=st.lists(clouds, min_size=1, max_size=3),
    yaw=st.floats(-math.pi, math.pi),
    x=st.floats(-5.0, 5.0),
    y=st.floats(-5.0, 5.0),
    confidence=st.floats(0.0, 1.0),
    nan_rows=st.integers(0, 5),
)
def test_risk_layers_stay_in_the_unit_interval(clouds, yaw, x, y, confidence, nan_rows):
    mapper = subterra.TerrainMapper()
    for n, cloud in enumerate(clouds):
        cloud = cloud.copy()
        cloud[:nan_rows] = np.nan
        risk_map = mapper.update(cloud, stamp=0.1 * n, world_from_body=_pose(yaw, x + 0.2 * n, y),
                                 body_from_sensor=translation(z=0.7), confidence=confidence)
    stats = risk_map.stats
    assert stats["non_finite"] == min(nan_rows, len(cloud))
    assert stats["kept"] + stats["non_finite"] + stats["out_of_range"] + stats["self_hits"] + stats["downsampled"] \
        + stats["outliers"] == stats["input_points"] == len(cloud)
    for name in RISK_LAYERS:
        layer = risk_map.layer(name)
        assert np.all(np.isfinite(layer)), name
        assert layer.min() >= 0.0 and layer.max() <= 1.0, (name, layer.min(), layer.max())
    variance = risk_map.layer("risk_variance")
    assert np.all(np.isfinite(variance)) and variance.min() >= 0.0
    low, high = risk_map.cvar(0.5), risk_map.cvar(0.95)
    assert np.all((low >= 0.0) & (low <= 1.0) & (high <= 1.0))
    assert np.all(high >= low - 1e-6), "CVaR grows with alpha"
    assert np.all(high >= risk_map.layer("risk") - 1e-6), "CVaR is at least the mean risk"
