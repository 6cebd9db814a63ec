"""What drives a skeleton hand's bones in a scene run (docs/skeleton.md, Sections 4 and 8): each
bone's target at the end of every step, from the scene's keyed targets or its tracking stream,
with the root on the device trajectory when skeleton.root_device is on. Every driven bone
follows its target through its own virtual coupling (the root with coupling.*, the others with
skeleton.drive.*), or reaches it at the end of the step (skeleton.drive.prescribed); a bone of
drive_scale 0 is free."""

from __future__ import annotations

import numpy as np

from . import native_skeleton as ns
from . import quaternion as quat
from . import skeleton as sk
from . import tracking
from .trajectory import Trajectory
from .scene_skeleton import SceneSkeleton


def for_scene(scene, model) -> "BoneDrive":
    """The bones' drive of a scene (scene.Scene) on its model (which gives the bones' rest
    centres of mass and the root's, which the device trajectory is relative to)."""
    coms = [model.bone_info(b)["com"] for b in range(model.n_bones)]
    device = scene.trajectory(np.array(model.info()["handle_com"]))
    return BoneDrive(scene.skeleton, coms, device, bool(scene.data["device"]["enabled"]))


class BoneDrive:
    def __init__(self, rig: SceneSkeleton, coms: np.ndarray, device: Trajectory, device_on: bool):
        """coms: the bones' rest centres of mass (B, 3), as the model computed them."""
        self.rig, self.coms, self.device = rig, np.asarray(coms, dtype=float), device
        driven = ns.PRESCRIBED if rig.prescribed else ns.COUPLED
        self.modes = np.where(rig.drive_scales > 0, driven, ns.FREE).astype(np.int32)
        if rig.root_device:  # the device holds the root through the coupling, as it holds the palm handle
            self.modes[0] = ns.COUPLED if device_on else ns.FREE
        self.previous = None  # the last targets set: the next step's velocities are backward differences
        # per keyed bone: its turn and head offsets over time, and its rest head (None: the head
        # rides on the parent)
        self.keyed = {}
        for b, track in rig.tracks.items():
            offsets = track.positions if track.positions is not None else np.zeros((len(track.times), 3))
            head = None if track.positions is None else np.asarray(rig.skeleton.bones[b].head, dtype=float)
            self.keyed[b] = (Trajectory(track.times, offsets, track.quaternions), head)

    def animated(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Every bone's pose at t from the keyed targets or the tracking stream (rest without)."""
        rig = self.rig
        if rig.stream is not None:
            return tracking.bone_targets(rig.stream, rig.skeleton, self.coms, rig.tracking_map, t)
        turns, heads = [None] * len(rig.skeleton), [None] * len(rig.skeleton)
        for b, (track, head) in self.keyed.items():
            offset, turns[b] = track.pose(t)
            if head is not None:
                heads[b] = head + offset
        return sk.pose_bones(rig.skeleton, self.coms, turns, heads)

    def targets(self, t: float, root: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """The bones' targets at t. With the root on the device, the root's is the device's pose
        and every other bone keeps its animated pose relative to the animated root, carried by
        the root's actual pose `root` (position, quaternion): T_b = T_root T_root,anim^-1 T_b,anim."""
        p, q = self.animated(t)
        if not self.rig.root_device:
            return p, q
        x_root, q_root = root
        relative = quat.multiply(q_root, quat.conjugate(q[0]))
        out_p = x_root + (p - p[0]) @ quat.to_matrix(relative).T
        out_q = quat.multiply(relative, q)
        out_p[0], out_q[0] = self.device.pose(t)
        return out_p, out_q

    def apply(self, world, hand: int, t: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Sets the targets of the step that ends at t, velocities by backward difference over
        the step; returns the target poses."""
        root = None
        if self.rig.root_device:  # (the only drive that reads the bones back)
            positions, quaternions, _ = world.bone_states(hand)
            root = (positions[0], quaternions[0])
        p, q = self.targets(t, root)
        p0, q0 = self.previous if self.previous is not None else self.targets(t - dt, root)
        v = (p - p0) / dt
        w = quat.rotation_vector(quat.multiply(q, quat.conjugate(q0))) / dt
        world.set_bone_targets(hand, self.modes, p, q, v, w)
        self.previous = (p, q)
        return p, q
