"""Use Armature as Skeleton: the armature's deforming bones become the scene's bones (world
metres through the armature object's matrix and the scene's unit scale), each capturing what
engine/skeleton.py's rule gives it; the automatic radius is the limb's; a bone can hold its
vertex group's flesh instead; every problem is named with its fix (panel, Check Rig, export);
the panel lists the bones and the viewport draws their capsules; a skeleton scene imports as an
armature keyed with its targets."""

import json
import math
import re

import pytest

bpy = pytest.importorskip("bpy")
import numpy as np
from scipy.spatial.transform import Rotation

from haptic_hand.blender import armature, draw, scene_export, scene_import
from haptic_hand.engine import mesh as meshing
from haptic_hand.engine import rig_check
from haptic_hand.engine import scene as scenes
from haptic_hand.engine import skeleton as sk

from blender_helpers import SAMPLES, build_hand, draw_panels, labels, props, rig_procedural_armature

REFERENCE = sk.procedural_hand_skeleton()


def rigged(context, scale: float = 1.0):
    hand = build_hand(context, scale=scale)
    return hand, rig_procedural_armature(context, hand, scale)


def test_bones_export_in_world_metres_through_the_armatures_matrix(addon):
    """A centimetre scene, the hand and its armature turned and moved together: the bones reach
    the scene as the procedural hand's moved the same way, in metres, and capture exactly what
    the engine's rule gives the moved procedural skeleton."""
    context, scale = addon, 0.01
    hand, arm = rigged(context, scale)
    turn, shift = Rotation.from_rotvec([0.3, -0.2, 0.5]), np.array([2.0, -1.0, 3.0])  # shift in cm
    for obj in (hand, arm):
        obj.rotation_mode = "QUATERNION"
        obj.rotation_quaternion = np.roll(turn.as_quat(), 1)
        obj.location = shift
    context.scene.haptic_hand.armature = None
    context.view_layer.objects.active = arm
    assert bpy.ops.haptic_hand.use_armature() == {"FINISHED"}
    assert context.scene.haptic_hand.armature == arm

    def moved(x):
        return turn.apply(x) + shift * scale

    export = scene_export.export(context)
    try:
        bones = export.scene.data["hand"]["skeleton"]
        nodes = export.scene.nodes
    finally:
        export.cleanup()
    assert [b["name"] for b in bones] == list(REFERENCE.names)
    for got, bone in zip(bones, REFERENCE.bones):
        np.testing.assert_allclose(got["head"], moved(bone.head), atol=1e-7)
        np.testing.assert_allclose(got["tail"], moved(bone.tail), atol=1e-7)
        assert got["parent"] == bone.parent and got["radius"] == pytest.approx(bone.radius, rel=1e-7)
    expected = sk.Skeleton([sk.Bone(b.name, b.parent, moved(b.head), moved(b.tail), b.radius)
                            for b in REFERENCE.bones]).capture(nodes)
    np.testing.assert_array_equal(armature.rig(context.scene).owner, expected)


def test_ik_limits_export_as_the_bones_angular_limits_in_their_rest_axes(addon):
    """A pose bone's IK limits become its angular limits (docs/skeleton.md Section 5): a limited
    axis its [ik_min, ik_max], a locked one [0, 0], the others free (null); its rest axes are
    the bone's rest matrix through the turned armature's (mathutils, apart from the export's
    numpy); the root's IK limits stay out; the engine builds the exported rig."""
    context = addon
    hand, arm = rigged(context)
    for obj in (hand, arm):  # turned together, 0.4 rad about z
        obj.rotation_mode = "QUATERNION"
        obj.rotation_quaternion = (math.cos(0.2), 0.0, 0.0, math.sin(0.2))
    pose = arm.pose.bones
    pose["index_2"].use_ik_limit_x = True
    pose["index_2"].ik_min_x, pose["index_2"].ik_max_x = -1.5, 0.1
    pose["index_2"].lock_ik_z = True
    pose["palm"].use_ik_limit_y = True  # the root
    context.view_layer.update()
    export = scene_export.export(context)
    try:
        bones = {b["name"]: b for b in export.scene.data["hand"]["skeleton"]}
        model = scenes.build_model(export.scene)
    finally:
        export.cleanup()
    got = bones["index_2"]["limits"]
    assert got["min"] == [pytest.approx(-1.5), None, 0.0] and got["max"] == [pytest.approx(0.1), None, 0.0]
    expected = arm.matrix_world.to_3x3().normalized() @ arm.data.bones["index_2"].matrix_local.to_3x3()
    np.testing.assert_allclose(bones["index_2"]["axes"], np.array(expected), atol=1e-6)
    assert "limits" not in bones["palm"] and "limits" not in bones["index_1"]
    assert model.n_bones == 16
    listed = [t for t in labels(draw_panels(context)) if t.startswith("index_2:")]
    assert listed and listed[0].endswith(", limits x -86°..6°, z locked"), listed  # (-1.5 rad, 0.1 rad)
    for obj in (hand, arm):  # mirrored: the limits' axes would be left-handed
        obj.scale = (-1.0, 1.0, 1.0)
    context.view_layer.update()
    problems = armature.rig(context.scene).problems
    assert any("'index_2' has IK limits, but the armature" in p and "Apply > Scale" in p for p in problems), problems


def test_the_automatic_radius_is_the_limbs_own_with_a_margin(addon):
    """Without a radius of its own, a finger's middle and last bones get LIMB_MARGIN times the
    finger's capsule radius, the one the procedural mesh was made from (within 3%: the median
    distance of a contoured, rounded surface)."""
    context = addon
    _, arm = rigged(context)
    for bone in arm.data.bones:
        bone.haptic_hand.use_bone_radius = False
    rig = armature.rig(context.scene)
    limb = dict(zip(("little", "ring", "middle", "index", "thumb"), (r for _, _, r, _ in meshing._finger_segments())))
    checked = 0
    for b in rig.bones:
        digit, _, k = b.name.partition("_")
        if k in ("2", "3"):
            assert b.auto_radius and b.radius == pytest.approx(armature.LIMB_MARGIN * limb[digit], rel=0.03), b.name
            checked += 1
    assert checked == 10 and not rig.problems


def test_a_bone_holds_the_flesh_of_its_vertex_group(addon):
    """Capture: Vertex group. From the hand's skinning group: the nodes whose nearest render
    vertex is weighted above Group weight (brute-force nearest vertices here); a group of the
    bone's name on the tet mesh gives its nodes exactly."""
    context = addon
    hand, arm = rigged(context)
    group = hand.vertex_groups["index_2"]
    members = [v.index for v in hand.data.vertices if any(g.group == group.index for g in v.groups)]
    group.add(members[::2], 0.5, "REPLACE")  # half its vertices blended: not above 0.5
    arm.data.bones["index_2"].haptic_hand.capture = "GROUP"
    rig = armature.rig(context.scene)
    nodes, _ = scene_export.hand_tets_world(context.scene)
    surface = meshing_world(hand, context)
    nearest = np.array([np.argmin(np.linalg.norm(surface - x, axis=1)) for x in nodes])
    rigid = np.zeros(len(surface), dtype=bool)
    rigid[members[1::2]] = True
    expected = np.flatnonzero(rigid[nearest])
    bone = rig.bones[REFERENCE.index("index_2")]
    np.testing.assert_array_equal(bone.nodes, expected)
    assert bone.count == len(expected) >= 4 and bone.radius is None and "'Hand'" in bone.source
    assert not rig.problems
    exact = hand.haptic_hand.tet_object.vertex_groups.new(name="index_2")
    exact.add([3, 5, 8, 13, 21], 1.0, "REPLACE")
    bone = armature.rig(context.scene).bones[REFERENCE.index("index_2")]
    np.testing.assert_array_equal(bone.nodes, [3, 5, 8, 13, 21])
    assert "Hand.tets" in bone.source


def meshing_world(obj, context):
    from haptic_hand.blender import meshdata

    return meshdata.world_vertices(obj, context.scene)


def test_every_problem_is_named_with_its_fix(addon):
    """A capsule too thin to hold 4 nodes, two groups sharing flesh, a group that does not
    exist: the rig lists each, Check Rig reports them all and refuses, the export names the
    first; each message names the bone and the fix."""
    context = addon
    hand, arm = rigged(context)
    bones = arm.data.bones
    bones["index_3"].haptic_hand.use_bone_radius = True
    bones["index_3"].haptic_hand.bone_radius_si = 1e-4
    s = context.scene.haptic_hand
    s.group_weight = 0.3
    for name in ("middle_1", "middle_2"):
        bones[name].haptic_hand.capture = "GROUP"
    shared = [v.index for v in hand.data.vertices
              if any(g.group == hand.vertex_groups["middle_2"].index for g in v.groups)][:40]
    for name in ("middle_1", "middle_2"):
        hand.vertex_groups[name].add(shared, 0.4, "REPLACE")
    bones["little_3"].haptic_hand.capture = "GROUP"
    hand.vertex_groups.remove(hand.vertex_groups["little_3"])
    problems = armature.rig(context.scene).problems
    assert any(p.startswith("bone 'little_3' captures by vertex group, but neither 'Hand'") and "Capsule" in p
               for p in problems)
    assert any("in the vertex groups of both 'middle_1' and 'middle_2'" in p and "Normalize All" in p for p in problems)
    assert any(p.startswith("bone 'index_3' captures 0 node(s); a rigid bone needs at least 4: set a larger Radius")
               for p in problems)
    with pytest.raises(RuntimeError, match=rf"The skeleton has {len(problems)} problem\(s\): .*index_3"):
        bpy.ops.haptic_hand.check_rig()
    with pytest.raises(scene_export.ExportError, match=r"The skeleton: .*Check Rig lists them"):
        scene_export.export(context)
    assert "bone 'little_3'" in " ".join(labels(draw_panels(context)))  # the panel shows them too


def test_the_panel_lists_each_bone_with_what_it_captures(addon, monkeypatch):
    """Each bone's count is the engine's capture of the procedural skeleton on the same nodes,
    and its radius in mm; the active bone's settings are drawn; Check Rig passes the bones on
    to the engine's checks (its report lists each bone)."""
    context = addon
    _, arm = rigged(context)
    arm.data.bones.active = arm.data.bones["middle_2"]
    log = draw_panels(context)
    nodes, _ = scene_export.hand_tets_world(context.scene)
    owner = REFERENCE.capture(nodes)
    counts = np.bincount(owner[owner >= 0], minlength=16)
    listed = {m[1]: (int(m[2]), float(m[3])) for m in
              (re.fullmatch(r"(\w+): (\d+) nodes, radius ([\d.]+) mm", text) for text in labels(log)) if m}
    assert list(listed) == list(REFERENCE.names)
    for bone, count in zip(REFERENCE.bones, counts):
        assert listed[bone.name][0] == count and listed[bone.name][1] == pytest.approx(bone.radius * 1000, abs=0.051)
    assert {"armature", "group_weight", "capture", "use_bone_radius", "bone_radius", "bone_drive_scale"} <= \
        set(props(log))
    assert "handle_radius" not in props(log), "the bones hold the hand, not the palm handle"
    seen = []
    real = rig_check.format_report
    monkeypatch.setattr(rig_check, "format_report", lambda report: seen.append(report) or real(report))
    assert bpy.ops.haptic_hand.check_rig() == {"FINISHED"}
    bones = next(c for c in seen[-1]["checks"] if c["name"] == "bones")
    assert [b["n_nodes"] for b in bones["bones"]] == counts.tolist()  # the engine's model holds the same


def test_capsules_are_drawn_around_each_bone_as_the_pose_carries_it(addon):
    """Every point the viewport draws of a capsule lies at its radius from its segment; a bone
    turned in pose mode takes its capsule, and its children's, along."""
    h, t, r = np.array([0.0, 0.01, 0.02]), np.array([0.03, -0.01, 0.05]), 0.007
    lines = draw.capsule_lines(h, t, r)
    np.testing.assert_allclose(sk.segment_distance(lines, h, t), r, atol=1e-12)
    assert np.ptp(lines @ (t - h)) > (t - h) @ (t - h), "the caps reach past the segment's ends"
    context = addon
    _, arm = rigged(context)
    pose = arm.pose.bones["index_1"]
    pose.rotation_mode = "QUATERNION"
    pose.rotation_quaternion = (math.cos(0.3), math.sin(0.3), 0.0, 0.0)  # 0.6 rad about its local x
    context.view_layer.update()
    lines = draw.rig_lines(context.scene)
    bone = REFERENCE.bones[REFERENCE.index("index_1")]
    rest = arm.data.bones["index_1"].matrix_local
    axis = np.array(rest.to_3x3().col[0])
    turn = Rotation.from_rotvec(0.6 * axis)

    def posed(b):  # the index finger turns about index_1's head
        if not b.name.startswith("index"):
            return b.head, b.tail
        return tuple(bone.head + turn.apply(x - bone.head) for x in (b.head, b.tail))

    head, tail = posed(bone)
    on_it = np.abs(sk.segment_distance(lines, head, tail) - bone.radius) < 1e-6
    assert on_it.sum() >= 2 * 24 + 8 + 4 * 12 * 2, "index_1's whole capsule, turned"
    gap = np.min([np.abs(sk.segment_distance(lines, *posed(b)) - b.radius) for b in REFERENCE.bones], axis=0)
    assert gap.max() < 1e-6


def test_a_skeleton_scene_imports_as_an_armature_keyed_with_its_targets(addon):
    """procedural_hand_close.json: an armature of the 16 bones at their rest segments, chosen in
    Rig > Skeleton; at 1 s each bone's world turn from rest is the file's target there."""
    context = addon
    scene_import.build(context, SAMPLES / "procedural_hand_close.json")
    s = context.scene.haptic_hand
    arm = s.armature
    assert arm is not None and [b.name for b in arm.data.bones] == list(REFERENCE.names)
    for bone in REFERENCE.bones:
        np.testing.assert_allclose(arm.data.bones[bone.name].head_local, bone.head, atol=1e-7)
    closed = json.loads((SAMPLES / "procedural_hand_close.json").read_text())["skeleton"]["targets"][-1]
    assert closed["t"] == 1.0
    context.scene.frame_set(context.scene.frame_start + 30)
    for name, target in closed["bones"].items():
        rest = np.array(arm.data.bones[name].matrix_local)[:3, :3]
        posed = np.array(arm.pose.bones[name].matrix)[:3, :3]
        turn = Rotation.from_matrix(posed @ rest.T)
        assert (turn.inv() * Rotation.from_quat(target["quaternion"])).magnitude() < 1e-6, name
