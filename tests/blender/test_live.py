"""Live session: the per-frame update writes the session's frames into the meshes and every
body's pose into its object, Esc/stop puts the scene back; a real session with a falling
rigid body and a moving collider, as the engine moves them; a recorded session (to a
blend-relative file) baked through the Playback device to the same motion; none to // in a
file never saved."""

import time

import pytest

bpy = pytest.importorskip("bpy")
import numpy as np

from haptic_hand.blender import draw, live, meshdata, ops_bake, runtime, scene_export
from haptic_hand.engine import quaternion

from blender_helpers import SAMPLES, FakeFrame, FakeSession, open_copy


def world_vertices(context, obj):
    return meshdata.world_vertices(obj, context.scene)


def test_update_writes_frames_and_stop_restores(addon, built_scenes, tmp_path):
    context = open_copy(built_scenes("bunny_press"), tmp_path)
    s = context.scene.haptic_hand
    hand, bunny = s.hand, bpy.data.objects["bunny"]
    # move and turn the hand object: the session's world positions must come back in its frame
    hand.location = (0.1, 0.2, 0.3)
    hand.rotation_mode = "XYZ"
    hand.rotation_euler = (0.3, 0.0, 0.5)
    context.view_layer.update()
    rest_hand, rest_bunny = world_vertices(context, hand), world_vertices(context, bunny)
    s.device, s.target = "TARGET", s.target
    s.live_recording = "//fake take.npz"  # blend-relative, as the field offers
    state = live.start(context, session_factory=FakeSession)
    session = state.session
    assert session.started and session.device == "external"
    live.update(context, state)  # no frame yet: nothing written
    assert state.frames_written == 0
    np.testing.assert_array_equal(world_vertices(context, hand), rest_hand)

    for step in range(3):
        offset = np.array([0.0, 0.0, -0.001 * (step + 1)])
        session.frames.append(FakeFrame(step / 30, {"hand": rest_hand + offset, "bunny": rest_bunny - offset}))
        assert live.update(context, state)
        assert state.frames_written == step + 1
        assert np.abs(world_vertices(context, hand) - (rest_hand + offset)).max() < 1e-6
        assert np.abs(world_vertices(context, bunny) - (rest_bunny - offset)).max() < 1e-6
    assert draw.overlay is not None and np.allclose(draw.overlay["force"], [0, 0, 2])

    # the viewport target: moving the empty 1 cm moves the pushed device position 1 cm
    first = session.poses_pushed[-1][0]
    s.target.location.x += 0.01
    context.view_layer.update()
    live.update(context, state)
    np.testing.assert_allclose(session.poses_pushed[-1][0] - first, [0.01, 0.0, 0.0], atol=1e-6)

    # an error in the session ends it; stopping restores every mesh exactly and saves the take
    session.error = "device disconnected"
    with pytest.raises(live.LiveError, match="device disconnected"):
        live.update(context, state)
    live.stop(context, state)
    assert session.stopped and draw.overlay is None
    np.testing.assert_array_equal(world_vertices(context, hand), rest_hand)
    np.testing.assert_array_equal(world_vertices(context, bunny), rest_bunny)
    assert state.record_error is None and state.recorded == tmp_path / "fake take.npz"
    with np.load(state.recorded) as take:
        np.testing.assert_allclose(take["haptic_t"], [0, 1 / 30, 2 / 30])
        np.testing.assert_allclose(take["haptic_force"], [[0, 0, 2.0]] * 3)  # the felt force
        np.testing.assert_allclose(take["time"], [0, 1 / 30, 2 / 30])  # the frames Blender showed


def test_live_refuses_baked_meshes(addon, built_scenes, tmp_path):
    context = open_copy(built_scenes("hand_wave"), tmp_path)
    s = context.scene.haptic_hand
    s.bake_frame_end = s.bake_frame_start + 2
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
    with pytest.raises(live.LiveError, match="Free Bake"):
        live.start(context, session_factory=FakeSession)


def run_live(context, seconds, on_frame=None):
    """A real session for `seconds` of wall time, one update every 1/60 s (as the timer)."""
    state = live.start(context)
    try:
        start = time.monotonic()
        while time.monotonic() - start < seconds:
            before = state.frames_written
            assert live.update(context, state), state.session.error
            if state.frames_written > before and on_frame is not None:
                on_frame(state.last_frame)
            time.sleep(1.0 / 60.0)
    finally:
        live.stop(context, state)
    return state


def add_cube(context, name, location, role):
    bpy.ops.mesh.primitive_cube_add(size=0.02, location=location)
    cube = context.active_object
    cube.name = name
    cube.haptic_hand.role = role
    return cube


def test_rigid_and_moving_bodies_move_in_blender_as_in_the_engine(addon, built_scenes, tmp_path):
    """A cube falls beside the waving hand and a moving collider follows its animation: each
    frame Blender shows them where the engine's session has them, the falling one drops as
    gravity says, the moving one is where its Blender animation puts it at that time."""
    context = open_copy(built_scenes("hand_wave"), tmp_path)
    s = context.scene.haptic_hand
    s.device, s.live_record = "SIMULATED", False
    falling = add_cube(context, "Falling", (0.0, 0.25, 1.0), "RIGID")
    falling.rotation_euler = (0.2, 0.1, 0.0)
    pusher = add_cube(context, "Pusher", (0.0, 0.4, 0.0), "MOVING")
    pusher.keyframe_insert("location", frame=1)
    pusher.location.x = 0.06
    pusher.keyframe_insert("location", frame=31)
    context.scene.frame_set(1)
    fps = scene_export.fps(context.scene)
    rest = {o.name: world_vertices(context, o) for o in (falling, pusher)}
    matrices = {o.name: np.array(o.matrix_world) for o in (falling, pusher)}
    keyed = {}
    for frame in range(1, 32):
        context.scene.frame_set(frame)
        keyed[frame] = np.array(pusher.matrix_world.translation)
    context.scene.frame_set(1)
    seen = []

    def check(frame):
        """Blender's objects against the engine's published poses, this frame."""
        for obj in (falling, pusher):
            pose = np.asarray(frame.poses[obj.name])
            first = seen[0][obj.name] if seen else pose
            expected = pose[:3] + (rest[obj.name] - first[:3]) @ quaternion.to_matrix(
                quaternion.multiply(pose[3:], quaternion.conjugate(first[3:]))).T
            assert np.abs(world_vertices(context, obj) - expected).max() < 1e-5, (obj.name, frame.time)
        seen.append({o.name: np.asarray(frame.poses[o.name]) for o in (falling, pusher)} | {"t": frame.time})

    run_live(context, 1.2, on_frame=check)
    assert len(seen) >= 10, f"only {len(seen)} frames"
    first, last = seen[0], seen[-1]
    t = last["t"] - first["t"]
    drop = first["Falling"][2] - last["Falling"][2]
    assert 0.8 < drop / (0.5 * 9.81 * (last["t"] ** 2 - first["t"] ** 2)) < 1.25, (drop, t)
    for pose in seen:  # the collider is where its animation has it at that time
        frame = 1 + pose["t"] * fps
        if frame <= 31:
            lo = int(np.floor(frame))
            expected = keyed[lo] + (frame - lo) * (keyed[min(lo + 1, 31)] - keyed[lo])
            np.testing.assert_allclose(pose["Pusher"][:3], expected, atol=2e-4)
    assert seen[-1]["Pusher"][0] - seen[0]["Pusher"][0] > 0.01, "the collider moved"
    # stopping puts both back
    for obj in (falling, pusher):
        np.testing.assert_allclose(np.array(obj.matrix_world), matrices[obj.name], atol=1e-7)


def test_recorded_live_session_bakes_through_playback_to_the_same_motion(addon, built_scenes, tmp_path):
    """Record a live session (device stream and felt force, to a // file), then Bake
    Recording: the bake replays the device stream exactly, and the hand moves as it did live:
    a live frame ending at t reads the proxy at t, as the bake's does, so the two differ by the
    live loops' scheduling jitter, far less than the device's motion in a frame (a frame late,
    they differ by about one frame's motion)."""
    context = open_copy(built_scenes("hand_wave"), tmp_path)
    s = context.scene.haptic_hand
    hand = s.hand
    rest = world_vertices(context, hand)
    s.device, s.live_record, s.live_recording = "SIMULATED", True, "//takes/wave.npz"
    shown = []
    state = run_live(context, 2.0, on_frame=lambda f: shown.append(world_vertices(context, hand)))
    assert state.frames_written >= 10, f"only {state.frames_written} frames in 2 s"
    assert np.abs(shown[-1] - shown[0]).max() > 1e-3, "the simulated device waves the hand"
    np.testing.assert_array_equal(world_vertices(context, hand), rest)
    path = tmp_path / "takes" / "wave.npz"
    assert state.recorded == path and state.record_error is None
    with np.load(path) as take:
        take = dict(take)
    assert len(take["haptic_t"]) > 500, "about 1 kHz for 2 s, even on a busy 2-core machine"
    assert take["haptic_force"].shape == take["haptic_device_position"].shape == (len(take["haptic_t"]), 3)

    assert bpy.ops.haptic_hand.bake_recording() == {"FINISHED"}
    frames = int(np.ceil(take["haptic_t"][-1] * 30 - 1e-9))
    assert s.baked_range == f"{s.bake_frame_start}-{s.bake_frame_start + frames}"
    with np.load(bpy.path.abspath(s.bake_log)) as log:
        log = dict(log)
    # the device, replayed exactly: every haptic step reads the recording at its own time
    t = log["haptic_t"] if "haptic_t" in log else log["time"]
    read = log["haptic_device_position"] if "haptic_t" in log else log["device_pose"][:, :3]
    device = np.stack([np.interp(t, take["haptic_t"], take["haptic_device_position"][:, i]) for i in range(3)], axis=1)
    np.testing.assert_allclose(read, device, atol=1e-9)
    step = np.linalg.norm(np.diff(take["haptic_device_position"], axis=0), axis=1) / np.diff(take["haptic_t"])
    one_frame = step.max() / 30  # how far the device moves in a frame at its fastest
    k = np.round(take["time"] * 30).astype(int)
    inside = k < len(log["time"])
    apart = np.linalg.norm(log["handle_pose"][k[inside], :3] - take["handle_pose"][inside, :3], axis=1)
    travel = np.linalg.norm(log["handle_pose"][:, :3] - log["handle_pose"][0, :3], axis=1).max()
    assert travel > 3 * one_frame, "the hand travels further than the tolerance below"
    assert apart.max() < 0.2 * one_frame, (apart.max(), one_frame)


def test_blend_relative_paths_work_everywhere(addon, built_scenes, tmp_path):
    """Every file-path setting takes // paths (Blender 4.5+ says so per property), and the
    Playback device reads a // recording."""
    from haptic_hand.blender import properties

    for cls in properties.classes:
        for prop in cls.bl_rna.properties:
            if getattr(prop, "subtype", "") == "FILE_PATH" and hasattr(prop, "is_path_supports_blend_relative"):
                assert prop.is_path_supports_blend_relative, f"{cls.__name__}.{prop.identifier}"
    context = open_copy(built_scenes("hand_wave"), tmp_path)
    s = context.scene.haptic_hand
    t = np.linspace(0, 0.2, 21)
    np.savez(tmp_path / "down.npz", t=t, position=np.c_[0 * t, 0 * t, -0.05 * t])
    s.device, s.device_file = "PLAYBACK", "//down.npz"
    s.bake_frame_end = s.bake_frame_start + 6
    job = ops_bake.prepare(context)
    try:
        data = __import__("json").loads((job.export.folder / "scene.json").read_text())
    finally:
        job.release()
    assert data["haptics"]["device"] == f"playback:{tmp_path / 'down.npz'}"
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}


def test_an_unsaved_file_records_nowhere_but_where_asked(addon, tmp_path, monkeypatch):
    """In a file never saved, // has no folder: a recording to //haptic_recording.npz is refused
    (as Bake is) rather than written to the working directory; a full path or Record off runs."""
    from haptic_hand.blender import scene_import

    monkeypatch.chdir(tmp_path)
    context = addon
    scene_import.build(context, SAMPLES / "hand_wave.json")
    s = context.scene.haptic_hand
    assert s.live_record and s.live_recording == "//haptic_recording.npz" and not bpy.data.filepath
    with pytest.raises(live.LiveError, match=r"Save the .blend file first .*//haptic_recording.npz"):
        live.start(context, session_factory=FakeSession)
    assert not runtime.state.busy() and not list(tmp_path.iterdir()), "nothing runs, nothing written"

    s.live_recording = str(tmp_path / "take.npz")  # a full path is where it says
    state = live.start(context, session_factory=FakeSession)
    state.session.frames.append(FakeFrame(0.0, {"hand": world_vertices(context, s.hand)}))
    assert live.update(context, state)
    live.stop(context, state)
    assert state.recorded == tmp_path / "take.npz" and state.recorded.is_file()
    s.live_record = False  # and without recording, nothing is written at all
    state = live.start(context, session_factory=FakeSession)
    live.stop(context, state)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["take.npz"]

