"""The log's Foxglove channels, read as a viewer reads them: by the stock `mcap` reader with the
stock protobuf decoder built from the schemas the file carries (no project code decodes them),
and checked against the tick rows they were drawn from."""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from haptic_local_model.haptic_server.foxglove_view import (
    FORCE_M_PER_N,
    LOG_TOPIC,
    SCENE_TOPIC,
    TRANSFORMS_TOPIC,
    VIEW_HZ,
    ViewFrames,
)
from haptic_local_model.haptic_server.harness.virtual import run_virtual_named
from haptic_local_model.haptic_server.log import TICK_TOPIC, LogWriter, read_ticks
from haptic_local_model.haptic_server.logger import LogDrain
from haptic_local_model.haptic_server.mailbox import C_TICK_HEAD, SharedBlock
from haptic_local_model.shared.config import load_scene

SECONDS = 2.0


def _decoded(path: Path) -> dict[str, list[tuple[int, str, Any]]]:
    """topic -> [(log time, schema name, decoded message)]."""
    out: dict[str, list[tuple[int, str, Any]]] = defaultdict(list)
    with path.open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(
            topics=[SCENE_TOPIC, TRANSFORMS_TOPIC, LOG_TOPIC], log_time_order=True
        ):
            out[channel.topic].append((message.log_time, schema.name, decoded))
    return out


@pytest.fixture(scope="module")
def wall_push_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("fox") / "wall_push.mcap"
    run_virtual_named("wall_push", "ideal", "push_2n", SECONDS, path)
    return path


@pytest.mark.processes
def test_the_channels_carry_foxglove_schemas(wall_push_log: Path) -> None:
    msgs = _decoded(wall_push_log)
    assert {s for _, s, _ in msgs[SCENE_TOPIC]} == {"foxglove.SceneUpdate"}
    assert {s for _, s, _ in msgs[TRANSFORMS_TOPIC]} == {"foxglove.FrameTransforms"}
    frames = len(msgs[TRANSFORMS_TOPIC])
    assert abs(frames - SECONDS * VIEW_HZ) <= 1  # VIEW_HZ of log time


@pytest.mark.processes
def test_the_static_bodies_are_drawn_where_the_scene_puts_them(wall_push_log: Path) -> None:
    scene = load_scene("wall_push")
    statics = [b for b in scene.bodies if b.kind == "static"]
    assert statics, "wall_push has a static wall"
    first = _decoded(wall_push_log)[SCENE_TOPIC][0][2]
    (entity,) = [e for e in first.entities if e.id == "static"]
    shapes = list(entity.cubes) + list(entity.lines) + list(entity.cylinders)
    assert len(shapes) == len(statics)
    for body in statics:
        if body.shape == "box":
            assert any(
                math.isclose(c.pose.position.x, body.position[0])
                and math.isclose(c.pose.position.y, body.position[1])
                and math.isclose(c.size.x, body.size[0])
                and math.isclose(c.size.y, body.size[1])
                for c in entity.cubes
            ), body.name


@pytest.mark.processes
def test_transforms_and_force_arrows_follow_the_tick_rows(wall_push_log: Path) -> None:
    ticks = read_ticks(wall_push_log)
    with wall_push_log.open("rb") as fh:
        tick_times = [
            m.log_time for _s, _c, m in make_reader(fh).iter_messages(topics=[TICK_TOPIC])
        ]
    row_at = {t: k for k, t in enumerate(tick_times)}
    msgs = _decoded(wall_push_log)
    pushed = 0
    for log_ns, _, frame in msgs[TRANSFORMS_TOPIC]:
        row = ticks[row_at[log_ns]]  # every frame is drawn from the row logged at its time
        by_child = {t.child_frame_id: t for t in frame.transforms}
        for child, pose in (("device", row["device_pose"]), ("proxy", row["vm_pose"])):
            t = by_child[child]
            assert (t.translation.x, t.translation.y) == pytest.approx(tuple(pose[:2]), abs=1e-12)
            assert 2 * math.atan2(t.rotation.z, t.rotation.w) == pytest.approx(pose[2], abs=1e-9)
    for log_ns, _, update in msgs[SCENE_TOPIC][1:]:
        row = ticks[row_at[log_ns]]
        (forces,) = [e for e in update.entities if e.id == "forces"]
        x, y = row["device_pose"][:2]
        at_device = [a for a in forces.arrows if (a.pose.position.x, a.pose.position.y) == (x, y)]
        force = float(np.hypot(*row["wrench_command"][:2]))
        if force * FORCE_M_PER_N > 1e-4:
            (arrow,) = at_device
            length = arrow.shaft_length + arrow.head_length
            assert length == pytest.approx(force * FORCE_M_PER_N, rel=1e-9)
            direction = 2 * math.atan2(arrow.pose.orientation.z, arrow.pose.orientation.w)
            fx, fy = row["wrench_command"][:2]
            assert math.remainder(direction - math.atan2(fy, fx), 2 * math.pi) == pytest.approx(
                0.0, abs=1e-9
            )
            pushed += 1
    # the device and the proxy are drawn once, locked to the frames the transforms move
    markers = [e for _, _, u in msgs[SCENE_TOPIC] for e in u.entities if e.frame_locked]
    assert sorted((e.id, e.frame_id) for e in markers) == [("device", "device"), ("proxy", "proxy")]
    assert pushed > 0.5 * SECONDS * VIEW_HZ  # the user pushes 2 N most of the run
    # the wall's contact appears, at the contact points of the installed updates
    assert any(
        len(e.spheres) > 0
        for _, _, u in msgs[SCENE_TOPIC]
        for e in u.entities
        if e.id == "contacts"
    )


@pytest.mark.processes
def test_a_failing_view_never_stops_the_log(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The Foxglove channels are extras: if drawing them raises, the writer says so once and
    goes on writing every tick row."""

    def broken(self: ViewFrames, row: Any, log_ns: int) -> Any:
        raise ValueError("drawing failed")

    monkeypatch.setattr(ViewFrames, "frame", broken)
    rows = read_ticks(_small_log(tmp_path))
    block = SharedBlock.create()
    try:
        block.ticks[: len(rows)] = rows
        block.ctl[C_TICK_HEAD] = len(rows)
        log = LogWriter(tmp_path / "out.mcap", {})
        drain = LogDrain(block, log, 10**18)
        drain.drain(len(rows), 0.0)
        log.close()
        assert drain.view_failed == "ValueError: drawing failed"
        np.testing.assert_array_equal(read_ticks(tmp_path / "out.mcap"), rows)
    finally:
        shm = block.shm
        block.release()
        shm.close()
        shm.unlink()


def _small_log(tmp_path: Path) -> Path:
    path = tmp_path / "small.mcap"
    run_virtual_named("wall_push", "ideal", "push_2n", 0.5, path)
    return path


def test_the_shipped_layout_is_generated_and_names_what_logs_hold() -> None:
    """docs/foxglove/layout.json is layout_json()'s (foxglove-sdk's layout API), and every
    topic and tick field its panels read is one the log writes."""
    import json
    import re

    from haptic_local_model.haptic_server.foxglove_view import layout_json
    from haptic_local_model.haptic_server.model import TICK_DTYPE

    shipped = (Path(__file__).resolve().parent.parent / "docs/foxglove/layout.json").read_text()
    assert shipped == layout_json()
    text = json.dumps(json.loads(shipped))
    for topic, field in re.findall(r'"(/haptic/tick)\.(\w+)\[\d\]"', text):
        assert topic == TICK_TOPIC and field in TICK_DTYPE.names, field
    assert SCENE_TOPIC in text
