"""Baking the bunny scene in a child process: shape keys and PC2 reproduce the engine, the hand
deforms where it touches, keys only where a frame needs one, the last frame held, the forces as
F-curves, the log; the size shown before a bake; PC2 files beside the .blend, relative, and
said to be missing when they are; cancel, re-bake, free bake and no orphan files."""

import shutil
import time

import pytest

bpy = pytest.importorskip("bpy")
import numpy as np
from scipy.spatial import cKDTree

import haptic_hand
from haptic_hand.blender import bake_store, meshdata, ops_bake, panel, runtime, scene_export
from haptic_hand.engine import bake_formats, quaternion, simulate
from haptic_hand.engine import mesh as meshing
from haptic_hand.engine import scene as scenes

from blender_helpers import draw_panels, labels, open_copy

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
    """The engine's result for this Blender scene, in this process, through the scene folder
    the export writes (scene.json + .obj + .npz read back by the engine's own loaders)."""
    export = scene_export.export(context)
    try:
        return simulate.run(scenes.load(export.folder / "scene.json"))
    finally:
        export.cleanup()


def bake_in_background(context, cancel_at=None, recording=None):
    """The modal bake's steps: prepare, start the child, poll until done (cancel when progress
    reaches cancel_at). Returns (final state, job, [(progress, message)] seen)."""
    job = ops_bake.prepare(context, recording=recording)
    runtime.state.bake = job.start()
    seen, state = [], "RUNNING"
    deadline = time.time() + 120
    while state == "RUNNING" and time.time() < deadline:
        if not seen or seen[-1] != (job.progress, job.message):
            seen.append((job.progress, job.message))
        if cancel_at is not None and job.progress >= cancel_at:
            job.cancel()
        time.sleep(0.005)
        state = ops_bake.poll_job(context, job)
    assert runtime.state.bake is None, "a finished bake leaves nothing running"
    return state, job, seen


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
            "after": {o.name: evaluated_world(context, o, 2 + FRAMES + 10) for o in (hand, bunny)},
            "keys": {o.name: [b.name for b in o.data.shape_keys.key_blocks] for o in (hand, bunny)},
            "log_path": bpy.path.abspath(s.bake_log),
            "folder": folder,
            "forces": {},
        }
        for frame in frames:
            context.scene.frame_set(frame)
            ev = hand.evaluated_get(context.evaluated_depsgraph_get())
            for name in bake_store.FORCE_PROPERTIES:
                out["forces"].setdefault(name, []).append(list(ev[name]))
        out["forces"] = {k: np.array(v) for k, v in out["forces"].items()}
        with np.load(out["log_path"]) as log:
            out["log"] = dict(log)
        return out
    finally:
        if not registered:
            haptic_hand.unregister()


def test_keys_reproduce_engine_positions(bunny_bake):
    ref = bunny_bake["reference"]
    assert len(ref["time"]) == FRAMES + 1
    for name, obj in (("hand", "Hand"), ("bunny", "bunny")):
        expected = engine_surfaces(ref, name)
        got = bunny_bake[name]
        assert got.shape == expected.shape
        assert np.abs(got - expected).max() < 1e-6, name
        # the bake is not the rest mesh held still: the comparison above has teeth
        assert np.abs(expected[-1] - expected[0]).max() > 1e-3  # a thousand times the tolerance
        # a key for every frame that differs from the rest mesh, and only those
        moved = np.abs(expected - expected[0]).max(axis=(1, 2)) > bake_store.STILL
        assert bunny_bake["keys"][obj] == ["Basis"] + [f"hh_f{f:05d}" for f, m in zip(range(1, 2 + FRAMES), moved)
                                                      if m]
        assert not moved[0], "the first frame is the rest mesh: no key"
        # after the range the last frame holds (as a point cache does), not the rest mesh
        assert np.abs(bunny_bake["after"][obj] - expected[-1]).max() < 1e-6, name


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


def test_forces_are_keyed_custom_properties(bunny_bake):
    """The Graph Editor's curves of the hand: the spring force and torque on the handle per
    frame (the engine's coupling wrench), and the force felt at the device (the haptic log's
    feedback at each frame's time)."""
    ref, forces = bunny_bake["reference"], bunny_bake["forces"]
    wrench = ref["coupling_wrench"]
    np.testing.assert_allclose(forces["hh_force"], wrench[:, :3], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(forces["hh_torque"], wrench[:, 3:], rtol=1e-6, atol=1e-7)
    t, felt = ref["haptic"]["t"], ref["haptic"]["force"]
    for k, time_k in enumerate(ref["time"][1:], start=1):
        last = np.flatnonzero(t <= time_k + 1e-9)[-1]  # the last haptic step by that time
        np.testing.assert_allclose(forces["hh_felt_force"][k], felt[last], rtol=1e-5, atol=1e-5)
    assert np.abs(forces["hh_force"]).max() > 0.1, "the hand pushes the bunny: the curves are not flat"


def test_log_saved_beside_blend(bunny_bake):
    log, ref = bunny_bake["log"], bunny_bake["reference"]
    assert str(bunny_bake["log_path"]).startswith(str(bunny_bake["folder"]))
    assert log["time"].shape == (FRAMES + 1,)
    np.testing.assert_allclose(log["time"], np.arange(FRAMES + 1) / 30.0, atol=1e-12)
    assert log["coupling_wrench"].shape == (FRAMES + 1, 6)
    np.testing.assert_array_equal(log["coupling_wrench"], ref["coupling_wrench"])


def test_log_has_one_row_per_haptic_step(bunny_bake):
    """simulate.run's result['haptic'] (one row per haptic step) is saved as haptic_*: a row at
    every multiple of haptic_dt up to the bake's end, evenly spaced in virtual time."""
    log = bunny_bake["log"]
    assert "haptic_t" in log, "the engine's result has no 'haptic' log (simulate.run)"
    dt = 1.0 / 30.0
    t = log["haptic_t"]
    haptic_dt = float(np.median(np.diff(t)))
    assert 0.0 < haptic_dt < dt / 2, "several haptic steps per frame"
    rows = int(np.floor(FRAMES * dt / haptic_dt + 1e-6))
    for key in ("t", "device_position", "device_quaternion", "proxy_position", "proxy_quaternion", "force",
                "torque", "period", "cost"):
        assert log[f"haptic_{key}"].shape[0] == rows, key
    assert np.all(np.diff(t) > 0)
    assert abs((t[-1] - t[0]) - (rows - 1) * haptic_dt) < 1e-6


def test_keys_size_shown_before_the_bake(addon, built_scenes, tmp_path):
    """The panel shows what a shape-key bake will add before it starts; the .blend grows by
    at most that (uncompressed: by nearly that, since every frame but the first moves)."""
    import os

    context = open_copy(built_scenes("bunny_press"), tmp_path)
    s = context.scene.haptic_hand
    s.bake_frame_start, s.bake_frame_end, s.bake_format = 1, 41, "KEYS"
    meshes = panel.deformed_meshes(context.scene)
    assert [o.name for o in meshes] == ["Hand", "bunny"]
    estimate = bake_store.keys_size(meshes, 41)
    assert any(panel.mib(estimate) in text for text in labels(draw_panels(context)))
    blend = tmp_path / "bunny_press.blend"
    sizes = {}
    for compress in (False, True):
        bpy.ops.wm.save_mainfile(compress=compress)
        sizes[compress] = os.path.getsize(blend)
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
    for compress in (False, True):
        bpy.ops.wm.save_mainfile(compress=compress)
        growth = os.path.getsize(blend) - sizes[compress]
        assert growth <= estimate, (compress, growth, estimate)
        if not compress:
            assert growth > 0.85 * estimate, (growth, estimate)
    # PC2 is offered as the compact choice: its files hold the same vertices, the .blend nothing
    assert any(panel.mib(bake_store.pc2_size(meshes, 41)) in text and "PC2" in text
               for text in labels(draw_panels(context)))


def cache_files(folder):
    return sorted(p.name for p in folder.iterdir()) if folder.exists() else []


def test_pc2_cancel_rebake_and_free(addon, built_scenes, tmp_path):
    context = open_copy(built_scenes("bunny_press"), tmp_path)
    s = context.scene.haptic_hand
    hand = s.hand
    rest = evaluated_world(context, hand, 1)
    folder = tmp_path / "bunny_press_haptic" / "Scene"  # the .blend's bake folder, the scene's own
    # a short point-cache bake, from the child process, with progress along the way
    s.bake_frame_start, s.bake_frame_end, s.bake_format = 1, 9, "PC2"
    reference = engine_surfaces(reference_run(context), "hand")
    state, job, seen = bake_in_background(context)
    assert state == "FINISHED", job.error
    progress = [p for p, _ in seen]
    assert len(seen) >= 3 and progress == sorted(progress) and any("frame" in m for _, m in seen), seen
    assert cache_files(folder) == ["Hand.pc2", "bunny.pc2", "haptic_log.npz"]
    pc2 = folder / "Hand.pc2"
    cached, start, rate = bake_formats.read_pc2(pc2)
    assert (start, rate, cached.shape) == (1.0, 1.0, reference.shape)
    assert hand.modifiers[0].type == "MESH_CACHE" and hand.modifiers[0].filepath == \
        "//bunny_press_haptic/Scene/Hand.pc2"
    shown = np.array([evaluated_world(context, hand, f) for f in range(1, 10)])
    assert np.abs(shown - reference).max() < 1e-6
    assert np.abs(evaluated_world(context, hand, 20) - reference[-1]).max() < 1e-6, "holds its last frame"

    # a longer bake cancelled part-way: the child is killed, the first bake stays untouched
    s.bake_frame_end, s.bake_format = 61, "KEYS"
    state, job, _ = bake_in_background(context, cancel_at=0.5)
    assert state == "CANCELLED" and job.child.process.returncode is not None
    assert job.child.process.returncode < 0, "killed by a signal, not finished"
    assert 0.5 <= job.progress < 1.0
    assert s.baked and s.baked_range == "1-9" and s.baked_format == "PC2"
    assert hand.data.shape_keys is None and [m.type for m in hand.modifiers] == ["MESH_CACHE"]
    np.testing.assert_array_equal(bake_formats.read_pc2(pc2)[0], cached)
    assert np.abs(evaluated_world(context, hand, 9) - reference[8]).max() < 1e-6
    assert not job.export.folder, "the exported scene folder is gone"

    # a finished re-bake as shape keys replaces it: the caches, their modifiers and files gone
    s.bake_frame_end = 4
    state, job, _ = bake_in_background(context)
    assert state == "FINISHED", job.error
    assert s.baked_range == "1-4" and not hand.modifiers
    assert cache_files(folder) == ["haptic_log.npz"], "no orphan .pc2 after the switch to shape keys"
    assert [b.name for b in hand.data.shape_keys.key_blocks] == ["Basis"] + [f"hh_f{f:05d}" for f in range(2, 5)]
    assert len([a for a in bpy.data.actions if a.name.startswith(ops_bake.ACTION_PREFIX)]) == 3  # 2 keys, forces
    assert np.abs(evaluated_world(context, hand, 4) - reference[3]).max() < 1e-6

    # and back to PC2: the keys go, the caches come back
    s.bake_format = "PC2"
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
    assert hand.data.shape_keys is None and cache_files(folder) == ["Hand.pc2", "bunny.pc2", "haptic_log.npz"]

    # free bake: the meshes are as before any bake, the files and their folder gone
    assert bpy.ops.haptic_hand.free_bake() == {"FINISHED"}
    assert hand.data.shape_keys is None and bpy.data.objects["bunny"].data.shape_keys is None
    assert not hand.modifiers and "hh_force" not in hand.keys()
    assert not [a for a in bpy.data.actions if a.name.startswith(ops_bake.ACTION_PREFIX)]
    assert not folder.parent.exists(), cache_files(folder.parent)
    assert not s.baked
    np.testing.assert_array_equal(evaluated_world(context, hand, 4), rest)


def test_pc2_bake_survives_a_copied_folder_and_says_when_its_files_are_missing(addon, built_scenes, tmp_path):
    first = tmp_path / "first"
    first.mkdir()
    context = open_copy(built_scenes("bunny_press"), first)
    s = context.scene.haptic_hand
    s.bake_frame_start, s.bake_frame_end, s.bake_format = 1, 6, "PC2"
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
    bpy.ops.wm.save_mainfile()
    shown = np.array([evaluated_world(context, s.hand, f) for f in range(1, 7)])
    assert not [t for t in labels(draw_panels(context)) if "missing" in t]

    # the .blend with its folder, elsewhere: the relative paths find the caches
    copied = tmp_path / "copied"
    copied.mkdir()
    shutil.copy(first / "bunny_press.blend", copied)
    shutil.copytree(first / "bunny_press_haptic", copied / "bunny_press_haptic")
    shutil.rmtree(first)  # the original is gone: nothing can be read from it
    bpy.ops.wm.open_mainfile(filepath=str(copied / "bunny_press.blend"))
    context = bpy.context
    hand = context.scene.haptic_hand.hand
    np.testing.assert_allclose(np.array([evaluated_world(context, hand, f) for f in range(1, 7)]), shown, atol=1e-7)
    assert not [t for t in labels(draw_panels(context)) if "missing" in t]

    # the .blend alone: the panel says which caches are missing and what to do
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(copied / "bunny_press.blend", alone)
    bpy.ops.wm.open_mainfile(filepath=str(alone / "bunny_press.blend"))
    texts = labels(draw_panels(bpy.context))
    missing = [t for t in texts if "missing" in t]
    assert len(missing) == 2 and any(t.startswith("Hand:") for t in missing) and any(
        t.startswith("bunny:") for t in missing), texts
    assert any("bunny_press_haptic" in t and "copy" in t.lower() for t in texts)


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


def test_objects_that_never_move_store_nothing(addon, built_scenes, tmp_path):
    """Without gravity or ground, a bunny the hand has not reached yet and a rigid cube far
    away never move: they get no keys, no cache and no keyed transform, and the report says
    so."""
    context = open_copy(built_scenes("bunny_press"), tmp_path)
    context.scene.use_gravity = False
    bpy.data.objects["ground"].haptic_hand.role = "NONE"  # the bunny rests just into its contact layer
    bpy.ops.mesh.primitive_cube_add(size=0.02, location=(0.5, 0.5, 0.5))
    cube = context.active_object
    cube.name = "Far cube"
    cube.haptic_hand.role = "RIGID"
    s = context.scene.haptic_hand
    s.bake_frame_start, s.bake_frame_end = 1, 4
    reference = reference_run(context)
    assert np.abs(engine_surfaces(reference, "bunny") - engine_surfaces(reference, "bunny")[0]).max() <= \
        bake_store.STILL, "the bunny is still in the engine too"
    assert np.abs(reference["body_Far cube_pose"] - reference["body_Far cube_pose"][0]).max() <= bake_store.STILL
    for fmt in ("KEYS", "PC2"):
        s.bake_format = fmt
        state, job, _ = bake_in_background(context)
        assert state == "FINISHED", job.error
        bunny = bpy.data.objects["bunny"]
        assert bunny.data.shape_keys is None and not bunny.modifiers and not bunny.haptic_hand.baked
        assert cube.animation_data is None or cube.animation_data.action is None
        assert "nothing stored for Far cube, bunny" in job.summary or "nothing stored for bunny, Far cube" in \
            job.summary, job.summary
        assert s.hand.haptic_hand.baked, "the hand moves: it is baked"
        assert not (bake_store.cache_dir() / "bunny.pc2").exists()
