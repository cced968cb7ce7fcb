"""The 30-60 Hz pymunk simulation server that publishes the local model."""

import haptic_local_model.shared as _shared  # noqa: F401 - first: sets up the numba cache (shared/__init__.py)
