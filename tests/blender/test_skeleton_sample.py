"""The rigged hand sample (blender_scenes/hand_close.blend and its export hand_close/scene.json,
written by blender_scenes/build_scenes.py): an armature of the procedural hand's 16 bones whose
action closes the fingers, exporting to the engine's sample procedural_hand_close.json where
that makes sense: the same bones (as a list instead of "procedural"), the same motion of every
bone at every frame, the same drive, frames, step and block. The two-finger samples import and
export to their own motion too."""

import json
import shutil
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")
import numpy as np

from haptic_hand.blender import scene_export
from haptic_hand.engine import scene as scenes
from haptic_hand.engine import skeleton as sk

from blender_helpers import SAMPLES, bone_motion, open_copy

SAMPLE_BLENDS = Path(__file__).resolve().parents[2] / "blender_scenes"
F32 = 2e-7  # metres: float32 rounding of coordinates below 1 m, as Blender stores them


def test_the_rigged_hand_sample_exports_to_the_engines_sample(addon, tmp_path):
    context = open_copy(SAMPLE_BLENDS / "hand_close.blend", tmp_path)
    s = context.scene.haptic_hand
    arm = s.armature
    assert arm is not None and len(arm.data.bones) == 16
    assert arm.animation_data.action is not None, "an action closes the fingers"
    sample = scenes.load(SAMPLES / "procedural_hand_close.json")
    export = scene_export.export(context)
    try:
        got = export.scene
        shutil.copytree(export.folder, tmp_path / "fresh")
    finally:
        export.cleanup()
    reference = sk.procedural_hand_skeleton()
    bones = got.data["hand"]["skeleton"]
    assert [b["name"] for b in bones] == list(reference.names)
    for spec, bone in zip(bones, reference.bones):
        np.testing.assert_allclose(spec["head"] + spec["tail"], np.concatenate([bone.head, bone.tail]), atol=F32)
        assert spec["parent"] == bone.parent and spec["radius"] == pytest.approx(bone.radius, rel=1e-7)
    assert (got.frames, got.dt) == (sample.frames, pytest.approx(sample.dt))
    assert got.data["skeleton"]["drive"] == pytest.approx(sample.data["skeleton"]["drive"])
    motion, expected = bone_motion(got), bone_motion(sample)
    assert np.abs(expected[-1] - expected[0]).max() > 0.01, "the fingers close: the comparison can fail"
    np.testing.assert_allclose(motion, expected, atol=1e-6)
    block = next(b for b in got.bodies if b["name"] == "block")
    want = next(b for b in sample.bodies if b["name"] == "block")
    assert block["type"] == "soft" and block["fixed"] == want["fixed"] == "bottom"
    assert block["material"] == pytest.approx(want["material"])
    # the committed export is this .blend's: the same scene, field for field but its file names
    committed = json.loads((SAMPLE_BLENDS / "hand_close" / "scene.json").read_text())
    fresh = json.loads((tmp_path / "fresh" / "scene.json").read_text())
    stale = "blender_scenes/hand_close/ is stale: run blender_scenes/build_scenes.py hand_close"
    keys = [committed["skeleton"].pop("targets"), fresh["skeleton"].pop("targets")]  # sampled: round-off apart
    assert committed == fresh, stale
    poses = [[[k["t"], *p["quaternion"]] for k in ks for p in k["bones"].values()] for ks in keys]
    np.testing.assert_allclose(poses[0], poses[1], atol=1e-9, err_msg=stale)
    np.testing.assert_allclose(bone_motion(scenes.load(SAMPLE_BLENDS / "hand_close" / "scene.json")), expected,
                               atol=1e-6)


@pytest.mark.parametrize("name", ["grasp_ball", "pinch_letter"])
def test_the_two_finger_samples_import_and_export_to_their_motion(addon, name):
    """The soft two-finger hand's samples (bones given as a list, their heads keyed to move:
    the keys give positions): imported, the armature's action exports to the same motion of
    every bone at every frame, and the bones as the file gives them."""
    from haptic_hand.blender import scene_import

    scene_import.build(addon, SAMPLES / f"{name}.json")
    sample = scenes.load(SAMPLES / f"{name}.json")
    export = scene_export.export(addon)
    try:
        got = export.scene
    finally:
        export.cleanup()
    given = json.loads((SAMPLES / f"{name}.json").read_text())["hand"]["skeleton"]
    for spec, bone in zip(got.data["hand"]["skeleton"], given, strict=True):
        assert (spec["name"], spec["parent"]) == (bone["name"], bone.get("parent"))
        np.testing.assert_allclose(spec["head"] + spec["tail"], bone["head"] + bone["tail"], atol=F32)
        assert spec["radius"] == pytest.approx(bone["radius"], rel=1e-7)
    assert got.data["skeleton"]["drive"]["prescribed"] is True
    motion, expected = bone_motion(got), bone_motion(sample)
    assert np.abs(expected[-1] - expected[0]).max() > 1e-3, "the fingers move: the comparison can fail"
    np.testing.assert_allclose(motion, expected, atol=1e-6)
