"""Built-in scenes and frame sequences (the simulator's worlds will live here too)."""

from subterra.scenarios.synthetic import approaching_box_frames, noise_only_frames

__all__ = ["approaching_box_frames", "noise_only_frames"]
