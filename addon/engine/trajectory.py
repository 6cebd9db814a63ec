"""Timed poses, interpolated: positions linear, orientations slerp, held at both ends. A device's
trajectory, a kinematic body's script, a tracked joint's motion."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import quaternion


@dataclass
class Trajectory:
    """Timed device poses; linear in position, slerp in orientation, held at both ends."""

    times: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        k = int(np.searchsorted(self.times, t, side="right")) - 1
        if k < 0:
            return self.positions[0].copy(), self.quaternions[0].copy()
        if k >= len(self.times) - 1:
            return self.positions[-1].copy(), self.quaternions[-1].copy()
        a = (t - self.times[k]) / (self.times[k + 1] - self.times[k])
        p = (1 - a) * self.positions[k] + a * self.positions[k + 1]
        return p, quaternion.slerp(self.quaternions[k], self.quaternions[k + 1], a)

    def velocity(self, t: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Linear and angular velocity over [t - dt, t] (the step that ends at t)."""
        p1, q1 = self.pose(t)
        p0, q0 = self.pose(t - dt)
        return (p1 - p0) / dt, quaternion.rotation_vector(quaternion.multiply(q1, quaternion.conjugate(q0))) / dt
