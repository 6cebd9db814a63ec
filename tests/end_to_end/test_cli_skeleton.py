"""A hand driven by a skeleton through the command line (docs/skeleton.md, Section 8): `simulate`
writes each bone's pose, target, springs' wrench and contact force per frame; `check-rig`
reports what each bone holds and how much of the hand's weight it carries."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from haptic_hand.engine import mesh
from haptic_hand.engine import skeleton as sk

SAMPLES = Path(__file__).resolve().parents[2] / "addon" / "engine" / "sample_scenes"


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "haptic_hand", *args], capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("skeleton_cli")
    shutil.copy(SAMPLES / "procedural_hand_tets.npz", d / "hand_tets.npz")
    turn = [0.0, np.sin(0.2), 0.0, np.cos(0.2)]  # 0.4 rad about y: the index finger curls towards the palm side
    scene = {"format": "haptic_hand.scene/1", "frames": 12,
             "hand": {"mesh": "procedural", "tets": "hand_tets.npz", "skeleton": "procedural"},
             "skeleton": {"targets": [{"t": 0.0, "bones": {"index_1": {"quaternion": [0, 0, 0, 1]}}},
                                      {"t": 0.2, "bones": {"index_1": {"quaternion": turn}}}]}}
    (d / "scene.json").write_text(json.dumps(scene))
    return d


def test_simulate_writes_each_bones_pose_target_wrench_and_contact_force(scene_dir):
    out = scene_dir / "result.npz"
    proc = run_cli("simulate", str(scene_dir / "scene.json"), "--out", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    r = np.load(out)
    rig = sk.procedural_hand_skeleton()
    assert list(r["bone_names"]) == list(rig.names) and list(r["bone_parents"]) == list(rig.parents)
    n = len(r["rest_nodes"])
    assert r["bone_pose"].shape == r["bone_target"].shape == (13, 16, 7)
    assert r["bone_wrench"].shape == (13, 16, 6) and r["bone_contact_force"].shape == (13, 16, 3)
    assert np.array_equal(r["bone_nodes"], rig.capture(r["rest_nodes"])) and r["bone_region"].shape == (n,)
    # frame 0 is the rest: bones at their centres of mass, unturned
    assert np.allclose(r["bone_pose"][0, :, 3:], [0, 0, 0, 1], atol=0)
    # the keyed turn, held from 0.2 s: index_1's and its children's targets are turned by it
    i1, i3 = rig.index("index_1"), rig.index("index_3")
    assert np.allclose(r["bone_target"][-1, i1:i3 + 1, 3:], [0.0, np.sin(0.2), 0.0, np.cos(0.2)], atol=1e-12)
    # and the finger followed: index_3 turned most of the way, the little finger stayed
    angle = 2 * np.arccos(np.clip(np.abs(r["bone_pose"][-1, :, 6]), 0, 1))
    assert angle[i3] > 0.5 * 0.4 and angle[rig.index("little_3")] < 0.05 * 0.4
    # nothing touches but the fingers themselves, and their pushes on the hand cancel
    assert np.abs(r["bone_contact_force"][-1].sum(axis=0)).max() < 1e-9


def test_check_rig_reports_each_bones_nodes_and_the_weight_it_carries(scene_dir):
    proc = run_cli("check-rig", str(scene_dir / "scene.json"), "--json")
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    checks = {c["name"]: c for c in report["checks"]}
    assert report["ok"] and {"bones", "droop", "weight", "schur_vs_monolithic"} <= set(checks)
    stored = np.load(scene_dir / "hand_tets.npz")
    owner = sk.procedural_hand_skeleton().capture(stored["nodes"])  # the numpy capture rule
    assert [b["n_nodes"] for b in checks["bones"]["bones"]] == list(np.bincount(owner[owner >= 0], minlength=16))
    # the bones' springs carry the whole hand: its mass is the density times its tets' volume
    hand_mass = 1000.0 * mesh.tet_signed_volumes(stored["nodes"], stored["tets"]).sum()
    carried = sum(b["carries"] for b in checks["droop"]["bones"])
    assert carried == pytest.approx(hand_mass, rel=1e-3) and checks["weight"]["relative_error"] < 1e-3
    assert checks["schur_vs_monolithic"]["relative_difference"] < 1e-8
    readable = run_cli("check-rig", str(scene_dir / "scene.json"))
    assert "index_1" in readable.stdout and "rig is ready" in readable.stdout


def test_with_the_root_on_the_device_the_hand_follows_it_and_the_fingers_keep_their_pose(scene_dir):
    """skeleton.root_device, gravity off: the device moves 2 cm along x and turns 0.3 rad about z
    over 0.3 s; the palm follows it through the coupling, and the keyed finger rides along,
    its target its keyed pose relative to the palm, carried by the palm's pose."""
    scene = json.loads((scene_dir / "scene.json").read_text())
    turn = [0.0, 0.0, np.sin(0.15), np.cos(0.15)]
    scene.update({"gravity": [0, 0, 0], "frames": 20,
                  "device": {"trajectory": [{"t": 0.0, "position": [0, 0, 0], "quaternion": [0, 0, 0, 1]},
                                            {"t": 0.3, "position": [0.02, 0, 0], "quaternion": turn}]}})
    scene["skeleton"]["root_device"] = True
    (scene_dir / "device.json").write_text(json.dumps(scene))
    out = scene_dir / "device.npz"
    proc = run_cli("simulate", str(scene_dir / "device.json"), "--out", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    r = np.load(out)
    palm, device = r["bone_pose"][-1, 0], r["device_pose"][-1]
    assert np.allclose(r["bone_target"][-1, 0], device, atol=1e-12)
    assert np.linalg.norm(palm[:3] - device[:3]) < 5e-4 and abs(abs(palm[3:] @ device[3:]) - 1) < 1e-5
    rig = sk.procedural_hand_skeleton()
    i3 = rig.index("index_3")
    keyed_turn = Rotation.from_quat([0.0, np.sin(0.2), 0.0, np.cos(0.2)])
    # the finger's keyed pose relative to the unmoved palm, carried by the palm's pose at the
    # start of the last step
    rest, head1 = r["bone_pose"][0, :, :3], rig.bones[rig.index("index_1")].head
    keyed = head1 + keyed_turn.apply(rest[i3] - head1)
    carrier = Rotation.from_quat(r["bone_pose"][-2, 0, 3:])
    expected = r["bone_pose"][-2, 0, :3] + carrier.apply(keyed - rest[0])
    assert np.allclose(r["bone_target"][-1, i3, :3], expected, atol=1e-12)
    # and the hand went along: every bone within 3 mm of its target (the keyed finger's flesh
    # holds it back most), the little finger, not keyed, carried 2 cm or more with the palm
    assert np.linalg.norm(r["bone_pose"][-1, :, :3] - r["bone_target"][-1, :, :3], axis=1).max() < 0.003
    assert np.linalg.norm(r["bone_pose"][-1, rig.index("little_3"), :3] - rest[rig.index("little_3")]) > 0.02


def joint_gaps(result) -> np.ndarray:
    """Per frame and joint, |p_child - p_parent| of the child's rest head carried by each bone's
    pose (frame 0: the rest centres of mass)."""
    rig = sk.procedural_hand_skeleton()
    pose = result["bone_pose"]
    rest = pose[0, :, :3]
    gaps = []
    for c, p in enumerate(rig.parents):
        if p < 0:
            continue
        head = np.asarray(rig.bones[c].head, float)
        ends = [pose[:, b, :3] + Rotation.from_quat(pose[:, b, 3:]).apply(head - rest[b]) for b in (p, c)]
        gaps.append(np.linalg.norm(ends[1] - ends[0], axis=1))
    return np.array(gaps).T


def test_ball_joints_from_the_scene_hold_the_curling_finger_to_its_parents(scene_dir):
    """skeleton.joints.stiffness through `simulate` (the world's step, docs/skeleton.md Section 5):
    the curling index finger's joints open less than without joints, and the run is the same
    hand otherwise (the finger still follows its key)."""
    scene = json.loads((scene_dir / "scene.json").read_text())
    scene["skeleton"]["joints"] = {"stiffness": 2e4, "damping": 5.0}
    (scene_dir / "joints.json").write_text(json.dumps(scene))
    runs = []
    for name in ("scene.json", "joints.json"):
        out = scene_dir / f"{name}.npz"
        proc = run_cli("simulate", str(scene_dir / name), "--out", str(out), "--quiet")
        assert proc.returncode == 0, proc.stderr
        runs.append(np.load(out))
    plain, joints = (joint_gaps(r) for r in runs)
    print(f"largest joint gap: {plain.max() * 1e3:.3g} mm without joints, {joints.max() * 1e3:.3g} mm with")
    assert joints.max() < 0.5 * plain.max()
    i3 = sk.procedural_hand_skeleton().index("index_3")
    angle = 2 * np.arccos(np.clip(np.abs(runs[1]["bone_pose"][-1, i3, 6]), 0, 1))
    assert angle > 0.5 * 0.4
