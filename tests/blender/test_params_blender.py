"""The parameter table in Blender: every property's default is the engine's, every property has
a tooltip, a Blender scene with default settings exports to the command line's default scene,
Blender -> JSON -> Blender -> JSON keeps every parameter (and a skeleton: its bones, their
radii and vertex groups, and the armature's motion or a tracking stream), and lengths follow
the scene's units."""

import json
import math
import shutil

import pytest

bpy = pytest.importorskip("bpy")
import numpy as np

from haptic_hand.blender import meshdata, ops_rig, param_props, properties, scene_export, scene_import
from haptic_hand.engine import mesh as meshing
from haptic_hand.engine import native, params, tracking
from haptic_hand.engine import scene as scenes
from haptic_hand.engine import skeleton as sk

from blender_helpers import bone_motion, build_hand, curling_stream, key_finger_curl, rig_procedural_armature


def rna_default(settings, name):
    prop = settings.bl_rna.properties[name]
    return prop.enum_items[prop.default].identifier if prop.type == "ENUM" else prop.default


def test_every_property_default_is_the_tables(addon):
    s = bpy.context.scene.haptic_hand
    bpy.ops.mesh.primitive_cube_add()
    o = bpy.context.active_object.haptic_hand
    checked = 0
    for settings, where in ((s, params.UI_SCENE), (o, params.UI_OBJECT)):
        for p in param_props.rows(where):
            name = f"{p.name}_si" if p.unit == "m" else p.name
            value = rna_default(settings, name)
            if p.kind == params.KIND_ENUM:
                assert value == p.choices[int(p.default_value[0])], p.json
            elif p.kind in params.NUMERIC_KINDS:
                assert value == pytest.approx(p.default_value[0], rel=1e-7), p.json  # single precision
                assert param_props.get_si(settings, p) == p.default or p.nullable, p.json
            checked += 1
    assert checked > 40


def test_every_property_has_a_tooltip(addon):
    bpy.ops.mesh.primitive_cube_add()
    for settings in (bpy.context.scene.haptic_hand, bpy.context.active_object.haptic_hand):
        for prop in settings.bl_rna.properties:
            if prop.identifier not in ("rna_type", "name"):
                assert prop.description.strip(), f"{settings.bl_rna.identifier}.{prop.identifier} has no tooltip"


def test_every_operator_and_its_properties_have_a_tooltip(addon):
    names = dir(bpy.ops.haptic_hand)
    assert {"mark_body", "import_scene", "tetrahedralize", "bake"} <= set(names), "the check reads the add-on's"
    for name in names:
        rna = getattr(bpy.ops.haptic_hand, name).get_rna_type()
        assert rna.description.strip(), f"haptic_hand.{name} has no tooltip"
        for prop in rna.properties:
            if prop.identifier != "rna_type":
                assert prop.description.strip(), f"haptic_hand.{name}'s '{prop.identifier}' has no tooltip"


def test_a_default_blender_scene_exports_to_the_default_scene(addon):
    build_hand(addon)
    export = scene_export.export(addon)
    try:
        got = export.scene.data
        cli = scenes.from_dict({"format": scenes.FORMAT}).data
        content = ("hand.mesh", "hand.tets", "hand.palm_seed", "device.trajectory")  # the scene's own content
        compared = 0
        for p in params.table():
            if p.element or p.flags & params.INTERNAL or p.json in content:
                continue
            assert params.get(got, p) == params.get(cli, p), p.json
            compared += 1
        assert compared > 40
    finally:
        export.cleanup()


def non_default(p: params.Param):
    """A valid value of the row other than its default (within the slider's range)."""
    if p.kind == params.KIND_BOOL:
        return not bool(p.default_value[0])
    if p.kind == params.KIND_ENUM:
        return next(c for c in reversed(p.choices) if c != p.choices[int(p.default_value[0])] and c != "cg")
    if p.kind == params.KIND_INT:
        return int(p.soft_min) if int(p.soft_min) != p.default_value[0] else int(p.soft_max)
    if p.kind == params.KIND_PATH:
        return "/opt/openhaptics/libHD.so"
    lo, hi = p.soft_min, p.soft_max
    if p.flags & params.ZERO_OR_RANGE:
        lo = max(lo, p.min)
    return param_props.decimal(lo + 0.37 * (hi - lo) if math.isfinite(hi) else 2 * p.default_value[0] + 1)


def set_all(settings, rows):
    for p in rows:
        value = non_default(p)
        if p.kind == params.KIND_JSON:
            value = param_props.json_switch_value(p) if p.json in param_props.JSON_SWITCHES else None
        param_props.set_si(settings, p, value)


def add_body(context, name, role, vertices, faces, location):
    obj = bpy.data.objects.new(name, meshdata.new_mesh(name, vertices, faces))
    context.scene.collection.objects.link(obj)
    obj.location = location
    obj.haptic_hand.role = role
    return obj


def table_values(path) -> dict:
    """Every table field of the scene file at path, default-filled as the engine reads it."""
    scene = scenes.load(path)
    out = {p.json: params.get(scene.data, p) for p in params.table() if not p.element and not p.flags & params.INTERNAL}
    for b in scene.bodies:
        for p in params.table():
            if p.body and p.applies_to(b["type"]):
                out[f"{b['name']}:{p.json}"] = params.get(b, p)
    return out


def key_motion(obj, frames, locations, angles):
    """Keys obj's location and Z rotation at these frames."""
    for f, at, angle in zip(frames, locations, angles):
        obj.location, obj.rotation_euler = at, (0.0, 0.0, angle)
        obj.keyframe_insert("location", frame=f)
        obj.keyframe_insert("rotation_euler", frame=f)


HID_PATH = "/dev/hidraw7"
F32 = 2e-7  # metres: float32 rounding of coordinates below 1 m, as Blender stores them
# what the scene refuses without a skeleton (it drives a skeleton's bones, feeds back per bone, or
# ties bones to their parents)
NEEDS_SKELETON = {"skeleton.tracking", "skeleton.tracking_map", "skeleton.root_device", "skeleton.drive.prescribed",
                  "haptics.feedback", "skeleton.joints.stiffness", "skeleton.joints.damping",
                  "skeleton.joints.limit_stiffness", "skeleton.joints.limit_damping"}


def rig_skeleton(context, hand, drive: str, folder) -> None:
    """The procedural armature on the hand, one bone holding a vertex group of the tets (the
    nodes its capsule held), driven by keyed pose bones or by a tracking stream."""
    from haptic_hand.blender import armature

    arm_obj = rig_procedural_armature(context, hand)
    held = armature.rig(context.scene).owner == 6  # index_3's nodes
    group = hand.haptic_hand.tet_object.vertex_groups.new(name="index_3")
    group.add(np.flatnonzero(held).tolist(), 1.0, "REPLACE")
    arm_obj.data.bones["index_3"].haptic_hand.capture = "GROUP"
    arm_obj.data.bones["ring_2"].haptic_hand.bone_drive_scale = 0.5
    s = context.scene.haptic_hand
    s.skeleton_tracking, s.tracking_map = "", ""
    if drive == "action":
        key_finger_curl(arm_obj, (1, 31), 0.4)
    else:  # MANO joints onto the procedural bones, the layout's own map given
        curling_stream(folder / "curl.csv")
        s.skeleton_tracking = str(folder / "curl.csv")
        s.tracking_map = json.dumps(tracking.PROCEDURAL_MAPS["mano"])


@pytest.mark.parametrize("device, skeleton", [("PLAYBACK", None), ("HID", "action"), ("PLAYBACK", "tracking")])
def test_blender_json_blender_json_keeps_every_parameter(addon, tmp_path, monkeypatch, device, skeleton):
    """Every row set to a value other than its default. A skeleton hand runs without the haptic
    loop (the scene refuses both), and what drives bones needs a skeleton: each variant sets
    those it can."""
    from haptic_hand.engine import devices

    monkeypatch.setattr(devices, "hid_devices", lambda: [{"path": HID_PATH.encode(), "product": "SpaceMouse"}])
    context = addon
    hand = build_hand(context)
    s = context.scene.haptic_hand
    refused = {"haptics.enabled"} if skeleton else NEEDS_SKELETON
    set_all(s, [p for p in param_props.rows(params.UI_SCENE) if p.json not in refused])
    s.use_kinetic_friction, s.kinetic_friction = True, 0.1  # at most the static friction
    s.coupling_stiffness = 2500.0  # the haptic loop is on: within its tested range
    if skeleton:
        rig_skeleton(context, hand, skeleton, tmp_path)
    set_all(hand.haptic_hand, [p for p in param_props.selected(params.UI_OBJECT, prefix="hand.")])
    nodes, tets = meshing.structured_box([0.04, 0.04, 0.04], [2, 2, 2])
    faces = meshing.tet_boundary_faces(tets)
    for name, role, at in (("soft", "SOFT", (0, 0.2, -0.2)), ("rigid", "RIGID", (0.2, 0, -0.2)),
                           ("wall", "STATIC", (-0.2, 0, -0.2)), ("ground", "PLANE", (0, 0, -0.3)),
                           ("slider", "MOVING", (0.2, 0.2, -0.2))):
        obj = add_body(context, name, role, nodes, faces, at)
        body_type = scene_export.BODY_TYPES[role]
        set_all(obj.haptic_hand, [p for p in param_props.selected(params.UI_OBJECT, body_type)])
        obj.haptic_hand.use_kinetic_friction, obj.haptic_hand.kinetic_friction = True, 0.05
        if role == "SOFT":
            ops_rig.make_tet_object(context, obj, nodes, tets)
        if role == "MOVING":  # slides 5 cm and turns a quarter turn over the first second
            key_motion(obj, (1, 31, 61), [at, (0.25, 0.2, -0.2), (0.25, 0.2, -0.2)], (0.0, math.pi / 2, math.pi / 2))
    if device == "PLAYBACK":
        s.device, s.device_file = "PLAYBACK", str(tmp_path / "recording.npz")
        device_json = f"playback:{tmp_path / 'recording.npz'}"
    else:  # the SpaceMouse picked from the menu
        s.device, s.hid_device = "HID", HID_PATH
        device_json = f"hid:{HID_PATH}"
    first = scene_export.export(context)
    folder = tmp_path / "first"
    shutil.copytree(first.folder, folder)
    first.cleanup()
    json1 = json.loads((folder / "scene.json").read_text())
    # what was set in Blender reached the file
    assert json1["coupling"]["damping"] == non_default(params.by_json("coupling.damping"))
    assert json1["haptics"]["device"] == device_json
    assert next(b for b in json1["bodies"] if b["name"] == "soft")["solver"]["name"] == \
        non_default(params.by_json("bodies[].solver.name"))
    slider = next(b for b in json1["bodies"] if b["name"] == "slider")
    assert slider["type"] == "kinematic"
    # at frame 31 its centre (the box's middle, off its origin) has slid 5 cm and swung about the origin
    offset = (nodes.min(axis=0) + nodes.max(axis=0)) / 2
    quarter_turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(slider["trajectory"][30]["position"],
                               np.array([0.05, 0.0, 0.0]) + quarter_turn @ offset - offset, atol=1e-6)

    monkeypatch.setattr(devices, "hid_devices", lambda: [])  # imported where the device is unplugged
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene_import.build(bpy.context, folder / "scene.json")
    second = scene_export.export(bpy.context)
    folder2 = tmp_path / "second"
    shutil.copytree(second.folder, folder2)
    second.cleanup()
    v1, v2 = table_values(folder / "scene.json"), table_values(folder2 / "scene.json")
    # file names in each export's own folder; trajectories are compared as the motion they give
    skip = {"hand.mesh", "hand.tets", "device.trajectory", "bodies"}  # bodies: field by field below
    skip |= {k for k in v1 if k.endswith((":bodies[].mesh", ":bodies[].tets", ":bodies[].trajectory"))}
    scene1, scene2 = scenes.load(folder / "scene.json"), scenes.load(folder2 / "scene.json")
    for t in np.linspace(0, 2.0, 61):
        np.testing.assert_allclose(np.concatenate(scene1.trajectory(np.zeros(3)).pose(t)),
                                   np.concatenate(scene2.trajectory(np.zeros(3)).pose(t)), atol=1e-6)
    slider1, slider2 = (next(b for b in sc.bodies if b["name"] == "slider") for sc in (scene1, scene2))
    for p1, p2 in zip(slider1["trajectory"], slider2["trajectory"], strict=True):
        np.testing.assert_allclose([p1["t"], *p1["position"], *p1["quaternion"]],
                                   [p2["t"], *p2["position"], *p2["quaternion"]], atol=1e-6)
    skip.add("skeleton.targets")  # sampled from Blender's pose each time: compared as the motion below
    changed = {k: (v1[k], v2.get(k)) for k in v1 if k not in skip and v1[k] != v2.get(k)}
    assert not changed
    assert v1["haptics.device"] == device_json
    assert len(v1) > 80 and set(v1) == set(v2)
    if skeleton:
        check_skeleton_round_trip(json1, scene1, scene2, skeleton)
    else:
        assert v1["hand.skeleton"] is None and v1["skeleton.targets"] == []


def check_skeleton_round_trip(json1: dict, scene1, scene2, drive: str) -> None:
    """The armature's bones reached the file as the procedural hand's (world metres, single
    precision), the group bone as its tet nodes, and both exports drive the bones alike."""
    bones = {b["name"]: b for b in json1["hand"]["skeleton"]}
    reference = sk.procedural_hand_skeleton()
    assert list(bones) == list(reference.names)
    for bone in reference.bones:
        got = bones[bone.name]
        np.testing.assert_allclose(got["head"] + got["tail"], np.concatenate([bone.head, bone.tail]), atol=F32)
        assert got["parent"] == bone.parent
        if bone.name == "index_3":
            assert got["radius"] is None and len(got["nodes"]) >= 4
        else:
            assert got["radius"] == pytest.approx(bone.radius, rel=1e-7) and got["nodes"] is None
    assert bones["ring_2"]["drive_scale"] == 0.5
    assert (json1["skeleton"]["tracking"] is not None) == (drive == "tracking")
    assert (json1["skeleton"].get("targets", []) != []) == (drive == "action")
    motion1, motion2 = bone_motion(scene1), bone_motion(scene2)
    assert np.abs(motion1[-1] - motion1[0]).max() > 0.01, "the fingers curl: the comparison can fail"
    np.testing.assert_allclose(motion2, motion1, atol=1e-6)


def test_lengths_follow_a_centimetre_scene(addon):
    context = addon
    bscene = context.scene
    bscene.unit_settings.length_unit = "CENTIMETERS"
    build_hand(context, scale=0.01)  # the hand modelled in centimetres: 1 Blender unit = 1 cm
    s = bscene.haptic_hand
    prop = s.bl_rna.properties["handle_radius"]
    assert prop.unit == "LENGTH"
    assert s.handle_radius == pytest.approx(3.0)  # the default 0.03 m, shown as 3 cm
    s.handle_radius = 3.5  # the user types 3.5, meaning 3.5 cm
    assert s.handle_radius_si == pytest.approx(0.035)
    assert bpy.utils.units.to_string("METRIC", "LENGTH", s.handle_radius * bscene.unit_settings.scale_length) \
        .replace(" ", "") == "3.5cm"
    nodes, _ = scene_export.hand_tets_world(bscene)
    expected = native.count_captured(nodes, meshing.procedural_hand_palm_seed(), 0.035)
    assert s.captured_nodes == expected and 4 <= expected < len(nodes)
    export = scene_export.export(context)
    try:
        assert export.scene.data["hand"]["handle_radius"] == pytest.approx(0.035)
        assert export.scene.data["contact"]["thickness"] == pytest.approx(1e-3)  # the default, in metres
        np.testing.assert_allclose(export.scene.nodes, nodes, atol=1e-6)
    finally:
        export.cleanup()
