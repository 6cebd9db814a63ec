"""A bake's files on disk: each scene of a .blend bakes into its own folder, and the next bake
or Free Bake removes every file the previous bake wrote, those of objects deleted or unmarked
since included (no orphan .pc2)."""

import pytest

bpy = pytest.importorskip("bpy")

from haptic_hand.blender import bake_store

from blender_helpers import open_copy


def files(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir()) if folder.exists() else []


def bake(context, frames=3) -> None:
    s = context.scene.haptic_hand
    s.bake_frame_start, s.bake_frame_end, s.bake_format = 1, 1 + frames, "PC2"
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}


def test_no_orphan_cache_after_an_object_is_unmarked_or_deleted(addon, built_scenes, tmp_path):
    context = open_copy(built_scenes("bunny_press"), tmp_path)
    folder = tmp_path / "bunny_press_haptic" / context.scene.name
    bake(context)
    assert files(folder) == ["Hand.pc2", "bunny.pc2", "haptic_log.npz"]

    bunny = bpy.data.objects["bunny"]
    bunny.haptic_hand.role = "NONE"  # unmarked: the next bake drops its cache and its modifier
    bake(context)
    assert files(folder) == ["Hand.pc2", "haptic_log.npz"]
    assert not bunny.modifiers and not bunny.haptic_hand.baked

    bunny.haptic_hand.role = "SOFT"
    bake(context)
    assert files(folder) == ["Hand.pc2", "bunny.pc2", "haptic_log.npz"]
    bpy.data.objects.remove(bunny)  # deleted: the next bake still removes its cache
    bake(context)
    assert files(folder) == ["Hand.pc2", "haptic_log.npz"]


def test_free_bake_removes_the_cache_of_a_deleted_object(addon, built_scenes, tmp_path):
    context = open_copy(built_scenes("bunny_press"), tmp_path)
    bake(context)
    bpy.data.objects.remove(bpy.data.objects["bunny"])
    assert bpy.ops.haptic_hand.free_bake() == {"FINISHED"}
    assert not (tmp_path / "bunny_press_haptic").exists(), files(tmp_path / "bunny_press_haptic" / "Scene")


def test_two_scenes_of_one_blend_keep_their_own_files(addon, built_scenes, tmp_path):
    context = open_copy(built_scenes("bunny_press"), tmp_path)
    first = context.scene
    bake(context)
    first_files = {p: p.read_bytes() for p in bake_store.bake_files(first)}
    assert len(first_files) == 3

    bpy.ops.scene.new(type="FULL_COPY")  # a second scene with copies of every object
    second = bpy.context.scene
    assert second != first and second.haptic_hand.hand.name in second.objects
    bake(bpy.context, frames=4)  # its objects' caches are named apart, its log is named alike
    second_files = bake_store.bake_files(second)
    assert len(second_files) == 3 and not second_files & set(first_files)
    assert {p.parent for p in second_files} == {bake_store.cache_dir(second)} != bake_store.cache_dir(first)
    assert {p: p.read_bytes() for p in first_files} == first_files, "the first scene's bake is untouched"

    assert bpy.ops.haptic_hand.free_bake() == {"FINISHED"}  # the second scene's
    assert not any(p.exists() for p in second_files)
    assert {p: p.read_bytes() for p in first_files} == first_files
    assert first.haptic_hand.baked and not bake_store.missing_caches(first)
    with bpy.context.temp_override(scene=first):
        assert bpy.ops.haptic_hand.free_bake() == {"FINISHED"}
    assert not (tmp_path / "bunny_press_haptic").exists()
