"""What runs (a bake, a live session) is never saved: a file saved while a bake or a live
session runs reopens with Bake and Live available, and opening it stops what ran."""

import time

import pytest

bpy = pytest.importorskip("bpy")

from haptic_hand.blender import live, ops_bake, runtime

from blender_helpers import FakeSession, draw_panels, open_copy, operators


def test_a_file_saved_during_a_bake_reopens_idle(addon, built_scenes, tmp_path):
    context = open_copy(built_scenes("bunny_press"), tmp_path)
    s = context.scene.haptic_hand
    s.bake_frame_end = 121
    job = ops_bake.prepare(context)
    runtime.state.bake = job.start()  # what the Bake button does (invoke)
    while job.progress < 0.05:
        time.sleep(0.01)
    assert not bpy.ops.haptic_hand.bake.poll() and not bpy.ops.haptic_hand.live.poll()
    assert "haptic_hand.bake_cancel" in operators(draw_panels(context))
    # a file from an older version kept its running state in the scene: it is cleared too
    s["bake_running"] = 1
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.open_mainfile(filepath=bpy.data.filepath)
    context = bpy.context
    assert not runtime.state.busy()
    assert job.child.process.returncode is not None, "opening a file stops the bake that ran"
    assert "bake_running" not in context.scene.haptic_hand.keys()
    assert bpy.ops.haptic_hand.bake.poll() and bpy.ops.haptic_hand.live.poll()
    drawn = operators(draw_panels(context))
    assert "haptic_hand.bake" in drawn and "haptic_hand.bake_cancel" not in drawn
    assert not context.scene.haptic_hand.baked
    # and the bake runs again
    context.scene.haptic_hand.bake_frame_end = 4
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}


def test_a_file_saved_during_a_live_session_reopens_idle(addon, built_scenes, tmp_path):
    context = open_copy(built_scenes("hand_wave"), tmp_path)
    s = context.scene.haptic_hand
    s.live_record = False
    state = live.start(context, session_factory=FakeSession)
    runtime.state.live = state  # what Start does (invoke)
    assert not bpy.ops.haptic_hand.live.poll() and bpy.ops.haptic_hand.live_stop.poll()
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.open_mainfile(filepath=bpy.data.filepath)
    assert not runtime.state.busy() and state.session.stopped
    assert bpy.ops.haptic_hand.live.poll() and not bpy.ops.haptic_hand.live_stop.poll()
    assert bpy.ops.haptic_hand.bake.poll()
