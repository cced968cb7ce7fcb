"""What the log writer adds for viewers: Foxglove's well-known channels, beside the project's own.

Foxglove (and Lichtblick) draw these without project code: `/foxglove/scene`
(`foxglove.SceneUpdate`: the scene's static bodies, the device and the proxy once, then
their force arrows and the contacts of the newest update), `/foxglove/transforms`
(`foxglove.FrameTransforms`: world -> device, world -> proxy) and `/foxglove/log`
(`foxglove.Log`: the run's events). The writer builds them from the tick rows and updates it
writes anyway, at VIEW_HZ of log time, off the real-time loop. The plane of the scene is the
x-y plane of the 3D view (z up, out of the plane); moving and dynamic bodies are the sim's
and are not in the log (their contacts with the tool are).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from haptic_local_model.shared.config import BodySpec, static_bodies
from haptic_local_model.shared.protocol.update import UpdateParser

SCENE_TOPIC = "/foxglove/scene"
TRANSFORMS_TOPIC = "/foxglove/transforms"
LOG_TOPIC = "/foxglove/log"
VIEW_HZ = 30.0  # frames a second of log time
WORLD = "world"
FORCE_M_PER_N = 0.01  # force arrows: 1 cm per newton
SLAB_M = 0.01  # thickness given to the planar shapes
NORMAL_ARROW_M = 0.02  # contact normals

_DEVICE = (0.20, 0.45, 0.95, 1.0)
_PROXY = (0.95, 0.35, 0.20, 1.0)
_STATIC = (0.55, 0.57, 0.60, 1.0)
_CONTACT = (0.10, 0.75, 0.30, 1.0)
WARNING_EVENTS = ("watchdog", "fault", "stale", "reject", "lost")  # shown as warnings


def _messages() -> Any:
    import foxglove.messages as m

    return m


def _quat(theta: float) -> Any:
    """A rotation by theta about z (the plane's normal)."""
    return _messages().Quaternion(x=0.0, y=0.0, z=math.sin(theta / 2), w=math.cos(theta / 2))


def _pose(x: float, y: float, theta: float, z: float = 0.0) -> Any:
    m = _messages()
    return m.Pose(position=m.Vector3(x=x, y=y, z=z), orientation=_quat(theta))


def _color(rgba: tuple[float, float, float, float]) -> Any:
    return _messages().Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _timestamp(ns: int) -> Any:
    return _messages().Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def _arrow(x: float, y: float, fx: float, fy: float, rgba: Any) -> Any | None:
    """An arrow from (x, y) along the force (fx, fy), FORCE_M_PER_N long per newton."""
    length = math.hypot(fx, fy) * FORCE_M_PER_N
    if not length > 1e-4:  # NaN included
        return None
    head = min(0.3 * length, 0.01)
    return _messages().ArrowPrimitive(
        pose=_pose(x, y, math.atan2(fy, fx)), shaft_length=length - head,
        shaft_diameter=0.002, head_length=head, head_diameter=0.006, color=_color(rgba),
    )  # fmt: skip


def _body_primitives(body: BodySpec) -> dict[str, list[Any]]:
    """A static body's shape as Foxglove primitives, in the world frame."""
    m = _messages()
    x, y, a = body.position[0], body.position[1], body.angle
    if body.shape == "box":
        cube = m.CubePrimitive(
            pose=_pose(x, y, a), size=m.Vector3(x=body.size[0], y=body.size[1], z=SLAB_M),
            color=_color(_STATIC),
        )  # fmt: skip
        return {"cubes": [cube]}
    if body.shape == "circle":
        d = 2 * body.radius
        disc = m.CylinderPrimitive(
            pose=_pose(x, y, a), size=m.Vector3(x=d, y=d, z=SLAB_M), bottom_scale=1.0,
            top_scale=1.0, color=_color(_STATIC),
        )  # fmt: skip
        return {"cylinders": [disc]}
    ends = [body.to_world(*body.a), body.to_world(*body.b)]
    line = m.LinePrimitive(
        type=m.LinePrimitiveLineType.LineStrip, pose=_pose(0.0, 0.0, 0.0),
        thickness=max(2 * body.radius, 0.002), scale_invariant=False,
        points=[m.Point3(x=px, y=py, z=0.0) for px, py in ends], color=_color(_STATIC),
    )  # fmt: skip
    return {"lines": [line]}


def _static_entity(scene_text: str | None, stamp: Any) -> Any | None:
    """The scene's static bodies (walls, floors) as one entity; None if the log's scene
    text is missing or does not load."""
    bodies = static_bodies(scene_text)
    if not bodies:
        return None
    parts: dict[str, list[Any]] = {"cubes": [], "cylinders": [], "lines": []}
    for body in bodies:
        for kind, prims in _body_primitives(body).items():
            parts[kind] += prims
    return _messages().SceneEntity(
        timestamp=stamp, frame_id=WORLD, id="static", frame_locked=False, **parts
    )


class ViewFrames:
    """The per-frame messages. The static bodies (from the scene config's text), the device
    and the proxy are drawn once, in the first frame, the last two as entities locked to their
    own frames, so a frame only moves the frames (FrameTransforms) and redraws the force
    arrows; the contacts are redrawn when an installed update changed them. `due` says
    whether a tick at `log_ns` starts a frame."""

    def __init__(self, scene_text: str | None = None) -> None:
        self._scene_text = scene_text
        self._parser = UpdateParser()
        self._contacts: list[tuple[float, float, float, float]] = []  # env x, y, normal x, y
        self._contacts_dirty = True
        self._markers_sent = False
        self._next_ns = -1
        self._period_ns = round(1e9 / VIEW_HZ)

    def due(self, log_ns: int) -> bool:
        if log_ns < self._next_ns:
            return False
        self._next_ns = log_ns + self._period_ns if self._next_ns < 0 else self._next_ns
        while self._next_ns <= log_ns:
            self._next_ns += self._period_ns
        return True

    def set_update(self, raw: bytes, installed: bool) -> None:
        """The contacts of an installed update (its environment points and normals)."""
        if not installed or self._parser.parse(raw) != 0:
            return
        out = self._parser.out[0]
        n = int(out["n_contacts"])
        env, normal = out["c_env"][:n].tolist(), out["c_normal"][:n].tolist()
        contacts = [(e[0], e[1], k[0], k[1]) for e, k in zip(env, normal, strict=True)]
        if contacts != self._contacts:
            self._contacts, self._contacts_dirty = contacts, True

    def frame(self, row: np.void, log_ns: int) -> tuple[Any, Any]:
        """(FrameTransforms, SceneUpdate) for one tick row."""
        m = _messages()
        stamp = _timestamp(log_ns)
        dev, vm = row["device_pose"], row["vm_pose"]
        transforms = m.FrameTransforms(
            transforms=[
                m.FrameTransform(
                    timestamp=stamp,
                    parent_frame_id=WORLD,
                    child_frame_id=child,
                    translation=m.Vector3(x=float(p[0]), y=float(p[1]), z=0.0),
                    rotation=_quat(float(p[2])),
                )
                for child, p in (("device", dev), ("proxy", vm))
            ]
        )
        command, contact = row["wrench_command"], row["contact_force_world"]
        arrows = [
            _arrow(float(p[0]), float(p[1]), float(f[0]), float(f[1]), rgba)
            for p, f, rgba in ((dev, command, _DEVICE), (vm, contact, _PROXY))
        ]
        entities = [
            m.SceneEntity(
                timestamp=stamp,
                frame_id=WORLD,
                id="forces",
                frame_locked=False,
                arrows=[a for a in arrows if a is not None],
            )
        ]
        if not self._markers_sent:
            self._markers_sent = True
            static = _static_entity(self._scene_text, stamp)
            entities += [] if static is None else [static]
            entities += [_marker("device", _DEVICE, stamp), _marker("proxy", _PROXY, stamp)]
        if self._contacts_dirty:
            self._contacts_dirty = False
            entities.append(self._contact_entity(stamp))
        return transforms, m.SceneUpdate(entities=entities)

    def _contact_entity(self, stamp: Any) -> Any:
        m = _messages()
        scale = NORMAL_ARROW_M / FORCE_M_PER_N  # a unit normal drawn NORMAL_ARROW_M long
        arrows = [_arrow(x, y, nx * scale, ny * scale, _CONTACT) for x, y, nx, ny in self._contacts]
        spheres = [
            m.SpherePrimitive(
                pose=_pose(x, y, 0.0),
                size=m.Vector3(x=0.004, y=0.004, z=0.004),
                color=_color(_CONTACT),
            )
            for x, y, _nx, _ny in self._contacts
        ]
        return m.SceneEntity(
            timestamp=stamp,
            frame_id=WORLD,
            id="contacts",
            frame_locked=False,
            arrows=[a for a in arrows if a is not None],
            spheres=spheres,
        )


def _marker(name: str, rgba: Any, stamp: Any) -> Any:
    """A labelled disc locked to the frame `name` (moved by /foxglove/transforms)."""
    m = _messages()
    disc = m.CylinderPrimitive(
        pose=_pose(0.0, 0.0, 0.0, SLAB_M), size=m.Vector3(x=0.012, y=0.012, z=0.004),
        bottom_scale=1.0, top_scale=1.0, color=_color(rgba),
    )  # fmt: skip
    label = m.TextPrimitive(
        pose=_pose(0.0, 0.015, 0.0, SLAB_M), billboard=True, font_size=12.0,
        scale_invariant=True, color=_color(rgba), text=name,
    )  # fmt: skip
    return m.SceneEntity(
        timestamp=stamp, frame_id=name, id=name, frame_locked=True, cylinders=[disc],
        texts=[label],
    )  # fmt: skip


def log_message(tick: int, kind: str, detail: str, log_ns: int) -> Any:
    """A foxglove.Log for one of the run's events (warnings for watchdog trips and faults)."""
    m = _messages()
    warn = any(w in kind for w in WARNING_EVENTS)
    return m.Log(
        timestamp=_timestamp(log_ns), level=m.LogLevel.Warning if warn else m.LogLevel.Info,
        message=f"{kind}: {detail}" if detail else kind, name="haptic_server",
        file=f"tick {tick}", line=0,
    )  # fmt: skip


def layout_json() -> str:
    """The shipped Foxglove layout (docs/foxglove/layout.json): the 3D view of the scene seen
    from above, following the world frame; plots of the device's commanded force and the
    proxy's contact force; the run's events."""
    import foxglove.layouts as fl

    def plot(title: str, field: str) -> Any:
        series = [
            fl.PlotSeries(value=f"/haptic/tick.{field}[{i}]", label=f"{field} {axis}", enabled=True)
            for i, axis in enumerate(("x", "y"))
        ]
        return fl.PlotPanel(title=title, config=fl.PlotConfig(paths=series, show_legend=True))

    three_d = fl.ThreeDeePanel(
        title="scene (from above)",
        config=fl.ThreeDeeConfig(
            follow_tf=WORLD, fixed_frame=WORLD, follow_mode="follow-none",
            camera_state=fl.ThreeDeeCameraState(
                distance=0.6, perspective=False, phi=0.0, target=(0.0, 0.0, 0.0)
            ),
            topics={SCENE_TOPIC: fl.BaseRendererSceneUpdateTopicSettings(visible=True)},
        ),
    )  # fmt: skip
    plots = fl.SplitContainer(
        direction="column",
        items=[
            fl.SplitItem(content=plot("device force command (N)", "wrench_command")),
            fl.SplitItem(content=plot("contact force on the proxy (N)", "contact_force_world")),
            fl.SplitItem(content=fl.LogPanel(title="events", config=fl.LogConfig())),
        ],
    )
    content = fl.SplitContainer(
        direction="row",
        items=[fl.SplitItem(proportion=2, content=three_d), fl.SplitItem(content=plots)],
    )
    return str(fl.Layout(content=content).to_json()) + "\n"
