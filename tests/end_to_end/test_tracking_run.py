"""A hand-tracking stream drives the procedural hand through `simulate` (docs/skeleton.md,
Sections 4 and 8): a recorded hand closing its fingers, written in MANO's and in OpenXR's joint
layout with tracking.write, retargeted onto the 16 bones. The bones' targets are the tracked
turns carried down each finger from its knuckle (computed here with scipy, not with
tracking.bone_targets), and once the stream holds still every bone sits where its drive
balances its springs, x_b = p*_b + F_b / k_b, which with 150 Hz drives is within half a
millimetre of its target when nothing is touched."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from haptic_hand.engine import skeleton as sk
from haptic_hand.engine import tracking

from bone_results import lumped_masses

SAMPLES = Path(__file__).resolve().parents[2] / "addon" / "engine" / "sample_scenes"
RIG = sk.procedural_hand_skeleton()
ANGLES = {"thumb": (10.0, 10.0, 10.0), "finger": (20.0, 20.0, 15.0)}  # degrees at each joint, closed
CLOSED_AT, HOLD_UNTIL, DRIVE = 0.8, 1.5, 150.0  # s, s, Hz


def closing_turns(fraction: float) -> dict:
    """Each finger and thumb bone's world turn from rest with the joints at `fraction` of
    ANGLES: a phalanx turns by the sum of its joints' angles about its digit's flexion axis
    (square to the digit, towards the palm side, -x)."""
    out = {}
    for digit in sk.DIGITS:
        first = RIG.bones[RIG.index(f"{digit}_1")]
        axis = np.cross(first.tail - first.head, [-1.0, 0.0, 0.0])
        axis /= np.linalg.norm(axis)
        angles = np.cumsum(ANGLES["thumb" if digit == "thumb" else "finger"]) * fraction
        for k, total in enumerate(angles):
            out[f"{digit}_{k + 1}"] = Rotation.from_rotvec(np.radians(total) * axis)
    return out


def posed_heads(turns: dict) -> dict:
    """Each finger bone's head carried by its parents' turns (the palm stays)."""
    heads = {"palm": RIG.bones[0].head}
    for b in sk.parents_first(RIG)[1:]:
        bone, parent = RIG.bones[b], RIG.bones[RIG.parents[b]]
        parent_turn = turns.get(parent.name, Rotation.identity())
        heads[bone.name] = heads[parent.name] + parent_turn.apply(bone.head - parent.head)
    return heads


def stream_of(layout: tracking.JointLayout) -> tracking.TrackingStream:
    """The closing hand as joint poses: each mapped joint at its bone's posed head, turned as
    the bone; joints that drive no bone (OpenXR's palm, metacarpals and tips) at the origin."""
    bone_of = tracking.PROCEDURAL_MAPS[layout.name]
    times = np.linspace(0.0, CLOSED_AT, 9)

    def frame(fraction):
        turns = closing_turns(fraction)
        heads = posed_heads(turns)
        p = np.array([heads[bone_of[j]] if j in bone_of else np.zeros(3) for j in layout.joints])
        q = np.array([turns.get(bone_of.get(j), Rotation.identity()).as_quat() for j in layout.joints])
        return p, q

    frames = [frame(t / CLOSED_AT) for t in times]
    rest_p, rest_q = frame(0.0)
    return tracking.TrackingStream(layout, times, np.array([p for p, _ in frames]), np.array([q for _, q in frames]),
                                   rest_p, rest_q)


@pytest.mark.parametrize("layout, suffix", [(tracking.MANO, ".csv"), (tracking.OPENXR, ".json")])
def test_a_tracked_hand_closing_drives_the_bones_to_its_retargeted_poses(tmp_path, layout, suffix):
    shutil.copy(SAMPLES / "procedural_hand_tets.npz", tmp_path / "hand_tets.npz")
    tracking.write(tmp_path / f"closing{suffix}", stream_of(layout))
    dt = 1.0 / 30.0
    scene = {"format": "haptic_hand.scene/1", "dt": dt, "frames": round(HOLD_UNTIL / dt),
             "hand": {"mesh": "procedural", "tets": "hand_tets.npz", "skeleton": "procedural"},
             "skeleton": {"tracking": f"closing{suffix}", "drive": {"frequency": DRIVE}}}
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    proc = subprocess.run([sys.executable, "-m", "haptic_hand", "simulate", str(tmp_path / "scene.json"), "--out",
                           str(tmp_path / "r.npz"), "--quiet"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    r = np.load(tmp_path / "r.npz")
    assert r["inverted_tets"].max() == 0

    # the targets: each bone's rest centre of mass turned about its head, the head carried down
    # the finger (the palm, its root joint still, stays)
    coms, turns = r["bone_pose"][0, :, :3], closing_turns(1.0)
    heads = posed_heads(turns)
    for b, bone in enumerate(RIG.bones):
        turn = turns.get(bone.name, Rotation.identity())
        expected = heads[bone.name] + turn.apply(coms[b] - bone.head)
        assert np.allclose(r["bone_target"][-1, b, :3], expected, atol=1e-12), bone.name
        assert abs(abs(r["bone_target"][-1, b, 3:] @ turn.as_quat()) - 1) < 1e-12, bone.name

    # held still for 0.7 s, nothing touched: every finger bone's coupling holds its springs,
    # k_b (p*_b - x_b) + F_b = 0 and k_r,b theta_b + T_b = 0, with the gains of
    # docs/skeleton.md, Section 4 from the bone's nodes' lumped masses and their inertia
    masses = lumped_masses(r, 1000.0)
    w = 2 * np.pi * DRIVE
    for b in range(1, len(RIG.bones)):
        nodes = r["bone_nodes"] == b
        m = masses[nodes]
        rel = r["rest_nodes"][nodes] - (m[:, None] * r["rest_nodes"][nodes]).sum(axis=0) / m.sum()
        k, k_r = m.sum() * w ** 2, 2.0 / 3.0 * (m * (rel ** 2).sum(axis=1)).sum() * w ** 2  # tr(I)/3 = 2/3 sum m r^2
        offset = r["bone_target"][-1, b, :3] - r["bone_pose"][-1, b, :3]
        theta = (Rotation.from_quat(r["bone_target"][-1, b, 3:]) * Rotation.from_quat(r["bone_pose"][-1, b, 3:]).inv())
        force, torque = r["bone_wrench"][-1, b, :3], r["bone_wrench"][-1, b, 3:]
        assert np.linalg.norm(k * offset + force) < 0.02 * np.linalg.norm(force) + 1e-4, RIG.names[b]
        assert np.linalg.norm(k_r * theta.as_rotvec() + torque) < 0.02 * np.linalg.norm(torque) + 1e-6, RIG.names[b]
        assert np.linalg.norm(offset) < 5e-4, RIG.names[b]

