"""Baking: the engine runs the scene offline (haptic_hand.engine.simulate.run) over a frame
range, off the UI thread, and the result is written into the .blend as shape keys with keyed
values (or a PC2 point cache played by a Mesh Cache modifier) and keyed transforms.

Three steps, each a plain function so scripts and tests can drive them without a window
(timers and modal events never fire headless):
    job = prepare(context)      # main thread: export the scene (Blender is read, not changed)
    job.start() / job.run()     # a worker thread, or inline: the engine only, no bpy
    poll_job(context, job)      # main thread: progress; when done, write the bake (finish)
Nothing in the scene changes until the new bake has finished: a cancelled or failed bake
leaves the previous one as it was.
"""

from __future__ import annotations

import threading
from pathlib import Path

import bpy
import numpy as np

from ..engine import bake_formats
from ..engine import mesh as meshing
from ..engine import native, simulate
from ..engine import scene as scenes
from . import meshdata, scene_export

KEY_PREFIX = "hh_f"
ACTION_PREFIX = "HH bake "
MODIFIER_NAME = "Haptic Hand bake"
LOG_NAME = "haptic_log.npz"

_running = None  # the job of the modal bake operator, for the panel and the cancel button


class Cancelled(Exception):
    pass


class BakeError(ValueError):
    """A bake that cannot start; the message names the problem and the fix."""


def cache_dir() -> Path:
    """<blend folder>/<blend name>_haptic: where the haptic log and point caches go."""
    blend = Path(bpy.data.filepath)
    return blend.parent / f"{blend.stem}_haptic"


class BakeJob:
    """One bake: the exported scene and the engine run. run() touches no bpy data."""

    def __init__(self, export: scene_export.Export, fmt: str):
        self.export = export
        self.fmt = fmt
        self.progress = 0.0
        self.message = "starting"
        self.cancel = False
        self.cancelled = False
        self.result = None
        self.error = None
        self.done = False
        self.thread = None
        self.on_progress = None  # optional extra callback (fraction, message), same thread as run()

    def _progress(self, fraction: float, message: str) -> None:
        self.progress, self.message = float(fraction), message
        if self.on_progress is not None:
            self.on_progress(fraction, message)
        if self.cancel:
            raise Cancelled()

    def run(self) -> None:
        try:
            self.result = simulate.run(self.export.scene, progress=self._progress)
        except Cancelled:
            self.cancelled = True
        except (scenes.SceneError, meshing.MeshError, native.NativeError, OSError, ValueError) as e:
            self.error = f"The simulation failed: {e}"
        except Exception as e:  # keep the UI alive whatever the engine raises
            self.error = f"The simulation failed unexpectedly ({type(e).__name__}: {e}); please report it"
        finally:
            self.done = True

    def start(self) -> None:
        self.thread = threading.Thread(target=self.run, name="haptic_hand bake", daemon=True)
        self.thread.start()

    def wait(self) -> None:
        if self.thread is not None:
            self.thread.join()


def prepare(context) -> BakeJob:
    """Export the scene for a bake; raises BakeError (or ExportError) with the fix."""
    s = context.scene.haptic_hand
    if not bpy.data.filepath:
        raise BakeError("Save the .blend file first (File > Save): the bake writes its haptic log"
                        + (" and point caches" if s.bake_format == "PC2" else "") + " beside it")
    if s.device in ("OPENHAPTICS", "HID"):
        raise BakeError(f"A bake cannot read a live {s.device.title()} device: record it in a live session, "
                        "then bake with the Playback device, or bake with the Simulated device and a target empty")
    export = scene_export.export(context)
    if s.device == "PLAYBACK":
        try:
            path = bpy.path.abspath(s.device_file)
            if export.scene.data["haptics"]["enabled"]:
                if not path or not Path(path).is_file():
                    raise BakeError(f"The recording '{path}' does not exist: choose a recording in Haptic Hand > "
                                    "Device")
                export.scene.data["haptics"]["device"] = f"playback:{path}"
            else:
                _use_recording(export, path)
        except Exception:
            export.cleanup()
            raise
    return BakeJob(export, s.bake_format)


def _use_recording(export: scene_export.Export, path: str) -> None:
    """Drive the bake by a recorded haptic log: its device poses, in world metres."""
    if not path or not Path(path).is_file():
        raise BakeError(f"The recording '{path}' does not exist: choose a haptic log (.npz) in Haptic Hand > Device")
    with np.load(path) as log:
        if "haptic_device_position" in log:
            t, p, q = log["haptic_t"], log["haptic_device_position"], log["haptic_device_quaternion"]
        elif "device_pose" in log and "time" in log:
            t, p, q = log["time"], log["device_pose"][:, :3], log["device_pose"][:, 3:]
        else:
            raise BakeError(f"'{path}' holds no device poses (device_pose or haptic_device_position): choose a "
                            "haptic log saved by a bake or a live session")
    keep = np.r_[True, np.diff(t) > 0]
    export.scene.data["device"] = {"enabled": True, "frame": "world", "trajectory": [
        {"t": float(ti - t[0]), "position": pi.tolist(), "quaternion": qi.tolist()}
        for ti, pi, qi in zip(t[keep], p[keep], q[keep])]}


def poll_job(context, job: BakeJob) -> str:
    """One step of the modal bake: 'RUNNING', or when the job is done, write it and return
    'FINISHED', 'CANCELLED' or 'FAILED' (job.error says why)."""
    s = context.scene.haptic_hand
    s.bake_progress = job.progress
    if not job.done:
        return "RUNNING"
    try:
        if job.cancelled:
            return "CANCELLED"
        if job.error is not None:
            return "FAILED"
        try:
            finish(context, job)
        except (OSError, ValueError) as e:
            job.error = f"Writing the bake failed: {e}"
            return "FAILED"
        return "FINISHED"
    finally:
        job.export.cleanup()


# --------------------------------------------------------------------------------------------
# Writing a bake
# --------------------------------------------------------------------------------------------


def _surface_frames(result: dict, prefix: str) -> np.ndarray:
    """(frames, vertices, 3) render-surface positions in world metres, from the tet nodes."""
    if prefix == "hand":
        positions, tets = result["positions"], result["tets"]
        index, weights = result["surface_tet_index"], result["surface_weights"]
    else:
        key = f"body_{prefix}"
        positions, tets = result[f"{key}_positions"], result[f"{key}_tets"]
        index, weights = result[f"{key}_surface_tet_index"], result[f"{key}_surface_weights"]
    corners = np.asarray(tets)[index]  # (v, 4)
    return np.einsum("vj,fvjk->fvk", weights, positions[:, corners])


def deformed_objects(job: BakeJob):
    """(object, engine name, rest matrix) of the meshes the bake deforms: the hand, soft bodies."""
    e = job.export
    out = [(e.hand, "hand", e.hand_rest_matrix)]
    out += [(b.obj, b.name, b.rest_matrix) for b in e.bodies if b.role == "SOFT"]
    return out


def finish(context, job: BakeJob) -> str:
    """Replace the previous bake by job's result. Returns a summary for the report."""
    scene = context.scene
    s = scene.haptic_hand
    result, e = job.result, job.export
    frames = np.arange(e.frame_start, e.frame_end + 1)
    local = {}
    for obj, name, rest in deformed_objects(job):
        world = _surface_frames(result, name)
        local[obj.name] = meshdata.transform(np.linalg.inv(rest), world / e.scale)
    folder = cache_dir()
    log_path = bake_formats.write_log(folder / LOG_NAME, bake_formats.haptic_log(result))
    free(context, keep_files=True)
    for obj, name, rest in deformed_objects(job):
        if job.fmt == "PC2":
            path = bake_formats.write_pc2(folder / f"{scene_export._safe(obj.name)}.pc2", local[obj.name],
                                          start_frame=float(e.frame_start))
            _add_mesh_cache(obj, path, e.frame_start)
        else:
            _write_shape_keys(obj, local[obj.name], frames)
        obj.haptic_hand.baked = True
    for b in e.bodies:
        if b.role == "RIGID":
            _write_transforms(b.obj, b.rest_matrix, result[f"body_{b.name}_pose"], frames, e.scale)
            b.obj.haptic_hand.baked = True
    s.baked, s.baked_format, s.baked_range = True, job.fmt, f"{e.frame_start}-{e.frame_end}"
    s.bake_log = bpy.path.relpath(str(log_path))
    context.view_layer.update()
    return (f"Baked frames {e.frame_start}-{e.frame_end} ({len(frames) - 1} steps) as "
            f"{'a point cache' if job.fmt == 'PC2' else 'shape keys'}; haptic log: {log_path}")


def _new_action(id_data, name: str):
    """A fresh action assigned to id_data; returns (action, fcurves collection, previous action)."""
    ad = id_data.animation_data or id_data.animation_data_create()
    previous = ad.action
    action = bpy.data.actions.new(name)
    action.use_fake_user = False
    ad.action = action
    if hasattr(action, "slots"):  # Blender 4.4 and newer: slotted actions
        from bpy_extras import anim_utils

        slot = action.slots.new(id_type=id_data.id_type, name=id_data.name)
        ad.action_slot = slot
        fcurves = anim_utils.action_ensure_channelbag_for_slot(action, slot).fcurves
    else:
        fcurves = action.fcurves
    return action, fcurves, previous


def _fcurve(fcurves, path: str, index: int, frames, values) -> None:
    fc = fcurves.new(path, index=index)
    fc.keyframe_points.add(len(frames))
    co = np.empty(2 * len(frames), dtype=np.float32)
    co[0::2], co[1::2] = frames, values
    fc.keyframe_points.foreach_set("co", co)
    for kp in fc.keyframe_points:
        kp.interpolation = "LINEAR"
    fc.update()


def _write_shape_keys(obj, local: np.ndarray, frames: np.ndarray) -> None:
    """One shape key per frame; its value is 1 on its frame and 0 on the neighbouring frames."""
    o = obj.haptic_hand
    if obj.data.shape_keys is None:
        obj.shape_key_add(name="Basis", from_mix=False)
        o.bake_made_basis = True
    key = obj.data.shape_keys
    key.use_relative = True
    action, fcurves, previous = _new_action(key, ACTION_PREFIX + obj.name)
    o.previous_action = previous
    for k, frame in enumerate(frames):
        block = obj.shape_key_add(name=f"{KEY_PREFIX}{int(frame):05d}", from_mix=False)
        block.data.foreach_set("co", np.ascontiguousarray(local[k], dtype=np.float32).reshape(-1))
        block.value = 0.0
        _fcurve(fcurves, f'key_blocks["{block.name}"].value', 0, [frame - 1, frame, frame + 1], [0.0, 1.0, 0.0])


def _add_mesh_cache(obj, path: Path, frame_start: int) -> None:
    mod = obj.modifiers.new(MODIFIER_NAME, "MESH_CACHE")
    mod.cache_format = "PC2"
    mod.filepath = bpy.path.relpath(str(path))
    mod.play_mode = "SCENE"
    mod.time_mode = "FRAME"
    mod.frame_start = float(frame_start)
    mod.interpolation = "LINEAR"
    mod.deform_mode = "OVERWRITE"
    mod.forward_axis, mod.up_axis = "POS_Y", "POS_Z"
    obj.modifiers.move(len(obj.modifiers) - 1, 0)


def _write_transforms(obj, rest: np.ndarray, poses: np.ndarray, frames: np.ndarray, scale: float) -> None:
    import mathutils

    o = obj.haptic_hand
    o.rest_matrix = rest.T.reshape(-1).tolist()  # column-major, as Blender's matrices
    o.rest_rotation_mode = obj.rotation_mode
    action, fcurves, previous = _new_action(obj, ACTION_PREFIX + obj.name)
    o.previous_action = previous
    obj.rotation_mode = "QUATERNION"
    locations, quats = [], []
    last = None
    centre = poses[0, :3]
    for pose in poses:
        m = mathutils.Matrix(meshdata.rigid_matrix(rest, centre, pose, scale).tolist())
        loc, rot, _ = (obj.parent.matrix_world.inverted() @ m if obj.parent else m).decompose()
        if last is not None:
            rot.make_compatible(last)
        last = rot
        locations.append(loc)
        quats.append(rot)
    for i in range(3):
        _fcurve(fcurves, "location", i, frames, [v[i] for v in locations])
    for i in range(4):
        _fcurve(fcurves, "rotation_quaternion", i, frames, [q[i] for q in quats])


def free(context, keep_files: bool = False) -> int:
    """Remove the bake from every object (and its files unless keep_files); returns how many
    objects had one."""
    import mathutils

    scene = context.scene
    count = 0
    for obj in scene.objects:
        o = obj.haptic_hand
        if not o.baked:
            continue
        count += 1
        key = obj.data.shape_keys if obj.type == "MESH" else None
        if key is not None:
            ad = key.animation_data
            if ad is not None and ad.action is not None and ad.action.name.startswith(ACTION_PREFIX):
                old = ad.action
                ad.action = o.previous_action
                bpy.data.actions.remove(old)
            for block in [b for b in key.key_blocks if b.name.startswith(KEY_PREFIX)]:
                obj.shape_key_remove(block)
            if o.bake_made_basis and obj.data.shape_keys is not None and len(obj.data.shape_keys.key_blocks) <= 1:
                obj.shape_key_clear()
        mod = obj.modifiers.get(MODIFIER_NAME)
        if mod is not None:
            if not keep_files:
                Path(bpy.path.abspath(mod.filepath)).unlink(missing_ok=True)
            obj.modifiers.remove(mod)
        ad = obj.animation_data
        if ad is not None and ad.action is not None and ad.action.name.startswith(ACTION_PREFIX):
            old = ad.action
            ad.action = o.previous_action
            bpy.data.actions.remove(old)
            obj.rotation_mode = o.rest_rotation_mode or "XYZ"
            rest = mathutils.Matrix(np.array(o.rest_matrix).reshape(4, 4).T.tolist())
            obj.matrix_world = rest
        o.baked, o.bake_made_basis, o.previous_action = False, False, None
    s = scene.haptic_hand
    if not keep_files and s.bake_log:
        Path(bpy.path.abspath(s.bake_log)).unlink(missing_ok=True)
    s.baked, s.baked_format, s.baked_range, s.bake_log = False, "", "", ""
    return count


# --------------------------------------------------------------------------------------------
# Operators
# --------------------------------------------------------------------------------------------


def _report_start_error(op, e) -> set:
    op.report({"ERROR"}, str(e))
    return {"CANCELLED"}


class HAPTIC_HAND_OT_bake(bpy.types.Operator):
    """Simulate the frame range and store the result (from a script this runs to the end;
    from the UI it runs in the background: Esc or Cancel stops it and keeps the previous bake)"""

    bl_idname = "haptic_hand.bake"
    bl_label = "Bake"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        s = context.scene.haptic_hand
        if s.hand is None:
            cls.poll_message_set("Choose the hand in Haptic Hand > Rig")
            return False
        if s.bake_running or s.live_running:
            cls.poll_message_set("A bake or live session is running")
            return False
        return context.mode == "OBJECT"

    def execute(self, context):
        try:
            job = prepare(context)
        except (BakeError, scene_export.ExportError, meshing.MeshError, native.NativeError, OSError) as e:
            return _report_start_error(self, e)
        wm = context.window_manager
        wm.progress_begin(0.0, 1.0)
        job.on_progress = lambda fraction, message: wm.progress_update(fraction)
        try:
            job.run()
        finally:
            wm.progress_end()
        return self._end(context, job, poll_job(context, job))

    def invoke(self, context, event):
        global _running
        try:
            job = prepare(context)
        except (BakeError, scene_export.ExportError, meshing.MeshError, native.NativeError, OSError) as e:
            return _report_start_error(self, e)
        s = context.scene.haptic_hand
        s.bake_running, s.bake_cancel, s.bake_progress = True, False, 0.0
        _running = self.job = job
        job.start()
        wm = context.window_manager
        wm.progress_begin(0.0, 1.0)
        self.timer = wm.event_timer_add(0.1, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        s = context.scene.haptic_hand
        if event.type == "ESC" or s.bake_cancel:
            self.job.cancel = True
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        context.window_manager.progress_update(self.job.progress)
        state = poll_job(context, self.job)
        if state == "RUNNING":
            if context.area is not None:
                context.area.tag_redraw()
            return {"PASS_THROUGH"}
        self._stop_modal(context)
        return self._end(context, self.job, state)

    def _stop_modal(self, context):
        global _running
        wm = context.window_manager
        wm.event_timer_remove(self.timer)
        wm.progress_end()
        s = context.scene.haptic_hand
        s.bake_running, s.bake_cancel = False, False
        _running = None

    def cancel(self, context):
        self.job.cancel = True
        self.job.wait()
        self.job.export.cleanup()
        self._stop_modal(context)

    def _end(self, context, job, state):
        if state == "FINISHED":
            self.report({"INFO"}, f"Bake done: frames {context.scene.haptic_hand.baked_range}")
            return {"FINISHED"}
        if state == "CANCELLED":
            self.report({"WARNING"}, "Bake cancelled: the previous bake is unchanged")
        else:
            self.report({"ERROR"}, f"{job.error}; the previous bake is unchanged")
        return {"CANCELLED"}


class HAPTIC_HAND_OT_bake_cancel(bpy.types.Operator):
    """Stop the running bake; the previous bake stays"""

    bl_idname = "haptic_hand.bake_cancel"
    bl_label = "Cancel Bake"

    @classmethod
    def poll(cls, context):
        return context.scene.haptic_hand.bake_running

    def execute(self, context):
        context.scene.haptic_hand.bake_cancel = True
        if _running is not None:
            _running.cancel = True
        return {"FINISHED"}


class HAPTIC_HAND_OT_free_bake(bpy.types.Operator):
    """Remove the bake: shape keys, point caches, keyed transforms and the haptic log"""

    bl_idname = "haptic_hand.free_bake"
    bl_label = "Free Bake"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        s = context.scene.haptic_hand
        return s.baked and not s.bake_running

    def execute(self, context):
        n = free(context)
        self.report({"INFO"}, f"Bake removed from {n} object(s)")
        return {"FINISHED"}


classes = (HAPTIC_HAND_OT_bake, HAPTIC_HAND_OT_bake_cancel, HAPTIC_HAND_OT_free_bake)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    global _running
    if _running is not None:
        _running.cancel = True
        _running.wait()
        _running = None
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
