"""Adapters for real haptic devices, through their makers' Python bindings (each an extra).

`base.PlanarHardware` is what every adapter shares: the planar map from the device's 3D
workspace to the scene's plane, the spring that holds the handle on that plane, force limits,
the NaN guard and the safe stop. Each vendor module adds only the calls into its binding
(`VendorLink`): haply (Haply Inverse3, `HaplyHardwareAPI`), forcedimension (Force Dimension
devices, `forcedimension-core`), touch (3D Systems Touch, `pyOpenHaptics`). docs/devices.md §6
says which were tried on real hardware.
"""
