"""Baking the bunny scene: shape keys and PC2 reproduce the engine, the hand deforms where it
touches, the log, cancel and re-bake, free bake."""

import time

import pytest

bpy = pytest.importorskip("bpy")
import numpy as np
from scipy.spatial import cKDTree

import haptic_hand
from haptic_hand.blender import meshdata, ops_bake, scene_export
from haptic_hand.engine import bake_formats, quaternion, simulate
from haptic_hand.engine import mesh as meshing
from haptic_hand.engine import scene as scenes

from blender_helpers import open_copy

FRAMES = 30  # steps of the main bake


def evaluated_world(context, obj, frame) -> np.ndarray:
    """The object's vertices as Blender shows them at frame (shape keys, modifiers), in metres."""
    context.scene.frame_set(frame)
    ev = obj.evaluated_get(context.evaluated_depsgraph_get())
    me = ev.to_mesh()
    try:
        return meshdata.transform(meshdata.matrix(obj), meshdata.local_vertices(me)) * meshdata.unit_scale(
            context.scene)
    finally:
        ev.to_mesh_clear()


def engine_surfaces(result, name):
    """Render-surface positions per frame from the engine's own result file arrays."""
    if name == "hand":
        keys = ("positions", "tets", "surface_tet_index", "surface_weights")
    else:
        keys = tuple(f"body_{name}_{k}" for k in ("positions", "tets", "surface_tet_index", "surface_weights"))
    x, tets, index, weights = (result[k] for k in keys)
    return np.array([meshing.interpolate_embedded(x[k], tets, index, weights) for k in range(len(x))])


def reference_run(context):
    """The engine's result for this Blender scene, through the scene folder the export writes
    (scene.json + .obj + .npz read back by the engine's own loaders, as the CLI would)."""
    export = scene_export.export(context)
    try:
        return simulate.run(scenes.load(export.folder / "scene.json"))
    finally:
        export.cleanup()


@pytest.fixture(scope="module")
def bunny_bake(built_scenes, tmp_path_factory):
    """One 30-frame shape-key bake of the bunny scene, read back frame by frame."""
    folder = tmp_path_factory.mktemp("bunny_bake")
    path = built_scenes("bunny_press")
    registered = hasattr(bpy.types.Scene, "haptic_hand")
    if not registered:
        haptic_hand.register()
    try:
        context = open_copy(path, folder)
        s = context.scene.haptic_hand
        s.bake_frame_start, s.bake_frame_end, s.bake_format = 1, 1 + FRAMES, "KEYS"
        reference = reference_run(context)
        assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
        hand, bunny = s.hand, bpy.data.objects["bunny"]
        frames = range(1, 2 + FRAMES)
        out = {
            "reference": reference,
            "hand": np.array([evaluated_world(context, hand, f) for f in frames]),
            "bunny": np.array([evaluated_world(context, bunny, f) for f in frames]),
            "keys": [b.name for b in hand.data.shape_keys.key_blocks],
            "log_path": bpy.path.abspath("//" + s.bake_log[2:]) if s.bake_log.startswith("//") else s.bake_log,
            "folder": folder,
        }
        with np.load(out["log_path"]) as log:
            out["log"] = dict(log)
        return out
    finally:
        if not registered:
            haptic_hand.unregister()


def test_keys_reproduce_engine_positions(bunny_bake):
    ref = bunny_bake["reference"]
    assert len(ref["time"]) == FRAMES + 1
    for name in ("hand", "bunny"):
        expected = engine_surfaces(ref, name)
        got = bunny_bake[name]
        assert got.shape == expected.shape
        assert np.abs(got - expected).max() < 1e-6, name
        # the bake is not the rest mesh held still: the comparison above has teeth
        assert np.abs(expected[-1] - expected[0]).max() > 1e-3  # a thousand times the tolerance
    # one key per frame (plus the basis)
    assert bunny_bake["keys"] == ["Basis"] + [f"hh_f{f:05d}" for f in range(1, 2 + FRAMES)]


def test_hand_deforms_where_it_touches(bunny_bake):
    """Flesh held back by the bunny moves away from the rigid motion of the handle; flesh far
    from the bunny follows the handle (it only sags and lags a little)."""
    log = bunny_bake["log"]
    hand, bunny = bunny_bake["hand"], bunny_bake["bunny"]
    c0 = log["handle_pose"][0, :3]
    k = FRAMES
    pose = log["handle_pose"][k]
    rigid = pose[:3] + (hand[0] - c0) @ quaternion.to_matrix(pose[3:]).T
    deformation = np.linalg.norm(hand[k] - rigid, axis=1)
    gap, _ = cKDTree(bunny[k]).query(hand[k])
    touching, far = gap < 3e-3, gap > 3e-2
    assert touching.sum() >= 3, "the hand reaches the bunny"
    press = np.linalg.norm(log["device_pose"][k, :3] - log["device_pose"][0, :3])
    assert press > 0.01  # the device pressed down over a centimetre
    assert deformation[touching].mean() > 1e-3, "visible (over 1 mm) where it touches"
    assert deformation[touching].mean() > 3 * deformation[far].mean()


def test_log_saved_beside_blend(bunny_bake):
    log, ref = bunny_bake["log"], bunny_bake["reference"]
    assert str(bunny_bake["log_path"]).startswith(str(bunny_bake["folder"]))
    assert log["time"].shape == (FRAMES + 1,)
    np.testing.assert_allclose(log["time"], np.arange(FRAMES + 1) / 30.0, atol=1e-12)
    assert log["coupling_wrench"].shape == (FRAMES + 1, 6)
    np.testing.assert_array_equal(log["coupling_wrench"], ref["coupling_wrench"])


def test_log_has_one_row_per_haptic_step(bunny_bake):
    """simulate.run's result['haptic'] (one row per haptic step) is saved as haptic_*: N =
    frames * round(dt / haptic_dt) rows, evenly spaced in virtual time over the bake."""
    log = bunny_bake["log"]
    assert "haptic_t" in log, "the engine's result has no 'haptic' log (simulate.run)"
    dt = 1.0 / 30.0
    t = log["haptic_t"]
    haptic_dt = float(np.median(np.diff(t)))
    assert 0.0 < haptic_dt < dt / 2, "several haptic steps per frame"
    rows = FRAMES * round(dt / haptic_dt)
    for key in ("t", "device_position", "device_quaternion", "proxy_position", "proxy_quaternion", "force",
                "torque", "period", "cost"):
        assert log[f"haptic_{key}"].shape[0] == rows, key
    assert np.all(np.diff(t) > 0)
    assert abs((t[-1] - t[0]) - (rows - 1) * haptic_dt) < 1e-6


def _bake_in_thread(context, cancel_at=None):
    """The modal bake's steps: prepare, worker thread, poll until done (cancel when progress
    reaches cancel_at). Returns the final state."""
    job = ops_bake.prepare(context)
    job.start()
    state = "RUNNING"
    deadline = time.time() + 120
    while state == "RUNNING" and time.time() < deadline:
        if cancel_at is not None and job.progress >= cancel_at:
            job.cancel = True
        time.sleep(0.005)
        state = ops_bake.poll_job(context, job)
    return state, job


def test_pc2_cancel_rebake_and_free(addon, built_scenes, tmp_path):
    context = open_copy(built_scenes("bunny_press"), tmp_path)
    s = context.scene.haptic_hand
    hand = s.hand
    rest = evaluated_world(context, hand, 1)
    # a short point-cache bake
    s.bake_frame_start, s.bake_frame_end, s.bake_format = 1, 9, "PC2"
    reference = engine_surfaces(reference_run(context), "hand")
    state, job = _bake_in_thread(context)
    assert state == "FINISHED", job.error
    pc2 = tmp_path / "bunny_press_haptic" / "Hand.pc2"
    cached, start, rate = bake_formats.read_pc2(pc2)
    assert (start, rate, cached.shape) == (1.0, 1.0, reference.shape)
    assert hand.modifiers[0].type == "MESH_CACHE"
    shown = np.array([evaluated_world(context, hand, f) for f in range(1, 10)])
    assert np.abs(shown - reference).max() < 1e-6
    np.testing.assert_allclose(meshdata.transform(meshdata.matrix(hand), cached), reference, atol=1e-6)

    # a longer bake cancelled half-way: the first bake stays, untouched and usable
    s.bake_frame_end, s.bake_format = 61, "KEYS"
    state, job = _bake_in_thread(context, cancel_at=0.5)
    assert state == "CANCELLED" and job.result is None
    assert 0.5 <= job.progress < 1.0
    assert s.baked and s.baked_range == "1-9" and s.baked_format == "PC2"
    assert hand.data.shape_keys is None and [m.type for m in hand.modifiers] == ["MESH_CACHE"]
    np.testing.assert_array_equal(bake_formats.read_pc2(pc2)[0], cached)
    assert np.abs(evaluated_world(context, hand, 9) - reference[8]).max() < 1e-6

    # a finished re-bake replaces it: keys now, the cache and its modifier gone
    s.bake_frame_end = 4
    state, job = _bake_in_thread(context)
    assert state == "FINISHED", job.error
    assert s.baked_range == "1-4" and not hand.modifiers
    assert [b.name for b in hand.data.shape_keys.key_blocks] == ["Basis"] + [f"hh_f{f:05d}" for f in range(1, 5)]
    assert len([a for a in bpy.data.actions if a.name.startswith(ops_bake.ACTION_PREFIX)]) == 2  # hand, bunny
    assert np.abs(evaluated_world(context, hand, 4) - reference[3]).max() < 1e-6

    # free bake: the meshes are as before any bake, the files gone
    assert bpy.ops.haptic_hand.free_bake() == {"FINISHED"}
    assert hand.data.shape_keys is None and bpy.data.objects["bunny"].data.shape_keys is None
    assert not [a for a in bpy.data.actions if a.name.startswith(ops_bake.ACTION_PREFIX)]
    assert not (tmp_path / "bunny_press_haptic" / ops_bake.LOG_NAME).exists()
    assert not s.baked
    np.testing.assert_array_equal(evaluated_world(context, hand, 4), rest)


def test_unsaved_blend_is_refused(addon):
    from haptic_hand.blender import scene_import

    from blender_helpers import SAMPLES

    context = addon
    scene_import.build(context, SAMPLES / "hand_wave.json")  # never saved
    context.scene.haptic_hand.bake_frame_end = 3
    objects = sorted(o.name for o in bpy.data.objects)
    with pytest.raises(RuntimeError, match="Save the .blend file first"):
        bpy.ops.haptic_hand.bake()
    assert not context.scene.haptic_hand.baked and context.scene.haptic_hand.hand.data.shape_keys is None
    assert sorted(o.name for o in bpy.data.objects) == objects
