"""The haptic tick as stages, each `stage(m, d)` over one model record and one data record.

In order (DESIGN §4): `blend_weights`, `proxy_kinematics`, `blend_model` (kinematics.py),
`contacts`, `impulses` (contacts.py), `operational_terms` (kinematics.py), `coupling_errors`
and `control` (control.py: one law per method, chosen once), `proxy_step` (proxy.py),
`safety_and_limits` and `fill_row` (safety.py). `tick.py` sequences them and wraps the
device-to-world map around them; `install.py` validates and installs updates.
"""
