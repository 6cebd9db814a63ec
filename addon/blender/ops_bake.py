"""Baking: the engine simulates the frame range in a child process (haptic_hand.engine.child,
fed by the scene file the export writes), and the result is written into the .blend
(bake_store: shape keys or PC2 point caches, keyed transforms and forces, the haptic log).
A native crash or a runaway allocation ends the child, never Blender, and is reported; Esc or
Cancel kills the child.

Three steps, each a plain function so scripts and tests can drive them without a window
(timers and modal events never fire headless):
    job = prepare(context)      # export the scene (Blender is read, not changed)
    job.start()                 # start the child process
    poll_job(context, job)      # progress; when the child is done, write the bake
Nothing in the scene changes until the new bake is written whole: a cancelled or failed bake
leaves the previous one as it was.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import bpy

from ..engine import child as child_process
from ..engine import devices
from ..engine import mesh as meshing
from ..engine import native
from . import background, bake_store, runtime, scene_export
from .bake_store import ACTION_PREFIX, KEY_PREFIX, LOG_NAME, MODIFIER_NAME, cache_dir  # noqa: F401 (the API)

START_ERRORS = (scene_export.ExportError, meshing.MeshError, native.NativeError, devices.DeviceError, OSError,
                ValueError)


class BakeError(ValueError):
    """A bake that cannot start; the message names the problem and the fix."""


class BakeJob(background.ChildJob):
    """One bake: the exported scene and the child process that simulates it."""

    def __init__(self, export: scene_export.Export, fmt: str, argv=None):
        self.export = export
        self.fmt = fmt
        self.result_path = export.folder / "result.npz"
        super().__init__(child_process.Child(["bake", export.folder / "scene.json", self.result_path],
                                             what="The bake's engine process", argv=argv))
        self.warnings = list(export.scene.warnings)  # a hand far outside a human hand's size
        self.unchanged = True  # the previous bake is as it was (false only if a swap broke half-way)

    def run(self, on_progress=None) -> str:
        """Start and wait for the child (a script's bake); returns its final state."""
        self.start()
        return self.child.wait(on_progress=on_progress)

    def release(self) -> None:
        super().release()
        self.export.cleanup()


def recording_frames(path: str, fps: float) -> int:
    """Frames a recording lasts at fps (at least 1); DeviceError for a file it is not."""
    t, _, _ = devices.load_recording(path)
    return max(1, int(math.ceil((t[-1] - min(t[0], 0.0)) * fps - 1e-9)))


def prepare(context, recording: str | None = None) -> BakeJob:
    """Export the scene for a bake (recording: bake a live session's recording through the
    Playback device with the haptic loop on, over as many frames as it lasts); raises BakeError
    (or ExportError, DeviceError) with the fix."""
    s = context.scene.haptic_hand
    if not bpy.data.filepath:
        raise BakeError("Save the .blend file first (File > Save): the bake writes its haptic log"
                        + (" and point caches" if s.bake_format == "PC2" else "") + " beside it")
    if recording is None and s.device in ("OPENHAPTICS", "HID"):
        raise BakeError(f"A bake cannot read a live {s.device.title()} device: record it in a live session (Live "
                        "Session > Record), then press Bake Recording, or bake with the Simulated device and a "
                        "target empty")
    if recording is not None:
        path = bpy.path.abspath(recording)
        if not Path(path).is_file():
            raise BakeError(f"The recording '{path}' does not exist: record a live session first (Live Session > "
                            "Record)")
        frames = recording_frames(path, scene_export.fps(context.scene))
        export = scene_export.export(context, s.bake_frame_start, s.bake_frame_start + frames)
    else:
        export = scene_export.export(context)
    try:
        scene_file = export.folder / "scene.json"
        data = json.loads(scene_file.read_text())
        if recording is not None:
            data["haptics"]["enabled"] = True
            data["haptics"]["device"] = f"playback:{path}"
        elif s.device == "PLAYBACK":
            _playback(data, bpy.path.abspath(s.device_file))
        scene_file.write_text(json.dumps(data, indent=1))
    except Exception:
        export.cleanup()
        raise
    return BakeJob(export, s.bake_format)


def _playback(data: dict, path: str) -> None:
    """Drive the bake by a recording: through the haptic loop's playback device when the loop
    runs, else as the device trajectory (its poses in world metres)."""
    if not path or not Path(path).is_file():
        raise BakeError(f"The recording '{path}' does not exist: choose a recording in Haptic Hand > Device")
    if data["haptics"]["enabled"]:
        devices.load_recording(path)  # a clear message now rather than from the child
        data["haptics"]["device"] = f"playback:{path}"
        return
    t, p, q = devices.load_recording(path)
    data["device"] = {"enabled": True, "frame": "world", "trajectory": [
        {"t": float(ti - t[0]), "position": pi.tolist(), "quaternion": qi.tolist()} for ti, pi, qi in zip(t, p, q)]}


def poll_job(context, job: BakeJob) -> str:
    """One step of the modal bake: 'RUNNING', or when the child is done, write the bake and
    return 'FINISHED', 'CANCELLED' or 'FAILED' (job.error says why). Never raises."""
    state = job.child.poll()
    if state == "RUNNING":
        return "RUNNING"
    try:
        if state == "CANCELLED":
            return "CANCELLED"
        if state == "FAILED":
            job.error = f"The simulation failed: {job.child.error}"
            return "FAILED"
        try:
            result = child_process.load_result(job.result_path)
            job.summary = bake_store.write(context, job.export, result, job.fmt)
        except bake_store.BakeSwapError as e:
            job.error, job.unchanged = f"Writing the bake failed: {e}", False
            return "FAILED"
        except Exception as e:  # whatever failed, bake_store left the previous bake as it was
            job.error = f"Writing the bake failed: {e}"
            return "FAILED"
        return "FINISHED"
    finally:
        job.release()
        if runtime.state.bake is job:
            runtime.state.bake = None


def end_message(job: BakeJob, state: str) -> tuple[str, str]:
    """(report level, message) for a finished, cancelled or failed bake."""
    if state == "FINISHED":
        return "INFO", job.summary
    if state == "CANCELLED":
        return "WARNING", "Bake cancelled: the previous bake is unchanged"
    return "ERROR", job.error + ("; the previous bake is unchanged" if job.unchanged else "")


def status_text(job: BakeJob) -> str:
    return f"Haptic Hand: baking {job.progress * 100:.0f}% ({job.message}); Esc cancels"


# --------------------------------------------------------------------------------------------
# Operators
# --------------------------------------------------------------------------------------------


class _BakeOperator(background.BackgroundOperator):
    """Runs prepare()'s job: to the end from a script (execute), in the background from the UI
    (invoke: the child streams progress into the panel and the status bar; Esc cancels)."""

    bl_options = {"REGISTER"}
    slot = "bake"

    def make_job(self, context) -> BakeJob:
        raise NotImplementedError

    def execute(self, context):
        try:
            job = self.make_job(context)
        except START_ERRORS as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report_warnings(job)
        wm = context.window_manager
        wm.progress_begin(0.0, 1.0)
        try:
            job.run(on_progress=lambda fraction, message: wm.progress_update(fraction))
        finally:
            wm.progress_end()
        self.job = job
        return self.finish(context, poll_job(context, job))

    def invoke(self, context, event):
        try:
            job = self.make_job(context)
        except START_ERRORS as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report_warnings(job)
        return self.start_modal(context, job.start())

    def step(self, context, job):
        return poll_job(context, job)

    def status(self, job):
        return status_text(job)

    def finish(self, context, state):
        level, message = end_message(self.job, state)
        self.report({level}, message)
        return {"FINISHED"} if state == "FINISHED" else {"CANCELLED"}


def _can_bake(cls, context) -> bool:
    s = context.scene.haptic_hand
    if s.hand is None:
        cls.poll_message_set("Choose the hand in Haptic Hand > Rig")
        return False
    busy = runtime.state.busy()
    if busy:
        cls.poll_message_set(busy)
        return False
    return context.mode == "OBJECT"


class HAPTIC_HAND_OT_bake(_BakeOperator, bpy.types.Operator):
    """Simulate the frame range and store the result (from a script this runs to the end;
    from the UI it runs in a child process: Esc or Cancel stops it and keeps the previous bake)"""

    bl_idname = "haptic_hand.bake"
    bl_label = "Bake"

    @classmethod
    def poll(cls, context):
        return _can_bake(cls, context)

    def make_job(self, context):
        return prepare(context)


class HAPTIC_HAND_OT_bake_recording(_BakeOperator, bpy.types.Operator):
    """Bake the live session's recording through the Playback device, with the haptic loop on,
    over as many frames as it lasts from Bake Start"""

    bl_idname = "haptic_hand.bake_recording"
    bl_label = "Bake Recording"

    @classmethod
    def poll(cls, context):
        s = context.scene.haptic_hand
        if not s.live_recording or not Path(bpy.path.abspath(s.live_recording)).is_file():
            cls.poll_message_set("Record a live session first (Live Session > Record)")
            return False
        return _can_bake(cls, context)

    def make_job(self, context):
        return prepare(context, recording=context.scene.haptic_hand.live_recording)


class HAPTIC_HAND_OT_bake_cancel(bpy.types.Operator):
    """Stop the running bake (its child process is killed); the previous bake stays"""

    bl_idname = "haptic_hand.bake_cancel"
    bl_label = "Cancel Bake"

    @classmethod
    def poll(cls, context):
        return runtime.state.bake is not None

    def execute(self, context):
        runtime.state.bake.cancel()
        return {"FINISHED"}


class HAPTIC_HAND_OT_free_bake(bpy.types.Operator):
    """Remove the bake: shape keys, point caches, keyed transforms and forces, and the haptic log"""

    bl_idname = "haptic_hand.free_bake"
    bl_label = "Free Bake"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return context.scene.haptic_hand.baked and runtime.state.bake is None

    def execute(self, context):
        n = bake_store.free(context)
        self.report({"INFO"}, f"Bake removed from {n} object(s)")
        return {"FINISHED"}


classes = (HAPTIC_HAND_OT_bake, HAPTIC_HAND_OT_bake_recording, HAPTIC_HAND_OT_bake_cancel,
           HAPTIC_HAND_OT_free_bake)


register, unregister = bpy.utils.register_classes_factory(classes)
