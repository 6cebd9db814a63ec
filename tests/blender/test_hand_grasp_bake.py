"""The grasping hand's ball grasp baked in Blender (blender_scenes/hand_grasp.blend, built by
blender_scenes/build_scenes.py from the engine's grasp_ball_hand.json): the armature's action
closes the index finger and the thumb on a soft ball, lifts it 3 cm with the palm, holds it 2 s
and opens. What Blender plays back after the bake (the hand through its Armature modifier and
Mesh Cache, the ball through its cache) is the engine's result for the exported scene, and it
shows the physics: the ball rises with the palm by friction alone, stays where the palm carries
it, and falls back to the ground once the fingers open."""

import json

import pytest

bpy = pytest.importorskip("bpy")
import numpy as np

import haptic_hand

from blender_helpers import SAMPLES, open_copy
from test_bake import engine_surfaces, evaluated_world, reference_run
from test_skeleton_sample import SAMPLE_BLENDS


@pytest.fixture(scope="module")
def grasp_bake(tmp_path_factory):
    """(scene, reference result, shown hand and ball per frame, the hand's modifiers) of one
    PC2 bake of every frame of hand_grasp.blend."""
    folder = tmp_path_factory.mktemp("hand_grasp_bake")
    registered = hasattr(bpy.types.Scene, "haptic_hand")
    if not registered:
        haptic_hand.register()
    try:
        context = open_copy(SAMPLE_BLENDS / "hand_grasp.blend", folder)
        s = context.scene.haptic_hand
        s.bake_format = "PC2"
        scene = json.loads((SAMPLES / "grasp_ball_hand.json").read_text())  # what the .blend is built from
        assert (s.bake_frame_start, s.bake_frame_end) == (1, 1 + scene["frames"]), "the whole action is baked"
        reference = reference_run(context)
        assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
        frames = range(s.bake_frame_start, s.bake_frame_end + 1)
        hand, ball = s.hand, bpy.data.objects["ball"]
        shown = {name: np.array([evaluated_world(context, obj, f) for f in frames])
                 for name, obj in (("hand", hand), ("ball", ball))}
        modifiers = [(m.type, m.show_viewport) for m in hand.modifiers]
        yield scene, reference, shown, modifiers
    finally:
        if not registered:
            haptic_hand.unregister()


def test_blender_plays_back_the_engines_grasp(grasp_bake):
    _, reference, shown, modifiers = grasp_bake
    for name in ("hand", "ball"):
        expected = engine_surfaces(reference, name)
        assert shown[name].shape == expected.shape
        assert np.abs(shown[name] - expected).max() < 1e-5, name  # float32 storage
    assert modifiers == [("ARMATURE", True), ("MESH_CACHE", True)], "the cache overwrites what the armature did"


def test_the_baked_ball_rises_with_the_palm_and_falls_when_the_fingers_open(grasp_bake):
    """Read from what Blender shows: the ball's centre rises by the palm's lift (3 cm) within
    3 mm and stays within 3 mm of where the palm carries it for the 2 s hold; once the fingers
    are open plus a free fall's time sqrt(2 h / g), its lowest point is on the ground (within the
    1 mm contact thickness + 0.5 mm). The phases' times are the engine sample's keys."""
    scene, reference, shown, _ = grasp_bake
    gravity = np.array(scene["gravity"])
    g = np.linalg.norm(gravity)
    up, dt = -gravity / g, scene["dt"]
    keys = scene["skeleton"]["targets"]
    lifted, opening, opened = (round(key["t"] / dt) for key in keys[3:6])  # the keys: lifted, held until, open
    lift = np.linalg.norm(keys[3]["bones"]["palm"]["position"])
    assert lift == pytest.approx(0.03, abs=1e-6)  # (the keyed position rounded to 1 um)
    ground = next(b for b in scene["bodies"] if b["type"] == "plane")
    assert np.allclose(ground["normal"], up, atol=1e-5)
    ball = shown["ball"]
    centre, height = ball.mean(axis=1), (ball - np.array(ground["point"])) @ up
    palm = reference["bone_pose"][:, 0, :3]
    assert abs((centre[opening] - centre[0]) @ up - lift) < 0.003
    assert height[lifted:opening + 1].min() > 0.9 * lift
    carried = centre[lifted:opening + 1] - palm[lifted:opening + 1]
    assert np.linalg.norm(carried - carried[0], axis=1).max() < 0.003
    landed = opened + int(np.ceil(np.sqrt(2 * height[opening].min() / g) / dt)) + 1
    assert height[landed:].min(axis=1).max() < 0.001 + 0.0005
