"""A held chain in a user's own pymunk space against our own linkage scene (issue 44,
done-when 2): seed 000's three-link arm built in a plain space with PivotJoints
(sim_server/held_chain.py), its distal link held, against `linkage_distal`'s own world, both
with the device starting on the operational point (ideal_identity, push_04n, 60 Hz, the
virtual clock): the VM's error against the independent reference (RMS, max, mm) and the
drift |x_h - x_VM| (steady, max, mm). Target: the user's within 10 % of ours.

    python -m haptic_local_model.benchmarks.user_chain [--seconds 5]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys

import numpy as np
import pymunk

from haptic_local_model.benchmarks.linkage import DEVICE, USER, drift_metrics, reference_error_mm
from haptic_local_model.device_models.registry import load_device
from haptic_local_model.haptic_server.harness.virtual import run_virtual
from haptic_local_model.shared.config import LinkageSpec, SceneConfig, load_scene, load_user
from haptic_local_model.sim_server.user_space import UserSpaceWorld


def plain_arm(space: pymunk.Space, lk: LinkageSpec) -> list[pymunk.Body]:
    """The linkage as a user builds it: a body per link, its origin at its pivot, its x axis
    along the link, a PivotJoint to the previous link (the first to the static body)."""
    bodies: list[pymunk.Body] = []
    pos, angle = np.array(lk.base, dtype=float), lk.base_angle
    for i, length in enumerate(lk.lengths):
        body = pymunk.Body(lk.masses[i], lk.inertias[i])
        body.center_of_gravity = lk.com_offsets[i]
        angle += lk.initial_angles[i]
        body.angle = angle
        body.position = (float(pos[0]), float(pos[1]))
        prev = bodies[-1] if bodies else space.static_body
        joint = pymunk.PivotJoint(prev, body, (float(pos[0]), float(pos[1])))
        joint.collide_bodies = False
        space.add(body, pymunk.Segment(body, (0.0, 0.0), (length, 0.0), lk.radius), joint)
        bodies.append(body)
        pos = pos + length * np.array([math.cos(angle), math.sin(angle)])
    return bodies


def figures(scene: SceneConfig, ticks: np.ndarray, seconds: float) -> dict[str, float]:
    err = reference_error_mm(scene, ticks, seconds)
    drift = drift_metrics(ticks)
    return {
        "rms_mm": float(np.sqrt(np.mean(err**2))),
        "max_mm": float(err.max()),
        "steady_drift_mm": drift["steady_drift_mm"],
        "max_drift_mm": drift["max_drift_mm"],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seconds", type=float, default=5.0)
    args = parser.parse_args(argv)
    scene = dataclasses.replace(load_scene("linkage_distal"), initial_device_offset=(0.0, 0.0, 0.0))
    user = load_user(USER)
    ours = run_virtual(scene, load_device(DEVICE), user, args.seconds).ticks
    space = pymunk.Space()
    arm = plain_arm(space, scene.tool_linkage)
    world = UserSpaceWorld(space, arm[scene.tool.link])
    theirs = run_virtual(world.scene, load_device(DEVICE), user, args.seconds, None, None, world)
    a, b = figures(scene, ours, args.seconds), figures(scene, theirs.ticks, args.seconds)
    print(f"{'figure':<18}{'linkage_distal':>16}{'user space':>12}{'ratio':>8}")
    for key in a:
        print(f"{key:<18}{a[key]:>16.4f}{b[key]:>12.4f}{b[key] / max(a[key], 1e-12):>8.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
