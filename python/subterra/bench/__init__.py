"""Benchmarks of subterra against straightforward NumPy reference implementations."""
