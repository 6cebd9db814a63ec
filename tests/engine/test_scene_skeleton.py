"""The skeleton in the scene format (docs/skeleton.md, Section 8; docs/scene_format.md):
`hand.skeleton` ("procedural" or a list of bones, by capsule or explicit nodes) builds the rig
the skeleton module describes, and `skeleton.targets`, `.root_device` and the drive settings
give each bone the target docs/skeleton.md, Section 4 defines, checked against scipy's
rotations and interpolation rather than the code's own quaternion helpers."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from haptic_hand.engine import native_skeleton as ns
from haptic_hand.engine import scene as scenes
from haptic_hand.engine import skeleton as sk
from haptic_hand.engine.bone_drive import BoneDrive

SAMPLES = Path(sk.__file__).resolve().parent / "sample_scenes"


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("skeleton")
    shutil.copy(SAMPLES / "procedural_hand_tets.npz", d / "hand_tets.npz")
    return d


def procedural_scene(scene_dir, skeleton="procedural", **section) -> scenes.Scene:
    data = {"format": scenes.FORMAT, "hand": {"mesh": "procedural", "tets": "hand_tets.npz", "skeleton": skeleton},
            "skeleton": section}
    return scenes.from_dict(json.loads(json.dumps(data)), scene_dir)


def bone_list(skeleton: sk.Skeleton) -> list:
    return [{"name": b.name, "parent": b.parent, "head": list(b.head), "tail": list(b.tail), "radius": b.radius}
            for b in skeleton.bones]


def test_the_procedural_skeleton_is_the_16_bone_rig_captured_as_the_python_rule_says(scene_dir):
    scene = procedural_scene(scene_dir)
    model = scenes.build_model(scene)
    assert isinstance(model, ns.SkeletonModel) and model.n_bones == 16
    expected = sk.procedural_hand_skeleton().capture(scene.nodes)  # the independent numpy capture
    assert np.array_equal(model.node_bones(), expected)


def test_a_bone_list_builds_the_same_rig_by_capsules_or_by_explicit_nodes(scene_dir):
    rig = sk.procedural_hand_skeleton()
    by_capsules = scenes.build_model(procedural_scene(scene_dir, bone_list(rig)))
    owner = by_capsules.node_bones()
    bones = bone_list(rig)
    for b in (0, 5):  # the palm and index_2 by their node lists (a vertex group's nodes) instead
        bones[b] = {**bones[b], "radius": None, "nodes": [int(i) for i in np.flatnonzero(owner == b)]}
    by_nodes = scenes.build_model(procedural_scene(scene_dir, bones))
    assert np.array_equal(by_nodes.node_bones(), owner)
    assert np.array_equal(owner, rig.capture(by_capsules.nodes))


def test_the_scenes_joint_stiffness_reaches_the_model(scene_dir):
    """skeleton.joints.stiffness (docs/skeleton.md Section 5) builds the model's ball joints: the
    bone index_1 moved 1 mm off its rest pose stretches two joints (its own to the palm and
    index_2's on it) by 1 mm each, which adds 2 * k (1 mm)^2 / 2 to the springs' energy against
    the same scene without joints."""
    k = 4e3
    energies = []
    for joints in ({}, {"stiffness": k}):
        model = scenes.build_model(procedural_scene(scene_dir, joints=joints))
        sim = ns.SkeletonSimulation(model)
        p, q, v, w = sim.bone_states()
        index_1 = model.skeleton.names.index("index_1")
        p[index_1] += [1e-3, 0.0, 0.0]
        sim.set_bone_states(p, q, v, w)
        energies.append(sim.energies()["spring"])
    assert energies[1] - energies[0] == pytest.approx(2 * 0.5 * k * 1e-3 ** 2, rel=1e-9)


def test_the_scenes_bone_limits_reach_the_model(scene_dir):
    """hand.skeleton[].limits and .axes with skeleton.joints.limit_stiffness (docs/skeleton.md
    Section 5): index_2 turned 0.3 rad about its rest x axis (turned from the world's) against a
    range of 0.1 rad adds k/2 (0.2 rad)^2 to the springs' energy, against the scene without
    limit stiffness; turned about the free y axis it adds nothing."""
    k = 0.7
    axes = Rotation.from_rotvec([0.0, 0.0, 0.4]).as_matrix()
    bones = bone_list(sk.procedural_hand_skeleton())
    index_2 = [b["name"] for b in bones].index("index_2")
    bones[index_2] = {**bones[index_2], "limits": {"min": [-0.1, None, -0.2], "max": [0.1, None, 0.2]},
                      "axes": axes.tolist()}
    for axis, added in ((0, 0.5 * k * 0.2 ** 2), (1, 0.0)):
        energies = []
        for joints in ({}, {"limit_stiffness": k}):
            model = scenes.build_model(procedural_scene(scene_dir, bones, joints=joints))
            sim = ns.SkeletonSimulation(model)
            p, q, v, w = sim.bone_states()
            turn = Rotation.from_rotvec(0.3 * axes[:, axis])  # about the bone's own axis, world frame
            q[index_2] = (turn * Rotation.from_quat(q[index_2])).as_quat()
            sim.set_bone_states(p, q, v, w)
            energies.append(sim.energies()["spring"])
        assert energies[1] - energies[0] == pytest.approx(added, rel=1e-9, abs=1e-15)


@pytest.mark.parametrize("limits, axes, message", [
    ({"min": [-0.1, 0.1, 0.0], "max": [0.1, 0.2, 0.0]}, None, r"limits = .* does not hold the bone's rest pose"),
    ({"low": [0, 0, 0]}, None, r"limits = .* is invalid: give \{\"min\""),
    ({"min": [-0.1, "a", 0.0]}, None, r"limits.min = .* is invalid: give three angles in radians"),
    ({"min": [float("nan"), 0.0, 0.0]}, None, r"limits = .* is invalid: give angles within \(-pi, pi\)"),
    ({"max": [4.0, None, None]}, None, r"limits = .* is invalid: give angles within \(-pi, pi\)"),
    (None, [[2, 0, 0], [0, 1, 0], [0, 0, 1]], r"axes = .* is not a rotation matrix"),
    (None, "x", r"axes = .* is not a rotation matrix"),
])
def test_bad_bone_limits_in_a_scene_name_the_field_and_the_fix(scene_dir, limits, axes, message):
    bones = bone_list(sk.procedural_hand_skeleton())
    bones[5] = {**bones[5], "limits": limits, "axes": axes}
    with pytest.raises(scenes.SceneError, match=r"hand.skeleton\[5\] \('index_2'\)\." + message):
        procedural_scene(scene_dir, bones)
    bones = bone_list(sk.procedural_hand_skeleton())
    bones[0] = {**bones[0], "limits": {"min": [-0.1, -0.1, -0.1]}}
    with pytest.raises(scenes.SceneError, match=r"hand.skeleton\[0\] \('palm'\) is a root with limits"):
        procedural_scene(scene_dir, bones)


def drive_of(scene: scenes.Scene, device=None) -> BoneDrive:
    model = scenes.build_model(scene)
    coms = np.array([model.bone_info(b)["com"] for b in range(model.n_bones)])
    device = device or scene.trajectory(coms[0])
    return BoneDrive(scene.skeleton, coms, device, bool(scene.data["device"]["enabled"]))


def test_keyed_targets_are_linear_in_position_slerp_in_turn_and_children_ride_on_their_parents(scene_dir):
    """The palm's head moves 2 cm and turns 40 degrees about x between two keys; index_1 turns
    60 degrees about y (world) from rest, no position: at t = 0.3 of the way, the palm's target
    is its rest centre of mass carried by the interpolated motion about its head (scipy's
    Slerp), index_1 turns about its own head, which the palm carries, and index_2, not keyed,
    moves rigidly with index_1."""
    turn_palm, turn_index = Rotation.from_rotvec([np.radians(40), 0, 0]), Rotation.from_rotvec([0, np.radians(60), 0])
    keys = [{"t": 0.0, "bones": {"palm": {"position": [0, 0, 0], "quaternion": [0, 0, 0, 1]},
                                 "index_1": {"quaternion": [0, 0, 0, 1]}}},
            {"t": 1.0, "bones": {"palm": {"position": [0.02, 0, 0], "quaternion": list(turn_palm.as_quat())},
                                 "index_1": {"quaternion": list(turn_index.as_quat())}}}]
    drive = drive_of(procedural_scene(scene_dir, targets=keys))
    rig, coms, t = drive.rig.skeleton, drive.coms, 0.3
    p, q = drive.animated(t)
    palm_turn = Slerp([0, 1], Rotation.concatenate([Rotation.identity(), turn_palm]))([t])[0]
    index_turn = Slerp([0, 1], Rotation.concatenate([Rotation.identity(), turn_index]))([t])[0]
    palm_head = rig.bones[0].head + [0.02 * t, 0, 0]

    def by_palm(x):
        return palm_head + palm_turn.apply(x - rig.bones[0].head)

    i1, i2 = rig.index("index_1"), rig.index("index_2")
    index_head = by_palm(rig.bones[i1].head)
    assert np.allclose(p[0], by_palm(coms[0]), atol=1e-14)
    assert np.allclose(p[i1], index_head + index_turn.apply(coms[i1] - rig.bones[i1].head), atol=1e-14)
    assert np.allclose(p[i2], index_head + index_turn.apply(coms[i2] - rig.bones[i1].head), atol=1e-14)
    assert abs(abs(q[i1] @ index_turn.as_quat()) - 1) < 1e-14 and abs(abs(q[i2] @ index_turn.as_quat()) - 1) < 1e-14
    m = rig.index("middle_1")  # not keyed: it rides on the palm
    assert np.allclose(p[m], by_palm(coms[m]), atol=1e-14)
    # held beyond the last key
    end = rig.bones[0].head + [0.02, 0, 0] + turn_palm.apply(coms[0] - rig.bones[0].head)
    assert np.allclose(drive.animated(5.0)[0][0], end, atol=1e-14)


def test_with_the_root_on_the_device_the_fingers_keep_their_pose_relative_to_the_root(scene_dir):
    """root_device: the palm's target is the device's pose; a keyed finger's target is its
    animated pose relative to the animated palm, carried by the palm's actual pose."""
    turn = Rotation.from_rotvec([0, np.radians(30), 0])
    keys = [{"t": 0.0, "bones": {"index_3": {"quaternion": list(turn.as_quat())}}}]
    scene = procedural_scene(scene_dir, targets=keys, root_device=True)
    scene.data["device"]["trajectory"] = [{"t": 0.0, "position": [0.01, 0.0, 0.02], "quaternion": [0, 0, 0, 1]}]
    drive = drive_of(scene)
    actual = (drive.coms[0] + [0.0, 0.005, 0.0], Rotation.from_rotvec([0.2, 0.0, 0.0]).as_quat())
    p, q = drive.targets(0.0, actual)
    assert np.allclose(p[0], drive.coms[0] + [0.01, 0.0, 0.02], atol=1e-15) and np.allclose(q[0], [0, 0, 0, 1])
    animated_p, animated_q = drive.animated(0.0)
    carried = Rotation.from_quat(actual[1])
    i3 = drive.rig.skeleton.index("index_3")
    assert np.allclose(p[i3], actual[0] + carried.apply(animated_p[i3] - animated_p[0]), atol=1e-14)
    assert abs(abs(q[i3] @ (carried * Rotation.from_quat(animated_q[i3])).as_quat()) - 1) < 1e-14
    assert drive.modes[0] == ns.COUPLED  # the device holds the root through coupling.*


def test_drive_modes_follow_drive_scale_prescribed_and_the_device_switch(scene_dir):
    bones = bone_list(sk.procedural_hand_skeleton())
    bones[3]["drive_scale"] = 0.0
    assert list(drive_of(procedural_scene(scene_dir, bones)).modes) == [ns.COUPLED] * 3 + [ns.FREE] + [ns.COUPLED] * 12
    prescribed = drive_of(procedural_scene(scene_dir, bones, drive={"prescribed": True}, root_device=True))
    assert list(prescribed.modes) == [ns.COUPLED, ns.PRESCRIBED, ns.PRESCRIBED, ns.FREE] + [ns.PRESCRIBED] * 12
    scene = procedural_scene(scene_dir, root_device=True)
    scene.data["device"]["enabled"] = False
    assert drive_of(scene).modes[0] == ns.FREE
