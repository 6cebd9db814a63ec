"""The bake's Start and End: the scene's frame range until the user sets one of them; setting one
keeps the other where it was shown, and from then on the bake's range is its own (saved in the
.blend)."""

import pytest

bpy = pytest.importorskip("bpy")


def shown(settings) -> tuple[int, int]:
    return settings.bake_frame_start, settings.bake_frame_end


def test_start_and_end_follow_the_scene_until_set(addon, tmp_path):
    scene = addon.scene
    s = scene.haptic_hand
    scene.frame_start, scene.frame_end = 10, 90
    assert shown(s) == (10, 90)
    scene.frame_start, scene.frame_end = 5, 120  # still the scene's
    assert shown(s) == (5, 120)

    s.bake_frame_end = 60  # End set: Start stays where it was shown
    assert shown(s) == (5, 60)
    scene.frame_start, scene.frame_end = 1, 250  # the bake's range is its own now
    assert shown(s) == (5, 60)
    path = tmp_path / "range.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.open_mainfile(filepath=str(path))
    assert shown(bpy.context.scene.haptic_hand) == (5, 60), "kept in the file"

    # and the other way round, in a scene of its own: Start set, End kept
    other = bpy.data.scenes.new("Other")
    other.frame_start, other.frame_end = 20, 80
    t = other.haptic_hand
    assert shown(t) == (20, 80)
    t.bake_frame_start = 30
    assert shown(t) == (30, 80)
    other.frame_end = 200
    assert shown(t) == (30, 80)
    assert shown(bpy.context.scene.haptic_hand) == (5, 60), "each scene has its own range"
