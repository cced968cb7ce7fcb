"""The harness: everything that drives the haptic server from outside the real-time process
(virtual clock, launcher, soak, warm-up, replay). The only part of haptic_server that may
import haptic_local_model.sim_server."""
