"""The rigged hand samples (blender_scenes/hand_close.blend, hand_grasp.blend and hand_pinch.blend,
and hand_close's export hand_close/scene.json, written by blender_scenes/build_scenes.py): armatures of
16 bones whose actions close the procedural hand's fingers onto a block, lift a ball with the
grasping hand, or pinch a letter with it, each exporting to the engine's sample it is built from
where that makes sense: the same bones (as a list instead of "procedural"), the same motion of
every bone at every frame, the same drive, frames, step, gravity, solver and bodies. The
two-finger samples import and export to their own motion too."""

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


RIGGED = {  # the rigged hands' .blend -> the engine's sample it is built from
    "hand_close": "procedural_hand_close",
    "hand_grasp": "grasp_ball_hand",
    "hand_pinch": "pinch_letter_hand",
}
COMMITTED_EXPORTS = {"hand_close"}  # blender_scenes/common.EXPORTED: exports kept beside their .blend


def sample_bones(sample_json: dict) -> list[tuple]:
    """(name, parent, head + tail, radius) of the sample's bones: its list, or the procedural hand's."""
    given = sample_json["hand"]["skeleton"]
    if given == "procedural":
        reference = sk.procedural_hand_skeleton()
        return [(n, b.parent, np.concatenate([b.head, b.tail]), b.radius) for n, b in zip(reference.names, reference.bones)]
    return [(b["name"], b.get("parent"), np.array(b["head"] + b["tail"]), b["radius"]) for b in given]


def assert_same_bodies(got, sample):
    """The sample's bodies, by name, as the export gives them: type, material, friction, fixing,
    planes' point and normal (meshes are written as the .blend holds them)."""
    assert sorted(b["name"] for b in got.bodies) == sorted(b["name"] for b in sample.bodies)
    for want in sample.bodies:
        body = next(b for b in got.bodies if b["name"] == want["name"])
        assert body["type"] == want["type"] and body.get("fixed") == want.get("fixed"), want["name"]
        assert body.get("friction") == pytest.approx(want.get("friction")), want["name"]
        for key in ("young_modulus", "poisson_ratio", "density"):
            assert body.get("material", {}).get(key) == pytest.approx(want.get("material", {}).get(key)), key
        if want["type"] == "plane":
            np.testing.assert_allclose(body["normal"], want["normal"], atol=1e-6)
            assert np.dot(np.subtract(body["point"], want["point"]), want["normal"]) == pytest.approx(0, abs=F32)


@pytest.mark.parametrize("blend", list(RIGGED))
def test_the_rigged_hand_samples_export_to_the_engines_samples(addon, tmp_path, blend):
    """Each rigged hand's .blend (16 bones, an action) exports to its engine sample: the same
    bones, the same motion of every bone at every frame, the same drive, frames, step, gravity,
    solver, contact settings and bodies; and an export kept beside it is this .blend's."""
    name = RIGGED[blend]
    context = open_copy(SAMPLE_BLENDS / f"{blend}.blend", tmp_path)
    s = context.scene.haptic_hand
    arm = s.armature
    assert arm is not None and len(arm.data.bones) == 16
    assert arm.animation_data.action is not None, "an action moves the bones"
    sample = scenes.load(SAMPLES / f"{name}.json")
    export = scene_export.export(context)
    try:
        got = export.scene
        shutil.copytree(export.folder, tmp_path / "fresh")
    finally:
        export.cleanup()
    bones = got.data["hand"]["skeleton"]
    want = sample_bones(json.loads((SAMPLES / f"{name}.json").read_text()))
    assert [b["name"] for b in bones] == [w[0] for w in want]
    for spec, (_, parent, ends, radius) in zip(bones, want):
        np.testing.assert_allclose(spec["head"] + spec["tail"], ends, atol=F32)
        assert spec["parent"] == parent and spec["radius"] == pytest.approx(radius, rel=1e-7)
    assert (got.frames, got.dt) == (sample.frames, pytest.approx(sample.dt))
    for key in ("gravity", "solver", "contact", "material", "springs"):
        assert got.data[key] == pytest.approx(sample.data[key]), key
    assert got.data["skeleton"]["drive"] == pytest.approx(sample.data["skeleton"]["drive"])
    motion, expected = bone_motion(got), bone_motion(sample)
    assert np.abs(expected[-1] - expected[:-1]).max() > 0.01, "the bones move: the comparison can fail"
    np.testing.assert_allclose(motion, expected, atol=1e-6)
    assert_same_bodies(got, sample)
    committed = SAMPLE_BLENDS / blend / "scene.json"
    assert committed.exists() == (blend in COMMITTED_EXPORTS)
    if committed.exists():
        assert_committed_export_is_fresh(blend, tmp_path / "fresh", expected)


def assert_committed_export_is_fresh(blend, fresh_folder, expected):
    """The committed export is this .blend's: the same scene, field for field but its file names."""
    committed = json.loads((SAMPLE_BLENDS / blend / "scene.json").read_text())
    fresh = json.loads((fresh_folder / "scene.json").read_text())
    stale = f"blender_scenes/{blend}/ is stale: run blender_scenes/build_scenes.py {blend}"
    keys = [committed["skeleton"].pop("targets"), fresh["skeleton"].pop("targets")]  # sampled: round-off apart
    assert committed == fresh, stale
    poses = [[v for k in ks for p in k["bones"].values() for v in (k["t"], *p.get("quaternion", []), *p.get("position", []))]
             for ks in keys]
    np.testing.assert_allclose(poses[0], poses[1], atol=1e-9, err_msg=stale)
    np.testing.assert_allclose(bone_motion(scenes.load(SAMPLE_BLENDS / blend / "scene.json")), expected, atol=1e-6)


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
