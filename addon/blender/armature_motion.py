"""The armature's animation <-> the scene file's bone targets (`skeleton.targets`, docs/skeleton.md
Sections 4 and 8).

Export: the armature's pose is sampled every frame of the range (keyframes, constraints, IK,
mocap: whatever Blender evaluates), each deforming bone's world pose through the armature
object's matrix. A bone's target is its turn from its rest pose, `R(t) R(rest)ᵀ` in the world
frame (rest: the armature's rest pose at the first frame's object matrix, where the skeleton's
heads and tails are taken), and, when its head leaves the place its parent carries it to (a
root that moves, a bone with keyed location), its head's offset from rest. Pose scale is left
out: the bones are rigid.

Import: the targets keyed as the armature's action, one key per frame, each pose bone's local
rotation (and location where a bone's head moves on its own) such that the bone's world pose
is the engine's interpolated target (engine/bone_drive.py's rule), so an import exports back to
the same motion.
"""

from __future__ import annotations

import numpy as np

from ..engine import quaternion as quat
from ..engine import skeleton as sk
from . import actions, meshdata

# A bone whose head stays within this of where its parent carries it (m) gives no position.
RIDES = 1e-6


def _rotation(m: np.ndarray) -> np.ndarray:
    """The rotation of a 4x4 (or 3x3) matrix, scale removed (polar factor)."""
    u, _, vt = np.linalg.svd(np.asarray(m)[:3, :3])
    r = u @ vt
    return r if np.linalg.det(r) > 0 else -r


class PoseSampler:
    """Collects the deforming bones' world poses frame by frame; `targets` turns them into the
    scene file's keys. Built at the first frame, where the rest is taken."""

    def __init__(self, arm_obj, names: list[str], parents: list[str | None], scale: float):
        self.arm_obj, self.names, self.scale = arm_obj, names, scale
        self.parents = [None if p is None else names.index(p) for p in parents]
        world = meshdata.matrix(arm_obj)
        rest = [world @ np.array(arm_obj.data.bones[n].matrix_local, dtype=np.float64) for n in names]
        self.rest_turn = np.array([_rotation(m) for m in rest])
        self.rest_head = np.array([m[:3, 3] for m in rest]) * scale
        self.turns, self.heads = [], []

    def sample(self, depsgraph) -> None:
        """The bones' world poses now (after the frame was set)."""
        ev = self.arm_obj.evaluated_get(depsgraph)
        world = np.array(ev.matrix_world, dtype=np.float64)
        poses = [world @ np.array(ev.pose.bones[n].matrix, dtype=np.float64) for n in self.names]
        self.turns.append([_rotation(m) @ r0.T for m, r0 in zip(poses, self.rest_turn)])
        self.heads.append([m[:3, 3] * self.scale for m in poses])

    def targets(self, times) -> list[dict]:
        """skeleton.targets: one key per sampled frame naming every bone."""
        turns, heads = np.array(self.turns), np.array(self.heads)  # (F, B, 3, 3), (F, B, 3)
        own_head = self._moving_heads(turns, heads)
        keys = []
        for k, t in enumerate(times):
            bones = {}
            for b, name in enumerate(self.names):
                pose = {"quaternion": meshdata.quaternion_xyzs(turns[k, b]).tolist()}
                if own_head[b]:
                    pose["position"] = (heads[k, b] - self.rest_head[b]).tolist()
                bones[name] = pose
            keys.append({"t": float(t), "bones": bones})
        return keys

    def _moving_heads(self, turns: np.ndarray, heads: np.ndarray) -> list[bool]:
        """Which bones' heads leave where their parent carries them (a root: its rest head)."""
        out = []
        for b, p in enumerate(self.parents):
            if p is None:
                carried = np.broadcast_to(self.rest_head[b], heads[:, b].shape)
            else:
                carried = heads[:, p] + np.einsum("fij,j->fi", turns[:, p], self.rest_head[b] - self.rest_head[p])
            out.append(bool(np.linalg.norm(heads[:, b] - carried, axis=1).max() > RIDES))
        return out


def key_targets(arm_obj, drive, skeleton: sk.Skeleton, times, frames) -> None:
    """Keys the armature's action so that each bone's world pose at frames[k] is the engine's
    target at times[k]; drive: an engine BoneDrive built with the bones' rest heads as its
    centres (its `animated` poses are then each bone's moved head and turn). The armature
    object's matrix is taken as it stands; every bone of `skeleton` must be in the armature."""
    world = meshdata.matrix(arm_obj)
    inverse = np.linalg.inv(world)
    rests = {b.name: np.array(arm_obj.data.bones[b.name].matrix_local, dtype=np.float64) for b in skeleton.bones}
    order = skeleton.order
    rotations, locations = {b.name: [] for b in skeleton.bones}, {b.name: [] for b in skeleton.bones}
    for t in times:
        heads, turns = drive.animated(float(t))
        posed = {}
        for b in order:
            bone = skeleton.bones[b]
            motion = np.eye(4)  # the bone's rigid motion from rest, armature space
            motion[:3, :3] = quat.to_matrix(turns[b])
            motion[:3, 3] = heads[b] - motion[:3, :3] @ np.asarray(bone.head, dtype=float)
            motion = inverse @ motion @ world
            posed[bone.name] = motion
            parent = posed[bone.parent] if bone.parent is not None else np.eye(4)
            rest = rests[bone.name]
            basis = np.linalg.inv(rest) @ np.linalg.inv(parent) @ motion @ rest
            rotations[bone.name].append(meshdata.quaternion_xyzs(_rotation(basis)))
            locations[bone.name].append(basis[:3, 3])
    _write_action(arm_obj, frames, rotations, locations)


def _write_action(arm_obj, frames, rotations: dict, locations: dict) -> None:
    """One key per frame of every bone's rotation (quaternion, w first as Blender keeps it) and
    of the location of those whose head moves on its own."""
    action, slot, fcurves = actions.new_action(arm_obj, f"{arm_obj.name} targets")
    actions.assign_action(arm_obj, action, slot)
    for name, q in rotations.items():
        pose_bone = arm_obj.pose.bones[name]
        pose_bone.rotation_mode = "QUATERNION"
        wxyz = np.array(q)[:, [3, 0, 1, 2]]
        for i in range(1, len(wxyz)):  # the shorter way between keys
            if wxyz[i] @ wxyz[i - 1] < 0:
                wxyz[i] = -wxyz[i]
        for i in range(4):
            actions.fcurve(fcurves, f'pose.bones["{name}"].rotation_quaternion', i, frames, wxyz[:, i])
        loc = np.array(locations[name])
        if np.abs(loc).max() > RIDES:
            for i in range(3):
                actions.fcurve(fcurves, f'pose.bones["{name}"].location', i, frames, loc[:, i])
