"""Device interface, registry and simulated devices."""

import haptic_local_model.shared as _shared  # noqa: F401 - first: sets up the numba cache (shared/__init__.py)
