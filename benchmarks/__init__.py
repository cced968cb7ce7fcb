"""Benchmarks and reports: measurements, not tests."""

import shared as _shared  # noqa: F401 - first: sets up the numba cache (shared/__init__.py)
