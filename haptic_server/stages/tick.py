"""One haptic tick as a list of stages, and the engine step around it (DESIGN §4)."""

from __future__ import annotations

from numba import njit, types
from numba.extending import overload

from haptic_local_model.device_models.world_map import (
    map_command_to_device,
    map_rate_step,
    map_sensors_to_world,
    map_wrench_to_world,
)
from haptic_local_model.haptic_server.stages.contacts import contacts
from haptic_local_model.haptic_server.stages.control import control, coupling_errors
from haptic_local_model.haptic_server.stages.finger import finger
from haptic_local_model.haptic_server.stages.kinematics import (
    blend_model,
    blend_weights,
    operational_terms,
    proxy_kinematics,
)
from haptic_local_model.haptic_server.stages.proxy import proxy_step
from haptic_local_model.haptic_server.stages.safety import (
    fill_row,
    runaway_guard,
    safety_and_limits,
)
from haptic_local_model.haptic_server.stages.train import fill_train_row, train_begin, train_end
from haptic_local_model.shared.protocol.codes import Method


@njit(cache=True)
def haptic_tick(model, data):
    """The local model and device control of one tick (seed 000 eq 11, 17, 18, 21; seed 001
    eq 5-8): model is MODEL_DTYPE[1], data DATA_DTYPE[1] (its sensors in the world frame);
    the command is left in data.row.wrench_command."""
    m = model[0]
    d = data[0]
    blend_weights(m, d)
    proxy_kinematics(m, d)
    blend_model(m, d)
    contacts(m, d)
    operational_terms(m, d)
    coupling_errors(m, d)
    control(m, d)
    proxy_step(m, d)
    runaway_guard(m, d)
    safety_and_limits(m, d)
    fill_row(m, d)


def method_marker(method: int) -> bool | None:
    """The scene's rendering method as the type the compiled step is specialised on, the
    last of the engine's records: None for the local model, True for the god-object. The
    step's tick is chosen on the marker's type as numba types it (`method_tick`'s overload),
    so each step holds its own method's tick alone: a local-model run neither compiles nor
    loads the god-object's (21 s of a cold start's compiling), nor a god-object run the
    local model's."""
    return True if method == Method.GOD_OBJECT else None


@njit(cache=True)
def rendering_tick(model, data, god):
    """The scene's method's tick: the god-object's (finger_tick; `god` True) or the local
    model's (`god` None: method_marker), chosen by the marker's type as numba types the
    step (`method_tick`): a step holds one tick, never both."""
    method_tick(model, data, god)


def method_tick(model, data, god):
    """The tick of the method `god` marks; called from compiled code only."""
    raise NotImplementedError("method_tick runs compiled only (rendering_tick)")


@overload(method_tick)
def _method_tick_for(model, data, god):
    """The tick for the marker's type, chosen in typing: the other is neither typed nor
    compiled into the step."""
    if isinstance(god, types.NoneType):

        def local_model(model, data, god):
            haptic_tick(model, data)

        return local_model

    def god_object(model, data, god):
        finger_tick(model, data)

    return god_object


@njit(cache=True)
def finger_tick(model, data):
    """The god_object method's tick (seed 003 §3): the god-object against the local shapes
    (a train's cars among them, moved by its animation variable around the step: seed 003
    §4), then the proxy's frames and D^ (the guard reads them), the guard, the limits, the
    row."""
    m = model[0]
    d = data[0]
    blend_weights(m, d)
    train_begin(m.train, d.train, d.god, d.god_blend, d.dt)
    finger(m, d)
    slot = m.slots[0]
    train_end(m.train, d.train, m.god, d.god_blend, slot.shapes, slot.n_shapes, d.dt)
    proxy_kinematics(m, d)
    blend_model(m, d)
    runaway_guard(m, d)
    safety_and_limits(m, d)
    fill_row(m, d)
    fill_train_row(m.train, d.train, d.row)


@njit(cache=True)
def begin_tick(data, io, world_map, clock):
    """The device reading into the world frame; the log row starts with the clock (data.dt
    and the row's timing fields are engine_step's)."""
    d = data[0]
    dio = io[0]
    c = clock[0]
    map_sensors_to_world(world_map, dio.sensors, d.sensors)
    m = world_map[0]
    src = dio.sensors[0]
    r = d.row
    for k in range(3):
        d.hand_measured[k] = d.sensors[0].hand_wrench[k]
        r.hand_wrench[k] = dio.hand[k] / (m.force_scale * m.scale[k])
        r.wrench_command[k] = 0.0
        r.world_offset[k] = m.offset[k]
    for k in range(r.device_aux.shape[0]):
        r.device_aux[k] = src.aux[k]
    r.tick = c.tick
    r.t = c.t
    r.device_fault = src.fault
    r.update_seq = c.update_seq
    r.update_age_ms = c.update_age_ms


@njit(cache=True)
def engine_step(recs, dt, lateness_us, work_us):
    """One tick in one Python -> numba transition: the reading mapped to the world, the
    scene's method's tick (rendering_tick: the local model and control, or the god-object),
    the command mapped back to the device frame and clipped at the device's own limits, then
    the map's rate-control step (seed 002 §4). recs is the engine's (model, data, io,
    world_map, clock, method marker). dt, lateness_us and work_us are what the loop measured
    for this tick (arguments, not record fields: a field write from Python costs more than
    the whole call)."""
    model, data, io, world_map, clock, god = recs
    begin_tick(data, io, world_map, clock)
    d = data[0]
    d.dt = dt
    r = d.row
    r.lateness_us = lateness_us
    r.work_us = work_us
    r.dt = dt
    slot = model[0].slots[0]
    r.update_epoch = slot.epoch
    r.dof = slot.dof
    if clock[0].ready == 1:
        rendering_tick(model, data, god)
    dio = io[0]
    map_command_to_device(world_map, r.wrench_command, dio.max_wrench, dio.command)
    map_rate_step(world_map, dio.sensors[0].pose, dt)
    clock[0].tick += 1
    clock[0].t += dt


@njit(cache=True)
def store_applied(world_map, applied, data):
    """The wrench the device reports it applied (device frame), into the row (world frame)."""
    map_wrench_to_world(world_map, applied, data[0].row.wrench_applied)


@njit(cache=True)
def store_row(rows, k, row):
    """rows[k] = row[0] (a numpy record copy costs 2 us from Python)."""
    rows[k] = row[0]
