"""Code shared by the sim and the haptic server: config, messages, kinematics, timing."""

__version__ = "0.1.0"
