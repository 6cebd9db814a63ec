"""Unit quaternions (x, y, z, s), as in the paper's Appendix A and the native engine."""

from __future__ import annotations

import math

import numpy as np


def multiply(a, b) -> np.ndarray:
    av, aw, bv, bw = np.asarray(a[:3]), a[3], np.asarray(b[:3]), b[3]
    return np.concatenate([aw * bv + bw * av + np.cross(av, bv), [aw * bw - av @ bv]])


def conjugate(q) -> np.ndarray:
    return np.array([-q[0], -q[1], -q[2], q[3]])


def rotation_vector(q) -> np.ndarray:
    """The rotation vector (axis times angle, rad) of q, the shorter way round."""
    q = np.asarray(q, dtype=float)
    q = q if q[3] >= 0 else -q
    vn = np.linalg.norm(q[:3])
    if vn < 1e-12:
        return 2.0 * q[:3]
    return 2.0 * math.atan2(vn, q[3]) / vn * q[:3]


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
