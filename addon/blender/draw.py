"""Viewport overlay of a live session: the handle sphere, the device and proxy poses and the
feedback force as an arrow (gpu module, drawn in the 3D viewport after the scene).

The geometry is made by plain functions (tested headless); the draw callback only hands it to
the GPU, and returns at once when there is nothing to draw. Headless nothing is ever drawn:
adding and removing the handler is all that happens.
"""

from __future__ import annotations

import math

import bpy
import numpy as np

FORCE_SCALE = 0.01  # metres of arrow per newton

# What the live session last published (world, scene units); None when no session runs.
overlay: dict | None = None
_handle = None


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
           "proxy": (1.0, 0.9, 0.2, 1.0)}


def _draw():
    if overlay is None:
        return
    import gpu
    from gpu_extras.batch import batch_for_shader

    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    gpu.state.line_width_set(2.0)
    for name, lines in overlay_lines(overlay).items():
        if len(lines) == 0:
            continue
        batch = batch_for_shader(shader, "LINES", {"pos": lines.astype(np.float32).tolist()})
        shader.uniform_float("color", COLOURS[name])
        batch.draw(shader)
    gpu.state.line_width_set(1.0)


def register():
    global _handle
    _handle = bpy.types.SpaceView3D.draw_handler_add(_draw, (), "WINDOW", "POST_VIEW")


def unregister():
    global _handle, overlay
    if _handle is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_handle, "WINDOW")
        _handle = None
    overlay = None
