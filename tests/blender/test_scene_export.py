"""Blender scene <-> engine scene: a sample scene built in Blender exports back to the same
engine scene (metres, world space, vertex order kept); moving colliders and rigid bodies; a
value the engine refuses is reported in Blender's terms."""

import json

import pytest

bpy = pytest.importorskip("bpy")
import numpy as np

from haptic_hand.blender import meshdata, ops_bake, scene_export
from haptic_hand.engine import mesh as meshing
from haptic_hand.engine import scene as scenes
from haptic_hand.engine import quaternion, simulate

from blender_helpers import SAMPLES, open_copy

F32 = 2e-7  # metres: float32 rounding of coordinates below 1 m, as Blender stores them


def test_bunny_scene_exports_to_the_sample_scene(addon, built_scenes, tmp_path):
    context = open_copy(built_scenes("bunny_press"), tmp_path)
    sample = scenes.load(SAMPLES / "bunny_press.json")
    scenes.load_hand_geometry(sample)
    export = scene_export.export(context)
    try:
        got = export.scene
        np.testing.assert_allclose(got.surface_vertices, sample.surface_vertices, atol=F32)
        np.testing.assert_array_equal(got.surface_faces, sample.surface_faces)  # order kept
        np.testing.assert_allclose(got.nodes, sample.nodes, atol=F32)
        np.testing.assert_array_equal(got.tets, sample.tets)
        np.testing.assert_allclose(got.palm_seed(), sample.palm_seed(), atol=F32)
        assert got.dt == pytest.approx(sample.dt) and got.frames == sample.frames
        for key in ("material", "springs", "coupling"):
            for k, v in sample.data[key].items():
                assert got.data[key][k] == pytest.approx(v, rel=1e-6), (key, k)
        assert got.data["contact"]["thickness"] == pytest.approx(sample.data["contact"]["thickness"])
        assert got.data["contact"]["threads"] == sample.data["contact"]["threads"] == 2
        # the device: the target empty keyed along the trajectory, sampled every frame
        com = np.array([0.01, -0.02, -0.05])
        a, b = got.trajectory(com), sample.trajectory(com)
        for t in np.arange(sample.frames + 1) * sample.dt:
            np.testing.assert_allclose(a.pose(t)[0], b.pose(t)[0], atol=1e-6)
        ground, bunny = (next(b for b in got.data["bodies"] if b["name"] == n) for n in ("ground", "bunny"))
        sg, sb = sample.data["bodies"]
        assert ground["type"] == "plane"
        np.testing.assert_allclose(ground["point"], sg["point"], atol=F32)
        np.testing.assert_allclose(ground["normal"], sg["normal"], atol=1e-7)
        assert bunny["type"] == "soft" and bunny["friction"] == pytest.approx(sb["friction"])
        assert bunny["material"]["young_modulus"] == pytest.approx(sb["material"]["young_modulus"])
        # the folder is a scene the command line can run
        assert scenes.load(export.folder / "scene.json").frames == sample.frames
    finally:
        export.cleanup()
    assert export.folder is None
    # the simulation threads the user picked reach the scene, and a soft body's solver
    assert bunny["solver"]["name"] == next(b for b in sample.bodies if b["name"] == "bunny")["solver"]["name"]
    context.scene.haptic_hand.threads = 1
    bpy.data.objects["bunny"].haptic_hand.solver = "reused_cholesky"
    export = scene_export.export(context)
    try:
        assert export.scene.data["contact"]["threads"] == 1
        bunny = next(b for b in export.scene.bodies if b["name"] == "bunny")
        assert bunny["solver"]["name"] == "reused_cholesky"
    finally:
        export.cleanup()


def test_moving_colliders_follow_their_animation(addon, built_scenes, tmp_path):
    context = open_copy(built_scenes("finger_squeeze"), tmp_path)
    sample = json.loads((SAMPLES / "finger_squeeze.json").read_text())
    export = scene_export.export(context)
    try:
        bodies = {b["name"]: b for b in export.scene.data["bodies"]}
        for spec in sample["bodies"]:
            got = scenes.body_trajectory(bodies[spec["name"]], np.zeros(3))
            want = scenes.body_trajectory(spec, np.zeros(3))
            assert bodies[spec["name"]]["type"] == "kinematic"
            for t in np.arange(0, 2.0, 1 / 30):
                np.testing.assert_allclose(got.pose(t)[0], want.pose(t)[0], atol=1e-6)
    finally:
        export.cleanup()


def test_rigid_body_bake_keys_its_transform(addon, built_scenes, tmp_path):
    """Two 2 cm cubes beside the hand: one falls freely, one rests on the ground plane. Their
    keyed transforms are the engine's poses; the falling one drops as gravity says, the
    resting one stays on the plane."""
    context = open_copy(built_scenes("hand_wave"), tmp_path)
    s = context.scene.haptic_hand
    cubes = []
    for location in ((0.0, 0.25, 1.0), (0.0, 0.35, -0.3 + 0.01 + 5e-4)):
        bpy.ops.mesh.primitive_cube_add(size=0.02, location=location)
        cubes.append(context.active_object)
        cubes[-1].haptic_hand.role = "RIGID"
    cubes[0].rotation_euler = (0.2, 0.1, 0.0)  # a turned body: the rotation is keyed too
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(0.0, 0.3, -0.3))  # below the hand (down to -0.2)
    context.active_object.haptic_hand.role = "PLANE"
    context.view_layer.update()
    s.bake_frame_start, s.bake_frame_end = 1, 16
    rest = [meshdata.world_vertices(c, context.scene) for c in cubes]
    rest_matrix = [np.array(c.matrix_world) for c in cubes]
    export = scene_export.export(context)
    try:
        reference = simulate.run(scenes.load(export.folder / "scene.json"))
    finally:
        export.cleanup()
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
    heights = {c.name: [] for c in cubes}
    for cube, rest_v in zip(cubes, rest):
        poses = reference[f"body_{cube.name}_pose"]
        for k, frame in enumerate(range(1, 17)):
            context.scene.frame_set(frame)
            shown = meshdata.world_vertices(cube, context.scene)
            pose = poses[k]
            expected = pose[:3] + (rest_v - poses[0, :3]) @ quaternion.to_matrix(pose[3:]).T
            assert np.abs(shown - expected).max() < 1e-5, (cube.name, frame)
            heights[cube.name].append(shown[:, 2].min())
    falling, resting = (np.array(heights[c.name]) for c in cubes)
    t = 15 / 30
    assert 0.5 * 9.81 * t**2 * 0.8 < falling[0] - falling[-1] < 0.5 * 9.81 * t**2 * 1.25
    assert np.all(np.abs(resting - (-0.3)) < 2e-3), "it rests on the plane"
    # free bake puts the cubes back where they were
    assert bpy.ops.haptic_hand.free_bake() == {"FINISHED"}
    assert not [a for a in bpy.data.actions if a.name.startswith(ops_bake.ACTION_PREFIX)]
    for cube, m in zip(cubes, rest_matrix):
        np.testing.assert_allclose(np.array(cube.matrix_world), m, atol=1e-6)
        assert cube.rotation_mode == "XYZ"


def test_overlay_geometry():
    from haptic_hand.blender import draw

    lines = draw.sphere_lines([1.0, 2.0, 3.0], 0.03)
    np.testing.assert_allclose(np.linalg.norm(lines - [1.0, 2.0, 3.0], axis=1), 0.03, rtol=1e-12)
    arrow = draw.arrow_lines([0.0, 0.0, 0.0], [0.0, 0.02, 0.0])
    np.testing.assert_allclose(arrow[1], [0.0, 0.02, 0.0])  # the shaft ends at origin + vector
    assert len(draw.arrow_lines([0, 0, 0], [0, 0, 0])) == 0  # no force, no arrow
    data = {"handle_position": np.zeros(3), "handle_quaternion": np.array([0, 0, 0, 1.0]), "radius": 0.03,
            "force": np.array([0.0, 0.0, 2.0]), "force_scale": 0.01, "device_position": np.ones(3),
            "proxy_position": np.ones(3)}
    drawn = draw.overlay_lines(data)
    np.testing.assert_allclose(drawn["force"][1], [0.0, 0.0, 0.02])  # 2 N at 1 cm per newton


def test_a_frame_rate_too_low_for_the_step_is_refused_in_blender_terms(addon, built_scenes, tmp_path):
    """The engine checks dt (at most 0.1 s, the table's range); Blender's report says which
    value and where it comes from in Blender, the frame rate, and nothing is baked."""
    context = open_copy(built_scenes("hand_wave"), tmp_path)
    context.scene.render.fps, context.scene.render.fps_base = 5, 1.0  # 0.2 s a frame
    s = context.scene.haptic_hand
    s.bake_frame_end = s.bake_frame_start + 2
    message = r"dt = 0\.2 is invalid.*0\.1.*in Blender, one step per frame at the scene's frame rate"
    with pytest.raises(RuntimeError, match=message):  # the Bake button's report
        bpy.ops.haptic_hand.bake()
    assert not s.baked and s.hand.data.shape_keys is None
    context.scene.render.fps_base = 0.4  # 12.5 fps: 0.08 s a frame is within the range
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}

