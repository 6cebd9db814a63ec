"""A skeleton hand's device in a haptic session from a scene (docs/haptics.md, "A skeleton hand"):
one frame per bone.

The simulated glove user follows the bones' targets (skeleton.targets or the tracking stream,
sampled at every frame): the root's frame is the simulated arm (haptics.arm.*), pushed by the
root's feedback, and every other bone's frame a glove finger (haptics.glove.*), pushed by its own
bone's feedback when the feedback is per bone or per group, posed (on its script, feeling
nothing) when it is the palm's. With skeleton.root_device the root's frame is the palm device on
the device trajectory and the fingers are posed on it, as the root carries them without haptics
(bone_drive). An external glove's frames are pushed by the host."""

from __future__ import annotations

import numpy as np

from . import bone_drive
from .scene_feedback import PALM


def targets(bones: bone_drive.BoneDrive, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Every frame's script at t: the bones' targets, with skeleton.root_device the root on the
    device trajectory and the others carried by its scripted pose."""
    return bones.targets(t, bones.device.pose(t))


def scripts(scene, bones: bone_drive.BoneDrive) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frames' scripts sampled at every frame of the run: times (n,), positions (n, B, 3),
    quaternions (n, B, 4); the glove interpolates between them."""
    times = np.arange(scene.frames + 1) * scene.dt
    poses = [targets(bones, t) for t in times]
    return times, np.array([p for p, _ in poses]), np.array([q for _, q in poses])


def arms(scene, n_bones: int) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's arm (mass, stiffness, damping), (B, 3): the root's the simulated arm's, the
    others the glove's fingers'; and which frames are posed (B,)."""
    h = scene.data["haptics"]
    row = [[h[part][k] for k in ("mass", "stiffness", "damping")] for part in ("arm", "glove")]
    out = np.array([row[0]] + [row[1]] * (n_bones - 1), dtype=float)
    posed = np.full(n_bones, scene.skeleton.root_device or scene.feedback.mode == PALM)
    posed[0] = False
    return out, posed


def attach(session, scene, model, kind: str, fail_at: float) -> None:
    """Gives a skeleton hand's session its device (kind: 'simulated' or 'external'; a one-bone
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
