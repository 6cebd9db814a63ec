"""Unit quaternions (x, y, z, s), as in the paper's Appendix A and the native engine."""

from __future__ import annotations

import math

import numpy as np


def multiply(a, b) -> np.ndarray:
    """a b, of one quaternion each or of arrays (..., 4) of them. Written out per component: a
    skeleton's drive turns every bone every step, and np.cross on 3-vectors took most of it."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack([aw * bx + bw * ax + ay * bz - az * by,
                     aw * by + bw * ay + az * bx - ax * bz,
                     aw * bz + bw * az + ax * by - ay * bx,
                     aw * bw - ax * bx - ay * by - az * bz], axis=-1)


def conjugate(q) -> np.ndarray:
    return np.asarray(q, dtype=float) * np.array([-1.0, -1.0, -1.0, 1.0])


def rotation_vector(q) -> np.ndarray:
    """The rotation vector (axis times angle, rad) of q, the shorter way round; of one
    quaternion or of arrays (..., 4) of them."""
    q = np.asarray(q, dtype=float)
    q = np.where(q[..., 3:] >= 0, q, -q)
    vn = np.linalg.norm(q[..., :3], axis=-1, keepdims=True)
    small = vn < 1e-12  # (2 atan2(|v|, s) / |v| -> 2 as |v| -> 0 with s = 1)
    scale = np.where(small, 2.0, 2.0 * np.arctan2(vn, q[..., 3:]) / np.where(small, 1.0, vn))
    return scale * q[..., :3]


def from_rotation_vector(theta) -> np.ndarray:
    theta = np.asarray(theta, dtype=float)
    angle = float(np.linalg.norm(theta))
    k = 0.5 - angle * angle / 48.0 if angle < 1e-8 else math.sin(0.5 * angle) / angle
    return np.concatenate([k * theta, [math.cos(0.5 * angle)]])


def slerp(q0, q1, a: float) -> np.ndarray:
    q0, q1 = np.asarray(q0, dtype=float), np.asarray(q1, dtype=float)
    if q0 @ q1 < 0:
        q1 = -q1
    angle = math.acos(min(1.0, float(q0 @ q1)))
    if angle < 1e-9:
        q = (1 - a) * q0 + a * q1
    else:
        q = (math.sin((1 - a) * angle) * q0 + math.sin(a * angle) * q1) / math.sin(angle)
    return q / np.linalg.norm(q)


def to_matrix(q) -> np.ndarray:
    x, y, z, s = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - s * z), 2 * (x * z + s * y)],
        [2 * (x * y + s * z), 1 - 2 * (x * x + z * z), 2 * (y * z - s * x)],
        [2 * (x * z - s * y), 2 * (y * z + s * x), 1 - 2 * (x * x + y * y)],
    ])
