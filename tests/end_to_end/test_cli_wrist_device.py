"""A skeleton hand driven from one real device on the wrist, the fingers posed on it
(skeleton.root_device; docs/skeleton.md, Section 6): a playback recording through `simulate`
turns the 16-bone procedural hand 90 degrees while moving it, the finger frames ride on the
wrist's, and a finger pressed on a floor pushes the wrist device with the whole contact force."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from haptic_hand.engine import scene as scenes
from haptic_hand.engine.scene_world import build_world

SAMPLES = Path(__file__).resolve().parents[2] / "addon" / "engine" / "sample_scenes"
CURL = [0.0, np.sin(0.2), 0.0, np.cos(0.2)]  # index_1 turned 0.4 rad: a finger whose pose on the wrist changes


def hand_scene(d: Path, **extra) -> dict:
    shutil.copy(SAMPLES / "procedural_hand_tets.npz", d / "hand_tets.npz")
    scene = {"format": "haptic_hand.scene/1", "frames": 24, "gravity": [0, 0, 0],
             "hand": {"mesh": "procedural", "tets": "hand_tets.npz", "skeleton": "procedural"},
             "skeleton": {"root_device": True},
             "haptics": {"enabled": True, "device": "playback:wrist.csv"}}
    scene.update(extra)
    return scene


def root_com(d: Path, scene: dict) -> np.ndarray:
    """The root bone's rest centre of mass, where the wrist device starts."""
    (d / "scene.json").write_text(json.dumps(scene))
    _, _, model, _, _ = build_world(scenes.load(d / "scene.json"))
    return np.array(model.bone_info(0)["com"])


def simulate(d: Path, times, positions, quaternions) -> dict:
    np.savetxt(d / "wrist.csv", np.column_stack([times, positions, quaternions]), delimiter=",")
    proc = subprocess.run([sys.executable, "-m", "haptic_hand", "simulate", str(d / "scene.json"), "--out",
                           str(d / "result.npz"), "--quiet"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    return dict(np.load(d / "result.npz"))


def test_a_turning_playback_wrist_carries_the_posed_fingers(tmp_path):
    """The wrist turns 90 degrees about x while it moves 3.6 cm (a smooth 0.4 s reach, then held
    0.4 s), the index finger curling on the hand meanwhile. Every haptic frame of a finger is the
    wrist's frame carried by the finger's animated pose relative to the animated root (1e-12),
    and, held, every visual-loop bone sits on its frame within what its coupling yields to the
    force it feels, F / k (k = coupling.stiffness): at rest k (x_frame - x_bone) = F."""
    scene = hand_scene(tmp_path)
    scene["skeleton"]["targets"] = [{"t": 0.0, "bones": {"index_1": {"quaternion": [0, 0, 0, 1]}}},
                                    {"t": 0.3, "bones": {"index_1": {"quaternion": CURL}}}]
    com = root_com(tmp_path, scene)
    t = np.linspace(0, 0.4, 41)
    s = 0.5 - 0.5 * np.cos(np.pi * t / 0.4)
    r = simulate(tmp_path, t, com + np.outer(s, [0.03, 0.0, 0.02]), Rotation.from_rotvec(np.outer(s * np.pi / 2, [1, 0, 0])).as_quat())

    frames, rest = r["haptic_bone_device"], r["bone_pose"][0]
    wrist_end = Rotation.from_rotvec([np.pi / 2, 0, 0])
    assert np.allclose(frames[-1, 0, :3], com + [0.03, 0.0, 0.02], atol=1e-12)
    assert min(np.abs(frames[-1, 0, 3:] - wrist_end.as_quat()).max(), np.abs(frames[-1, 0, 3:] + wrist_end.as_quat()).max()) < 1e-12
    # each finger's pose relative to the unturned root at rest: the rest offset, and the curled
    # index chain's turned about index_1's head once the curl is held (t >= 0.3 s)
    from haptic_hand.engine import skeleton as sk
    rig = sk.procedural_hand_skeleton()
    i1, i3 = rig.index("index_1"), rig.index("index_3")
    head = rig.bones[i1].head
    for k in range(10, len(frames)):  # frame 10 is t = 0.33 s
        wrist = Rotation.from_quat(frames[k, 0, 3:])
        for b in range(1, 16):
            offset, turn = rest[b, :3] - rest[0, :3], Rotation.identity()
            if i1 <= b <= i3:
                turn = Rotation.from_quat(CURL)
                offset = head + turn.apply(rest[b, :3] - head) - rest[0, :3]
            assert np.linalg.norm(frames[k, b, :3] - (frames[k, 0, :3] + wrist.apply(offset))) < 1e-12, (k, b)
            q = (wrist * turn).as_quat()
            assert min(np.abs(frames[k, b, 3:] - q).max(), np.abs(frames[k, b, 3:] + q).max()) < 1e-12, (k, b)
    # the wrist's turn carried the fingertips: the middle fingertip moved by centimetres
    assert np.linalg.norm(frames[-1, rig.index("middle_3"), :3] - rest[rig.index("middle_3"), :3]) > 0.1
    # held 0.4 s: each bone within twice F / k of its frame (measured: 0.13 mm against the
    # largest F / k, 0.21 mm; the couplings are still settling at 16 mm/s)
    k_coupling = json.loads(str(r["scene"]))["coupling"]["stiffness"]
    gap = np.linalg.norm(r["bone_pose"][-1, :, :3] - frames[-1, :, :3], axis=1)
    felt = np.linalg.norm(r["haptic_bone_feedback"][-1, :, :3], axis=1)
    assert gap.max() < 2 * felt.max() / k_coupling + 1e-5, (gap, felt / k_coupling)


def test_a_finger_pressed_on_a_floor_pushes_the_wrist_device_with_its_contact_force(tmp_path):
    """The hand lowered 2 mm onto a floor at its lowest node (the middle fingertip's; the next
    lowest, the ring fingertip, stays 3 mm above the contact's reach) and held: only the middle
    finger's last bone touches. The flesh carries the push to every bone, so the fingertip's
    own bone feels part of it; the wrist device, the fingers posed on it, is commanded the sum
    over every bone, which at rest (gravity off: the springs' forces balance the contact) is the
    contact force (2 %; measured 1e-9)."""
    lowest = float(np.load(SAMPLES / "procedural_hand_tets.npz")["nodes"][:, 2].min())
    scene = hand_scene(tmp_path, bodies=[{"name": "floor", "type": "plane", "point": [0, 0, lowest],
                                          "normal": [0, 0, 1]}])
    com = root_com(tmp_path, scene)
    t = np.linspace(0, 0.2, 21)
    s = 0.5 - 0.5 * np.cos(np.pi * t / 0.2)
    r = simulate(tmp_path, t, com + np.outer(s, [0, 0, -0.002]), np.tile([0, 0, 0, 1.0], (len(t), 1)))
    from haptic_hand.engine import skeleton as sk
    tip = sk.procedural_hand_skeleton().index("middle_3")
    contact = r["bone_contact_force"][-1]
    touching = np.flatnonzero(np.linalg.norm(contact, axis=1) > 0)
    assert list(touching) == [tip] and contact[tip, 2] > 1.0, contact
    commanded = r["haptic_force"][-1]
    assert np.linalg.norm(commanded - contact.sum(axis=0)) < 0.02 * np.linalg.norm(contact[tip])
    # the fingertip's bone alone or the root alone would feel far less (the check can fail)
    felt = r["haptic_bone_feedback"][-1, :, :3]
    assert np.linalg.norm(felt[tip]) < 0.8 * contact[tip, 2] and np.linalg.norm(felt[0]) < 0.2 * contact[tip, 2]
