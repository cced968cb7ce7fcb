"""One device on a co-simulated world (`box_push`): a World kind of its own, added as the
recipe of docs/architecture.md says (its module, its scene, and two lines elsewhere).

The records, the device-to-world map, the users and the rows are the two-port world's
(haptic_server.ports: a port scene with one port, its log `/ports/tick` and its replay);
what is its own is the compiled tick for one device: the hand on the device and the
device's reading in the world frame, the co-simulation (`stages/cosim.cosim_tick`), the
command mapped back, clipped at the device's limits, and the device's physics.
"""

from __future__ import annotations

from haptic_local_model.haptic_server.paced import kind_kernel, never_asks, paced_entry, paced_ticks
from haptic_local_model.haptic_server.ports import PortRun, run_port_ticks
from haptic_local_model.haptic_server.world import Compiled


@kind_kernel
def one_port_burst(w, rows, start, stop):
    """ports.run_port_ticks over the world's records (its model, data, I/O, the device's):
    the kind's compiled ticks as the runners call them (world.Compiled)."""
    return run_port_ticks(w[0], w[1], w[2], (w[3],), rows, start, stop)


@paced_entry(never_asks, one_port_burst)
def one_port_paced(w, rows, loop, windows, ts):
    """The real-time runner's compiled loop over one_port_burst (haptic_server.paced)."""
    return paced_ticks(never_asks, one_port_burst, w, rows, loop, windows, ts)


class OnePortRun(PortRun):
    """A port scene of one port with its device and user, ready to run: a World (its
    `burst` is PortRun's, over the compiled ticks below)."""

    @property
    def compiled(self) -> Compiled:
        """The compiled ticks (one_port_burst, one_port_paced) and the records they take."""
        records = (self.model, self.data, self.io, self.devices[0].records)
        return Compiled(one_port_burst, one_port_paced, records)
