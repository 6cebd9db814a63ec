"""What runs (a bake, a tetrahedralization, a live session) is never saved: a file saved while
one runs reopens with Bake, Tetrahedralize and Live available, and opening it stops what ran."""

import time

import pytest

bpy = pytest.importorskip("bpy")
import numpy as np

from haptic_hand.blender import live, ops_bake, ops_rig, runtime, scene_export

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


def test_a_file_saved_during_tetrahedralize_reopens_idle(addon, built_scenes, tmp_path):
    context = open_copy(built_scenes("hand_wave"), tmp_path)
    hand = context.scene.haptic_hand.hand
    nodes = scene_export.hand_tets_world(context.scene)[0]
    hand.haptic_hand.edge_length_fac, hand.haptic_hand.coarsen = 0.03, False  # long enough to save meanwhile
    context.view_layer.objects.active = hand
    job = ops_rig.start_tetrahedralize(context, hand, confirmed=True)
    runtime.state.tetrahedralize = job  # what the Tetrahedralize button does (invoke)
    while job.progress < 0.05 and job.child.poll() == "RUNNING":
        time.sleep(0.01)
    assert job.child.poll() == "RUNNING", "still running when the file is saved"
    assert not bpy.ops.haptic_hand.tetrahedralize.poll() and not bpy.ops.haptic_hand.bake.poll()
    assert "haptic_hand.tetrahedralize_cancel" in operators(draw_panels(context))
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.open_mainfile(filepath=bpy.data.filepath)
    context = bpy.context
    assert not runtime.state.busy()
    assert job.child.process.returncode is not None, "opening a file stops the child"
    assert not job.folder.exists(), "and removes its files"
    hand = context.scene.haptic_hand.hand
    context.view_layer.objects.active = hand
    assert bpy.ops.haptic_hand.tetrahedralize.poll() and bpy.ops.haptic_hand.bake.poll()
    drawn = operators(draw_panels(context))
    assert "haptic_hand.tetrahedralize" in drawn and "haptic_hand.tetrahedralize_cancel" not in drawn
    np.testing.assert_array_equal(scene_export.hand_tets_world(context.scene)[0], nodes)  # the hand keeps its tets

