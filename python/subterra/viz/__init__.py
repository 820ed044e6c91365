"""Pictures of what the stack saw and did (matplotlib; Rerun as the optional extra `subterra[viz]`,
in :mod:`subterra.viz.rerun`, imported only when used)."""

from subterra.viz.flight import plot_compute_time, plot_flight_path, plot_flight_trace
from subterra.viz.plots import plot_depth_trace

__all__ = ["plot_compute_time", "plot_depth_trace", "plot_flight_path", "plot_flight_trace"]
