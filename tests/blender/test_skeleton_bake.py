"""A bake driven by the armature's action plays back on the skinned hand where the engine put
it: the procedural hand closing its fingers (procedural_hand_close.json imported: an armature
keyed with the targets, the hand skinned to it by an Armature modifier), the hand parented to
its armature and the armature object moving 1 cm, so the hand's own object moves too. Shape
keys and point caches alike, evaluated through the Armature modifier (on for the cache, which
comes after it; turned off by shape keys, which act before it), against the engine's result
for the exported scene."""

import pytest

bpy = pytest.importorskip("bpy")
import numpy as np

import haptic_hand
from haptic_hand.blender import bake_store, scene_import

from blender_helpers import SAMPLES
from test_bake import engine_surfaces, evaluated_world, reference_run

FRAMES = 12


@pytest.fixture(scope="module", params=["PC2", "KEYS"])
def rigged_bake(request, tmp_path_factory):
    """(context, hand, reference result, evaluated hand per frame, format) of one bake."""
    folder = tmp_path_factory.mktemp(f"skeleton_bake_{request.param}")
    registered = hasattr(bpy.types.Scene, "haptic_hand")
    if not registered:
        haptic_hand.register()
    try:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        objects = scene_import.build(bpy.context, SAMPLES / "procedural_hand_close.json")
        context = bpy.context
        hand, arm = objects["hand"], objects["armature"]
        hand.parent = arm  # a rigged hand: its mesh a child of its armature
        for frame, x in ((1, 0.0), (1 + FRAMES, 0.01)):
            arm.location = (x, 0.0, 0.0)
            arm.keyframe_insert("location", frame=frame)
        s = context.scene.haptic_hand
        s.bake_frame_start, s.bake_frame_end, s.bake_format = 1, 1 + FRAMES, request.param
        bpy.ops.wm.save_as_mainfile(filepath=str(folder / "hand_close.blend"))
        reference = reference_run(context)
        assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
        shown = np.array([evaluated_world(context, hand, f) for f in range(1, 2 + FRAMES)])
        yield context, hand, reference, shown, request.param
    finally:
        if not registered:
            haptic_hand.unregister()


def test_the_baked_hand_lands_where_the_engine_put_it(rigged_bake):
    context, hand, reference, shown, fmt = rigged_bake
    expected = engine_surfaces(reference, "hand")
    assert shown.shape == expected.shape
    assert np.abs(shown - expected).max() < 1e-5, fmt
    # teeth: the fingers moved centimetres, the hand object moved with its armature
    assert np.abs(expected[-1] - expected[0]).max() > 5e-3
    pose = reference["bone_pose"]
    assert np.linalg.norm(pose[-1, 0, :3] - pose[0, 0, :3]) > 5e-3, "the palm went with its armature"
    modifiers = [(m.type, m.show_viewport) for m in hand.modifiers]
    if fmt == "PC2":
        assert modifiers == [("ARMATURE", True), ("MESH_CACHE", True)], "the cache overwrites what the armature did"
    else:
        assert modifiers == [("ARMATURE", False)], "shape keys come before the modifiers: the armature is off"


def test_the_armature_would_deform_the_bake_again_in_the_other_order(rigged_bake):
    """What the placement buys: a cache before the Armature modifier, or shape keys with it on,
    turns the baked fingers a second time (millimetres off)."""
    context, hand, reference, _, fmt = rigged_bake
    expected = engine_surfaces(reference, "hand")
    if fmt == "PC2":
        hand.modifiers.move(1, 0)
    else:
        hand.modifiers[0].show_viewport = True
    try:
        wrong = evaluated_world(context, hand, 1 + FRAMES)
    finally:
        if fmt == "PC2":
            hand.modifiers.move(0, 1)
        else:
            hand.modifiers[0].show_viewport = False
    assert np.abs(wrong - expected[-1]).max() > 2e-3


def test_free_bake_gives_the_hand_back_to_its_armature(rigged_bake):
    context, hand, _, _, fmt = rigged_bake
    assert bpy.ops.haptic_hand.free_bake() == {"FINISHED"}
    assert [(m.type, m.show_viewport, m.show_render) for m in hand.modifiers] == [("ARMATURE", True, True)]
    assert hand.data.shape_keys is None and bake_store.MODIFIER_NAME not in hand.modifiers
