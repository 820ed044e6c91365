"""Straightforward NumPy reference implementations, used for parity tests and benchmarks.

Each module depends only on NumPy and the standard library (``mpc`` also on SciPy, for
SLSQP), so it can be imported (also by file path) without the compiled ``subterra._core``
extension.
"""
