"""Live haptic session in the viewport: a modal operator that starts the engine's threads
(haptic_hand.engine.session.LiveSession) and, every viewport frame, writes the newest
deformed surfaces into the Blender meshes and the rigid bodies' poses into their objects.
The UI thread never steps the simulation: it only reads the newest frame the visual loop
published. A skinned hand's Armature modifiers are off while it runs (the frames are the
engine's positions, not to be posed again). Esc (or Stop) ends the session and puts every
object back as it was.

With Live Session > Record on, stopping saves the session's haptic log (the device stream and
the felt force, one row per haptic step, plus the frames Blender showed) to the Recording file;
Bake Recording replays it through the Playback device.

The per-frame work is plain functions, so tests drive a session without a window:
    state = start(context)            # export, create and start the session
    update(context, state)            # one viewport frame (what the timer calls)
    stop(context, state)              # join the threads, save the recording, restore the scene
"""

from __future__ import annotations

import numpy as np

import bpy

from ..engine import bake_formats, devices
from ..engine import mesh as meshing
from ..engine import native, native_world
from ..engine.session import LiveSession
from ..engine import scene as scenes
from . import armature, draw, meshdata, runtime, scene_export

DEVICES = devices.MENU_NAMES  # PLAYBACK is taken before this lookup


class LiveError(RuntimeError):
    """A live session that cannot start or went wrong; the message says what to do."""


class LiveState:
    def __init__(self, session, export: scene_export.Export):
        self.session = session
        self.export = export
        self.surfaces = {}      # engine name -> (object, inverse rest matrix)
        self.rigid = {}         # engine name -> (object, rest matrix, rest centre m)
        self.saved_positions = {}
        self.saved_matrices = {}
        self.muted = {}         # object name -> the Armature modifiers turned off while it runs
        self.frames_written = 0
        self.last_frame = None
        self.target = None      # (object, rest position m, rest quaternion) for the viewport target
        self.handle_com = None
        self.recording = None   # where stop() saves the recording (absolute), or None
        self.recorded = None    # the file stop() wrote
        self.record_error = None
        self.shown = []         # (time, handle pose, device pose) of every frame written

    def end(self, context) -> None:
        """stop(context, self): what the runtime calls when a file is opened."""
        stop(context, self)


def device_name(s) -> str:
    """haptics.device for the session; a playback recording is read here, so a bad one is
    refused before anything is exported or built."""
    if s.device == "PLAYBACK":
        path = bpy.path.abspath(s.device_file)
        if not s.device_file:
            raise LiveError("Choose the recording to play back (Haptic Hand > Device > Recording)")
        try:
            devices.load_recording(path)
        except devices.DeviceError as e:
            raise LiveError(f"The live session could not start: {e}") from None
        return f"playback:{path}"
    if s.device == "HID":
        if s.hid_device == "NONE":
            raise LiveError("No HID device found: plug in a 6-DoF HID device (SpaceMouse), or choose another device")
        return f"hid:{s.hid_device}"
    return DEVICES[s.device]


def start(context, session_factory=None) -> LiveState:
    """Export the scene, start a session and remember the meshes it will move. Raises
    LiveError / ExportError with the fix; on error nothing is left running or changed."""
    bscene = context.scene
    s = bscene.haptic_hand
    if s.device == "TARGET" and s.target is None:
        raise LiveError("The viewport-target device needs a target empty: pick one in Haptic Hand > Device > Target")
    device = device_name(s)
    if s.live_record and s.live_recording.startswith("//") and not bpy.data.filepath:
        raise LiveError(f"Save the .blend file first (File > Save): the session records to {s.live_recording}, "
                        "beside it; or give Live Session > Recording file a full path, or turn Record off")
    export = scene_export.export(context, bscene.frame_start, max(bscene.frame_end, bscene.frame_start + 1))
    try:
        return _start(context, export, device, session_factory or LiveSession)
    except Exception:
        export.cleanup()
        raise


def _start(context, export, device, factory) -> LiveState:
    bscene = context.scene
    s = bscene.haptic_hand
    deformed = [("hand", export.hand, export.hand_rest_matrix)]
    deformed += [(b.name, b.obj, b.rest_matrix) for b in export.bodies if b.role == "SOFT"]
    for name, obj, _ in deformed:
        if obj.data.shape_keys is not None or any(m.type == "MESH_CACHE" for m in obj.modifiers):
            raise LiveError(f"'{obj.name}' is driven by a bake (shape keys or a Mesh Cache): press Free Bake "
                            "before a live session")
    try:
        session = factory(export.scene, device=device)
    except (scenes.SceneError, meshing.MeshError, native.NativeError, devices.DeviceError, ValueError, OSError) as e:
        raise LiveError(f"The live session could not start: {e}") from None
    state = LiveState(session, export)
    for name, obj, rest in deformed:
        state.surfaces[name] = (obj, np.linalg.inv(rest))
        state.saved_positions[obj.name] = meshdata.local_vertices(obj.data).astype(np.float32)
    for b in export.bodies:
        if b.role in ("RIGID", "MOVING"):
            kind = native_world.RIGID if b.role == "RIGID" else native_world.KINEMATIC
            v = scene_export.rest_vertices(b.obj, bscene)
            centre = scene_export._kinematic_centre(v, meshdata.triangles(b.obj.data), kind)
            state.rigid[b.name] = (b.obj, b.rest_matrix, centre)
            state.saved_matrices[b.obj.name] = b.obj.matrix_world.copy()
    if s.live_record and s.live_recording:
        state.recording = bpy.path.abspath(s.live_recording)
    if s.device == "TARGET":
        m = meshdata.matrix(s.target)
        state.target = (s.target, m[:3, 3] * export.scale, m)
        state.handle_com = scene_export.handle_com(export)
    try:
        session.start()
    except Exception as e:
        session.stop()
        raise LiveError(f"The live session could not start: {e}") from None
    for _, obj, _ in deformed:  # the frames are where the engine put the meshes: no pose on top
        state.muted[obj.name] = armature.mute_skinning(obj)
    if s.device == "TARGET":
        push_target(state)
    return state


def push_target(state: LiveState) -> None:
    """Send the viewport target's pose as the device pose: its motion since the session
    started, applied to the handle's rest centre."""
    obj, p0, m0 = state.target
    m = meshdata.matrix(obj)
    rel = scene_export._relative_motion(m, m0)
    position = state.handle_com + (m[:3, 3] * state.export.scale - p0)
    state.session.set_device_pose(position, meshdata.quaternion_xyzs(rel))


def update(context, state: LiveState) -> bool:
    """One viewport frame: push the target pose, take the newest frame (if any) and write it
    into the meshes. Returns False once the session has stopped; raises LiveError on a
    session error."""
    session = state.session
    if session.error:
        raise LiveError(f"The live session stopped: {session.error}")
    if state.target is not None:
        push_target(state)
    frame = session.poll()
    if frame is None:
        return bool(session.running)
    scale = state.export.scale
    for name, (obj, inverse) in state.surfaces.items():
        world = np.asarray(frame.surfaces[name], dtype=np.float64)
        meshdata.write_positions(obj.data, meshdata.transform(inverse, world / scale))
    import mathutils

    for name, (obj, rest, centre) in state.rigid.items():
        if name in frame.poses:
            m = meshdata.rigid_matrix(rest, centre, np.asarray(frame.poses[name], dtype=float), scale)
            obj.matrix_world = mathutils.Matrix(m.tolist())
    state.frames_written += 1
    state.last_frame = frame
    state.shown.append((frame.time, np.concatenate([frame.handle_position, frame.handle_quaternion]),
                        np.concatenate([frame.device_position, frame.device_quaternion])))
    draw.overlay = {
        "handle_position": np.asarray(frame.handle_position) / scale,
        "handle_quaternion": np.asarray(frame.handle_quaternion),
        "device_position": np.asarray(frame.device_position) / scale,
        "proxy_position": np.asarray(frame.proxy_position) / scale,
        "force": np.asarray(frame.force), "force_scale": draw.FORCE_SCALE / scale,
        "radius": context.scene.haptic_hand.handle_radius_si / scale,
    }
    return True


def save_recording(state: LiveState) -> None:
    """The session's haptic log (haptic_t, haptic_device_position, haptic_force, ...) and the
    frames Blender showed (time, handle_pose, device_pose) to state.recording."""
    log = {f"haptic_{k}": np.asarray(v) for k, v in state.session.haptic_log().items()}
    if not len(log.get("haptic_t", ())):
        raise LiveError("the session ran no haptic step: nothing to record")
    if state.shown:
        log["time"] = np.array([t for t, _, _ in state.shown])
        log["handle_pose"] = np.array([h for _, h, _ in state.shown])
        log["device_pose"] = np.array([d for _, _, d in state.shown])
    state.recorded = bake_formats.write_log(state.recording, log)


def stop(context, state: LiveState) -> None:
    """Stop the session, save its recording (state.record_error says why not) and put the
    meshes and objects back as they were. Never raises."""
    try:
        state.session.stop()
        if state.recording:
            try:
                save_recording(state)
            except Exception as e:  # a full disk, a folder that is not there: the session still ends
                state.record_error = f"The recording could not be saved to {state.recording}: {e}"
    finally:
        draw.overlay = None
        for name, (obj, _) in state.surfaces.items():
            saved = state.saved_positions.get(obj.name)
            if saved is not None and len(saved) == len(obj.data.vertices):
                meshdata.write_positions(obj.data, saved)
        for obj_name, m in state.saved_matrices.items():
            obj = bpy.data.objects.get(obj_name)
            if obj is not None:
                obj.matrix_world = m
        for obj_name, names in state.muted.items():
            obj = bpy.data.objects.get(obj_name)
            if obj is not None:
                armature.unmute_skinning(obj, names)
        state.export.cleanup()


class HAPTIC_HAND_OT_live(bpy.types.Operator):
    """Start a live haptic session: the hand follows the device, the meshes update every
    viewport frame; Esc stops it and puts the scene back as it was"""

    bl_idname = "haptic_hand.live"
    bl_label = "Start Live Session"

    @classmethod
    def poll(cls, context):
        s = context.scene.haptic_hand
        busy = runtime.state.busy()
        if busy:
            cls.poll_message_set(busy)
            return False
        return s.hand is not None and context.mode == "OBJECT"

    def invoke(self, context, event):
        try:
            self.state = start(context)
        except (LiveError, scene_export.ExportError, meshing.MeshError, native.NativeError, devices.DeviceError,
                OSError, ValueError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        runtime.state.live, runtime.state.live_stop = self.state, False
        wm = context.window_manager
        self.timer = wm.event_timer_add(1.0 / 60.0, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        self.report({"ERROR"}, "A live session runs from the viewport (Haptic Hand > Live > Start); scripts call "
                               "haptic_hand.blender.live.start/update/stop")
        return {"CANCELLED"}

    def modal(self, context, event):
        if runtime.state.live is not self.state:  # stopped from outside (a file was opened)
            context.window_manager.event_timer_remove(self.timer)
            return {"CANCELLED"}
        if event.type == "ESC" or runtime.state.live_stop:
            self._end(context)
            self.report({"INFO"}, f"Live session stopped after {self.state.frames_written} frames")
            self._report_recording()
            return {"FINISHED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            alive = update(context, self.state)
        except (LiveError, ValueError) as e:
            self._end(context)
            self.report({"ERROR"}, f"{e}; the scene is restored")
            return {"CANCELLED"}
        if not alive:
            self._end(context)
            self.report({"INFO"}, "Live session ended (the device stopped)")
            self._report_recording()
            return {"FINISHED"}
        for area in context.screen.areas if context.screen else []:
            if area.type == "VIEW_3D":
                area.tag_redraw()
        return {"PASS_THROUGH"}

    def cancel(self, context):
        if runtime.state.live is self.state:
            self._end(context)

    def _end(self, context):
        context.window_manager.event_timer_remove(self.timer)
        runtime.state.live, runtime.state.live_stop = None, False
        stop(context, self.state)

    def _report_recording(self):
        if self.state.record_error:
            self.report({"WARNING"}, self.state.record_error)
        elif self.state.recorded:
            self.report({"INFO"}, f"Recording saved to {self.state.recorded}: Bake > Bake Recording replays it")


class HAPTIC_HAND_OT_live_stop(bpy.types.Operator):
    """Stop the live session and restore the scene"""

    bl_idname = "haptic_hand.live_stop"
    bl_label = "Stop Live Session"

    @classmethod
    def poll(cls, context):
        return runtime.state.live is not None

    def execute(self, context):
        runtime.state.live_stop = True
        return {"FINISHED"}


classes = (HAPTIC_HAND_OT_live, HAPTIC_HAND_OT_live_stop)


register, unregister = bpy.utils.register_classes_factory(classes)
