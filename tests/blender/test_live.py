"""Live session: the per-frame update writes the session's frames into the meshes, Esc/stop
puts the scene back; a real session driven by the simulated device for 2 s."""

import time

import pytest

bpy = pytest.importorskip("bpy")
import numpy as np

from haptic_hand.blender import draw, live, meshdata

from blender_helpers import open_copy


def world_vertices(context, obj):
    return meshdata.world_vertices(obj, context.scene)


class FakeFrame:
    def __init__(self, t, surfaces, poses=None):
        self.time, self.surfaces, self.poses = t, surfaces, poses or {}
        self.handle_position = np.array([0.0, 0.0, -0.04])
        self.handle_quaternion = np.array([0.0, 0.0, 0.0, 1.0])
        self.device_position = self.proxy_position = self.handle_position
        self.device_quaternion = self.proxy_quaternion = self.handle_quaternion
        self.force, self.torque = np.array([0.0, 0.0, 2.0]), np.zeros(3)


class FakeSession:
    """LiveSession's API, frames given by the test."""

    def __init__(self, scene, device="simulated", haptic_rate=1000.0):
        self.scene, self.device, self.frames, self.poses_pushed = scene, device, [], []
        self.running, self.error, self.started, self.stopped = False, None, False, False

    def start(self):
        self.running = self.started = True

    def poll(self):
        return self.frames.pop(0) if self.frames else None

    def set_device_pose(self, position, quaternion):
        self.poses_pushed.append((np.array(position), np.array(quaternion)))

    def stop(self):
        self.running, self.stopped = False, True


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

    # an error in the session ends it; stopping restores every mesh exactly
    session.error = "device disconnected"
    with pytest.raises(live.LiveError, match="device disconnected"):
        live.update(context, state)
    live.stop(context, state)
    assert session.stopped and draw.overlay is None
    np.testing.assert_array_equal(world_vertices(context, hand), rest_hand)
    np.testing.assert_array_equal(world_vertices(context, bunny), rest_bunny)


def test_live_refuses_baked_meshes(addon, built_scenes, tmp_path):
    context = open_copy(built_scenes("hand_wave"), tmp_path)
    s = context.scene.haptic_hand
    s.bake_frame_end = s.bake_frame_start + 2
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
    with pytest.raises(live.LiveError, match="Free Bake"):
        live.start(context, session_factory=FakeSession)


def test_simulated_device_live_for_two_seconds(addon, built_scenes, tmp_path):
    pytest.importorskip("haptic_hand.engine.session")
    context = open_copy(built_scenes("hand_wave"), tmp_path)
    s = context.scene.haptic_hand
    hand = s.hand
    rest = world_vertices(context, hand)
    s.device = "SIMULATED"
    state = live.start(context)
    written, times, shapes = 0, [], []
    try:
        start = time.monotonic()
        while time.monotonic() - start < 2.0:
            before = state.frames_written
            assert live.update(context, state), state.session.error
            if state.frames_written > before:  # a new frame: it is in the mesh now
                frame = state.last_frame
                shown = world_vertices(context, hand)
                assert np.abs(shown - frame.surfaces["hand"]).max() < 1e-6
                times.append(frame.time)
                shapes.append(shown)
            time.sleep(1.0 / 60.0)
        written = state.frames_written
    finally:
        live.stop(context, state)
    session = state.session
    print(f"{written} frames, {len(session.haptic_log()['t'])} haptic steps in 2 s")
    assert written >= 10, f"only {written} frames in 2 s"
    assert np.all(np.diff(times) > 0), "every frame written is newer than the last"
    # the simulated device waves the hand: the mesh moves between frames
    assert np.abs(shapes[-1] - shapes[0]).max() > 1e-3
    assert not session.running and session.error is None
    log = session.haptic_log()
    assert len(log["t"]) > 500  # about 1 kHz for 2 s, even on a busy 2-core machine
    np.testing.assert_array_equal(world_vertices(context, hand), rest)
