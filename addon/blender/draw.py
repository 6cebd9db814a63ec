"""Viewport overlays (gpu module, drawn in the 3D viewport after the scene): a live session's
handle sphere, device and proxy poses and feedback force as an arrow; and the skeleton's
capsules, each capsule bone's radius around its segment, carried by the armature's pose.

The geometry is made by plain functions (tested headless); the draw callbacks only hand it to
the GPU, and return at once when there is nothing to draw. Headless nothing is ever drawn:
adding and removing the handlers is all that happens.
"""

from __future__ import annotations

import math

import bpy
import numpy as np

FORCE_SCALE = 0.01  # metres of arrow per newton

# What the live session last published (world, scene units); None when no session runs.
overlay: dict | None = None
_handles = []


def circle(centre, axis_u, axis_v, radius: float, segments: int = 48) -> np.ndarray:
    """Line-segment vertices (2 * segments, 3) of a circle."""
    a = np.linspace(0.0, 2.0 * math.pi, segments + 1)
    ring = centre + radius * (np.cos(a)[:, None] * axis_u + np.sin(a)[:, None] * axis_v)
    return np.stack([ring[:-1], ring[1:]], axis=1).reshape(-1, 3)


def sphere_lines(centre, radius: float, rotation=np.eye(3), segments: int = 48) -> np.ndarray:
    """Three great circles of a sphere, turned by rotation (3x3): shows the handle's orientation."""
    c = np.asarray(centre, dtype=float)
    r = np.asarray(rotation, dtype=float)
    return np.concatenate([circle(c, r[:, i], r[:, (i + 1) % 3], radius, segments) for i in range(3)])


def arrow_lines(origin, vector, head: float = 0.25) -> np.ndarray:
    """Line-segment vertices of an arrow from origin along vector (empty if vector is ~0)."""
    o, v = np.asarray(origin, dtype=float), np.asarray(vector, dtype=float)
    length = np.linalg.norm(v)
    if length < 1e-9:
        return np.zeros((0, 3))
    d = v / length
    side = np.cross(d, [0.0, 0.0, 1.0] if abs(d[2]) < 0.9 else [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    tip = o + v
    back = tip - head * length * d
    return np.array([o, tip, tip, back + 0.5 * head * length * side, tip, back - 0.5 * head * length * side])


def _square_axes(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors square to axis (a unit vector) and to each other."""
    u = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def capsule_lines(head, tail, radius: float, segments: int = 24) -> np.ndarray:
    """Line-segment vertices of a capsule (the points within radius of the segment head-tail):
    a circle square to the axis at each end, four lines along it and a half circle capping each
    end in two planes; a sphere's great circles when head == tail."""
    h, t = np.asarray(head, dtype=float), np.asarray(tail, dtype=float)
    length = np.linalg.norm(t - h)
    if length < 1e-12:
        return sphere_lines(h, radius, segments=segments)
    axis = (t - h) / length
    u, v = _square_axes(axis)
    out = [circle(h, u, v, radius, segments), circle(t, u, v, radius, segments)]
    out += [np.array([h + radius * w, t + radius * w]) for w in (u, -u, v, -v)]
    a = np.linspace(0.0, math.pi, segments // 2 + 1)
    for end, outward in ((t, axis), (h, -axis)):
        for w in (u, v):
            arc = end + radius * (np.cos(a)[:, None] * w + np.sin(a)[:, None] * outward)
            out.append(np.stack([arc[:-1], arc[1:]], axis=1).reshape(-1, 3))
    return np.concatenate(out)


def rig_lines(scene) -> np.ndarray:
    """The skeleton's capsules (scene units): each capsule bone's radius around its segment as
    the armature's pose carries it now (at rest, the region it captures)."""
    from . import armature, meshdata

    chain = armature.chain_of(scene)
    arm_obj = scene.haptic_hand.armature
    bones = [b for b, _ in chain]
    scale = meshdata.unit_scale(scene)
    heads, tails = armature.rest_segments(arm_obj, bones, scale)
    world = meshdata.matrix(arm_obj)
    out = [np.zeros((0, 3))]
    for bone, (radius, _) in zip(bones, armature.radii(scene, bones, heads, tails)):
        if radius is not None:
            pose = arm_obj.pose.bones[bone.name]
            ends = meshdata.transform(world, np.array([pose.head, pose.tail], dtype=float))
            out.append(capsule_lines(ends[0], ends[1], radius / scale))
    return np.concatenate(out)


def overlay_lines(data: dict) -> dict:
    """Coloured line sets of an overlay: {"handle": ..., "force": ..., "device": ..., "proxy": ...}."""
    from ..engine.quaternion import to_matrix

    out = {"handle": sphere_lines(data["handle_position"], data["radius"],
                                  to_matrix(data["handle_quaternion"]))}
    out["force"] = arrow_lines(data["handle_position"], np.asarray(data["force"]) * data["force_scale"])
    for name in ("device", "proxy"):
        p = np.asarray(data[f"{name}_position"], dtype=float)
        s = 0.1 * data["radius"]
        out[name] = np.array([p - [s, 0, 0], p + [s, 0, 0], p - [0, s, 0], p + [0, s, 0], p - [0, 0, s],
                              p + [0, 0, s]])
    return out


COLOURS = {"handle": (0.2, 0.9, 0.3, 1.0), "force": (1.0, 0.25, 0.1, 1.0), "device": (0.2, 0.5, 1.0, 1.0),
           "proxy": (1.0, 0.9, 0.2, 1.0), "capsules": (0.2, 0.9, 0.3, 0.6)}


def _draw_lines(sets: dict) -> None:
    import gpu
    from gpu_extras.batch import batch_for_shader

    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    gpu.state.line_width_set(2.0)
    for name, lines in sets.items():
        if len(lines) == 0:
            continue
        batch = batch_for_shader(shader, "LINES", {"pos": lines.astype(np.float32).tolist()})
        shader.uniform_float("color", COLOURS[name])
        batch.draw(shader)
    gpu.state.line_width_set(1.0)


def _draw():
    if overlay is not None:
        _draw_lines(overlay_lines(overlay))


def _draw_rig():
    scene = bpy.context.scene
    s = getattr(scene, "haptic_hand", None)
    if s is None or s.armature is None or s.hand is None or overlay is not None:
        return
    try:
        lines = rig_lines(scene)
    except Exception:  # a rig being edited (no deforming bone, ...): the panel says what is wrong
        return
    _draw_lines({"capsules": lines})


def register():
    for callback in (_draw, _draw_rig):
        _handles.append(bpy.types.SpaceView3D.draw_handler_add(callback, (), "WINDOW", "POST_VIEW"))


def unregister():
    global overlay
    while _handles:
        bpy.types.SpaceView3D.draw_handler_remove(_handles.pop(), "WINDOW")
    overlay = None
