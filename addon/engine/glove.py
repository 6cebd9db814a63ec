"""A skeleton hand's device in a haptic session from a scene (docs/haptics.md, "A skeleton hand").

Without skeleton.root_device the device is a glove of one frame per bone. The simulated glove user
follows the bones' targets (skeleton.targets or the tracking stream, sampled at every frame): the
root's frame is the simulated arm (haptics.arm.*), pushed by the root's feedback, and every other
bone's frame a glove finger (haptics.glove.*), pushed by its own bone's feedback when the feedback
is per bone or per group, posed (on its script, feeling nothing) when it is the palm's. An external
glove's frames are pushed by the host.

With skeleton.root_device the device is one frame on the wrist, whichever kind (the simulated arm
on the device trajectory, a playback, OpenHaptics, HID, the host-pushed external device), and the
other bones are posed on it (pose_fingers): each keeps its animated pose relative to the animated
root, as the root carries them without haptics (bone_drive), and the device feels the whole hand's
wrench."""

from __future__ import annotations

import numpy as np

from . import bone_drive
from . import quaternion as quat
from .scene_feedback import PALM


def targets(bones: bone_drive.BoneDrive, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Every frame's script at t: the bones' targets, with skeleton.root_device the root on the
    device trajectory and the others carried by its scripted pose."""
    return bones.targets(t, bones.device.pose(t))


def frame_times(scene) -> np.ndarray:
    """The times the glove's scripts are sampled at: every frame of the run; the session
    interpolates between them."""
    return np.arange(scene.frames + 1) * scene.dt


def scripts(scene, bones: bone_drive.BoneDrive) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frames' scripts sampled at every frame of the run: times (n,), positions (n, B, 3),
    quaternions (n, B, 4)."""
    times = frame_times(scene)
    poses = [targets(bones, t) for t in times]
    return times, np.array([p for p, _ in poses]), np.array([q for _, q in poses])


def relative(bones: bone_drive.BoneDrive, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every bone's animated pose relative to the animated root at each time, rel_b =
    T_root,anim^-1 T_b,anim: positions (n, B, 3) in the root's frame, quaternions (n, B, 4)."""
    rel_p, rel_q = [], []
    for t in times:
        p, q = bones.animated(t)
        back = quat.conjugate(q[0])
        rel_p.append((p - p[0]) @ quat.to_matrix(q[0]))  # R_root^T (p_b - p_root), row by row
        turns = np.array([quat.multiply(back, qb) for qb in q])
        rel_q.append(turns / np.linalg.norm(turns, axis=1)[:, None])
    return np.array(rel_p), np.array(rel_q)


def pose_fingers(session, scene, model) -> None:
    """skeleton.root_device: poses every bone but the root on the session's one-frame device
    (given next), each at its animated pose relative to the root sampled at every frame."""
    times = frame_times(scene)
    session.pose_fingers(times, *relative(bone_drive.for_scene(scene, model), times))


def arms(scene, n_bones: int) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's arm (mass, stiffness, damping), (B, 3): the root's the simulated arm's, the
    others the glove's fingers'; and which frames are posed (B,)."""
    h = scene.data["haptics"]
    row = [[h[part][k] for k in ("mass", "stiffness", "damping")] for part in ("arm", "glove")]
    out = np.array([row[0]] + [row[1]] * (n_bones - 1), dtype=float)
    posed = np.full(n_bones, scene.feedback.mode == PALM)
    posed[0] = False
    return out, posed


def attach(session, scene, model, kind: str, fail_at: float) -> None:
    """Gives a skeleton hand's session its glove (kind: 'simulated' or 'external'; a one-bone
    skeleton's session is the palm handle's: its simulated arm follows the root's script) and
    its feedback groups."""
    fb = scene.feedback
    if fb.group_of_bone is not None:
        session.set_feedback_groups(fb.group_of_bone, len(fb.group_names))
    if kind == "external":
        session.device_external_frames(scene.data["haptics"]["external_timeout"])
        return
    times, positions, quaternions = scripts(scene, bone_drive.for_scene(scene, model))
    arm, posed = arms(scene, session.n_bones)
    if session.n_bones == 1:
        session.device_simulated(times, positions[:, 0], quaternions[:, 0], *arm[0], fail_at)
        return
    session.device_simulated_glove(times, positions, quaternions, arms=arm, posed=posed, fail_at=fail_at)
