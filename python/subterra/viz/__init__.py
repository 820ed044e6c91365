"""Pictures of what the stack saw and did (matplotlib; Rerun as the optional extra `subterra[viz]`)."""

from subterra.viz.plots import plot_depth_trace

__all__ = ["plot_depth_trace"]
