"""The 1 kHz haptic server: kernels, engine, real-time loop, I/O process, virtual clock."""

import haptic_local_model.shared as _shared  # noqa: F401 - first: sets up the numba cache (shared/__init__.py)
