"""The physics core: each law of the haptic side written once, for every world kind.

- `contact_law`: penalty, stick-spring friction and a contact's rows in the implicit step
  (seed 001 eq 8);
- `impulses`: the first-touch impulses, the complementarity problem of a tick's colliding
  contacts (seed 001 eq 5-6, DESIGN-WAVE2 §6);
- `implicit`: the linearly implicit (theta) step of a configuration in its springs
  (seed 000 eq 21).

A world (the local model, the co-simulation, the hands) finds its own contacts and builds
its own rows; what it does with them is here. Every function is a numba kernel of plain
floats and arrays: no record of any world is read here.
"""
