"""The local model of a held tool's neighbourhood in any pymunk space: one builder for a scene's
world (sim_server/world.py) and a user's own space (sim_server/user_space.py).

`SpaceLocalModel` takes a space, the tool's bodies and shapes, its chain (shared/tool_chain.py)
and the world shapes it may touch with their materials, and makes once what the compiled
kernels read: the tool record (sim_server/tool.py) and the neighbourhood queries
(sim_server/local_model.py). How the space was built does not matter to it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pymunk

from haptic_local_model.shared.config import Material, RenderingSpec, ToolSpec
from haptic_local_model.shared.kinematics import MAX_CHAINS, MAX_DOF
from haptic_local_model.shared.protocol.layout import MAX_CONTACTS, MAX_RESISTED, update_size
from haptic_local_model.shared.shapes import MAX_SHAPES
from haptic_local_model.shared.tool_chain import ToolChain
from haptic_local_model.sim_server.chipmunk import body_ptr, space_ptr
from haptic_local_model.sim_server.local_model import (
    LocalModelKernel,
    build_local_model,
    encode_stamped,
)
from haptic_local_model.sim_server.tool import TOOL_BODY, TOOL_DTYPE, TOOL_LINKAGE

#: The largest update (all sections, every contact and shape): the encoder's buffer
MAX_UPDATE_BYTES = update_size(
    MAX_DOF, MAX_RESISTED, MAX_CONTACTS, 0x7F, n_shapes=MAX_SHAPES, n_chains=MAX_CHAINS
)


def tool_record(
    space: pymunk.Space,
    tool_bodies: Sequence[pymunk.Body],
    chain: ToolChain,
    tool: ToolSpec,
    rendering: RenderingSpec,
) -> np.ndarray:
    """The tool as the compiled step and local model read it (TOOL_DTYPE[1])."""
    rec = np.zeros(1, TOOL_DTYPE)
    t = rec[0]
    c = chain.chain[0]
    dof = chain.dof
    t["space"] = space_ptr(space)
    t["kind"] = TOOL_BODY if tool.kind == "body" else TOOL_LINKAGE
    t["dof"] = dof
    t["bodies"][: len(tool_bodies)] = [body_ptr(b) for b in tool_bodies]
    t["gravity"] = chain.gravity
    t["base_angle"] = float(c["base_angle"])
    t["parents"][:dof] = c["parents"][:dof]
    t["op_link"] = chain.op_link
    t["op_point"] = chain.op_point
    t["bandwidth_hz"] = tool.tracking_bandwidth_hz
    t["foh_stiffness"] = rendering.foh_spring_stiffness
    t["foh_damping"] = rendering.foh_spring_damping
    t["foh_relative"] = 1.0 if rendering.foh_relative_damping else 0.0
    t["characteristic_length"] = tool.characteristic_length_m
    t["rank_tolerance"] = tool.rank_tolerance
    t["margin"] = tool.neighbourhood_margin_m
    return rec


class SpaceLocalModel:
    """The tool record, the neighbourhood queries and the encoder's buffer of one tool in one
    space; `build()` computes the local model into `record` (one compiled call), `encode()`
    stamps and encodes it."""

    def __init__(
        self,
        space: pymunk.Space,
        tool_bodies: Sequence[pymunk.Body],
        tool_shapes: Sequence[tuple[pymunk.Shape, int]],
        chain: ToolChain,
        env_shapes: Sequence[tuple[pymunk.Shape, int, Material]],
        tool: ToolSpec,
        rendering: RenderingSpec,
    ) -> None:
        self.chain = chain
        self.tool = tool_record(space, tool_bodies, chain, tool, rendering)
        self.kernel = LocalModelKernel(tool_shapes, env_shapes, tool.neighbourhood_margin_m)
        self.encoded = np.zeros(MAX_UPDATE_BYTES, np.uint8)

    @property
    def record(self) -> np.ndarray:
        """The last local model built (LOCAL_MODEL_DTYPE[1])."""
        return self.kernel.record

    def build(self) -> None:
        """The local model at the tool's current state into `record`."""
        k = self.kernel
        build_local_model(self.tool, self.chain.chain, k.query, k.work, k.record)

    def encode(
        self, epoch: int, seq: int, sim_time: float, publish_time_ns: int, state_lead_s: float
    ) -> bytes:
        """`record` stamped and encoded (the wire bytes of DESIGN §3)."""
        n = encode_stamped(
            self.kernel.record, self.encoded, epoch, seq, sim_time, publish_time_ns, state_lead_s
        )
        return self.encoded[:n].tobytes()
