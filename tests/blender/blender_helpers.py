"""Helpers shared by the Blender tests (a module with a unique name: every test folder has a
conftest.py, so `from conftest import ...` would be ambiguous)."""

from __future__ import annotations

import pathlib
import shutil

import haptic_hand

SAMPLES = pathlib.Path(haptic_hand.__file__).resolve().parent / "engine" / "sample_scenes"


def open_copy(path, folder) -> "bpy.types.Context":
    """Open a copy of the .blend at path saved in folder (a bake writes files beside it)."""
    import bpy

    target = pathlib.Path(folder) / pathlib.Path(path).name
    shutil.copy(path, target)
    bpy.ops.wm.open_mainfile(filepath=str(target))
    return bpy.context


class Recorder:
    """Stands in for bpy.types.UILayout: checks and records what a panel draws, as
    ("prop", data, name), ("operator", idname), ("label", text), ("progress", factor)."""

    def __init__(self, log):
        self.log = log
        self.active = True

    def _child(self, *args, **kwargs):
        return Recorder(self.log)

    row = column = box = grid_flow = split = _child

    def prop(self, data, name, **kwargs):
        import bpy  # noqa: F401

        assert name in data.bl_rna.properties, f"{type(data).__name__} has no property '{name}'"
        self.log.append(("prop", name, data))

    def operator(self, idname, **kwargs):
        import bpy

        module, name = idname.split(".")
        assert name in dir(getattr(bpy.ops, module)), f"operator {idname} is not registered"
        self.log.append(("operator", idname, kwargs.get("text")))

        class Props:
            pass
        return Props()

    def label(self, text="", **kwargs):
        self.log.append(("label", text, None))

    def separator(self, **kwargs):
        pass

    def progress(self, **kwargs):
        self.log.append(("progress", kwargs.get("factor"), kwargs.get("text")))


class FakePanel:
    def __init__(self, log):
        self.layout = Recorder(log)


def draw_panels(context) -> list:
    """What every panel of the Haptic Hand tab draws now: [(kind, what, extra)]."""
    from haptic_hand.blender import panel

    log = []
    for cls in panel.classes:
        cls.draw(FakePanel(log), context)
    return log


def labels(log) -> list[str]:
    return [what for kind, what, _ in log if kind == "label"]


def props(log) -> list[str]:
    return [what for kind, what, _ in log if kind == "prop"]


def operators(log) -> list[str]:
    return [what for kind, what, _ in log if kind == "operator"]


class FakeFrame:
    """A live session's frame with the given surfaces and poses (the rest made up)."""

    def __init__(self, t, surfaces, poses=None):
        import numpy as np

        self.time, self.surfaces, self.poses = t, surfaces, poses or {}
        self.handle_position = np.array([0.0, 0.0, -0.04])
        self.handle_quaternion = np.array([0.0, 0.0, 0.0, 1.0])
        self.device_position = self.proxy_position = self.handle_position
        self.device_quaternion = self.proxy_quaternion = self.handle_quaternion
        self.force, self.torque = np.array([0.0, 0.0, 2.0]), np.zeros(3)


class FakeSession:
    """LiveSession's API, frames given by the test; its haptic log has one row per frame."""

    def __init__(self, scene, device="simulated", haptic_rate=1000.0):
        self.scene, self.device, self.frames, self.poses_pushed = scene, device, [], []
        self.running, self.error, self.started, self.stopped = False, None, False, False
        self.polled = []

    def start(self):
        self.running = self.started = True

    def poll(self):
        frame = self.frames.pop(0) if self.frames else None
        if frame is not None:
            self.polled.append(frame)
        return frame

    def set_device_pose(self, position, quaternion):
        import numpy as np

        self.poses_pushed.append((np.array(position), np.array(quaternion)))

    def stop(self):
        self.running, self.stopped = False, True

    def haptic_log(self):
        import numpy as np

        f = self.polled
        return {"t": np.array([x.time for x in f]), "device_position": np.array([x.device_position for x in f]),
                "device_quaternion": np.array([x.device_quaternion for x in f]),
                "force": np.array([x.force for x in f]), "torque": np.array([x.torque for x in f])}


def rig_procedural_armature(context, hand, scale: float = 1.0):
    """The procedural hand's 16 bones as an armature on `hand` (the procedural hand's mesh and
    tets, in a scene of `scale` metres per unit), each bone with its capsule radius, the hand
    skinned to it; chosen in Rig > Skeleton."""
    import numpy as np

    from haptic_hand.blender import armature_build
    from haptic_hand.engine import skeleton as sk

    skeleton = sk.Skeleton([sk.Bone(b.name, b.parent, b.head / scale, b.tail / scale, b.radius)
                            for b in sk.procedural_hand_skeleton().bones])
    obj = armature_build.new_armature(context, skeleton, np.ones(len(skeleton)), hand,
                                      hand.haptic_hand.tet_object)
    context.scene.haptic_hand.armature = obj
    return obj


def key_finger_curl(arm_obj, frames, angle: float, bones=("index_1", "index_2", "middle_1")) -> None:
    """Keys the given pose bones' rotation about their local x from 0 at frames[0] to `angle`
    (rad) at frames[1] (a finger curling, as an animator keys it)."""
    import math

    for name in bones:
        pose = arm_obj.pose.bones[name]
        pose.rotation_mode = "QUATERNION"
        for frame, a in zip(frames, (0.0, angle)):
            pose.rotation_quaternion = (math.cos(a / 2), math.sin(a / 2), 0.0, 0.0)
            pose.keyframe_insert("rotation_quaternion", frame=frame)


def curling_stream(path, seconds: float = 1.0, angle: float = 0.4, layout_name: str = "mano"):
    """A tracking stream (docs/skeleton.md, Section 8) of a hand curling every finger joint by
    `angle` (rad) about the world y axis over `seconds`, the wrist still, at 11 samples;
    written to path (.csv or .json). Returns the stream."""
    import numpy as np

    from haptic_hand.engine import quaternion as quat
    from haptic_hand.engine import tracking

    layout = tracking.LAYOUTS[layout_name]
    times = np.linspace(0.0, seconds, 11)
    n = len(layout.joints)
    turned = [np.tile(quat.from_rotation_vector([0.0, angle * t / seconds, 0.0]), (n, 1)) for t in times]
    for q in turned:
        q[layout.joints.index("wrist")] = [0.0, 0.0, 0.0, 1.0]
    stream = tracking.TrackingStream(layout, times, np.zeros((len(times), n, 3)), np.array(turned),
                                     np.zeros((n, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)))
    tracking.write(path, stream)
    return stream


def build_hand(context, scale: float = 1.0):
    """The procedural hand with its stored tets and a seed at its palm, in a scene whose Blender
    unit is `scale` metres, all settings at their defaults; 30 fps, 60 frames."""
    import bpy
    import numpy as np

    from haptic_hand.blender import meshdata, ops_rig
    from haptic_hand.engine import mesh as meshing

    bscene = context.scene
    bscene.unit_settings.system = "METRIC"
    bscene.unit_settings.scale_length = scale
    bscene.render.fps, bscene.render.fps_base = 30, 1.0
    bscene.frame_start, bscene.frame_end = 1, 61
    stored = np.load(SAMPLES / "procedural_hand_tets.npz")
    v, f = meshing.procedural_hand()
    hand = bpy.data.objects.new("Hand", meshdata.new_mesh("Hand", v / scale, f))
    bscene.collection.objects.link(hand)
    ops_rig.make_tet_object(context, hand, stored["nodes"] / scale, stored["tets"])
    s = bscene.haptic_hand
    s.hand = hand
    hand.haptic_hand.role = "HAND"
    seed = bpy.data.objects.new(ops_rig.SEED_NAME, None)
    bscene.collection.objects.link(seed)
    seed.location = meshing.procedural_hand_palm_seed() / scale
    s.seed = seed
    context.view_layer.update()
    return hand


def bone_motion(scene):
    """The bones' driven poses (centres at their rest heads) at every frame time of a skeleton
    scene (engine.scene.Scene): what skeleton.targets or the tracking stream asks for, (F, B, 7)."""
    import numpy as np

    from haptic_hand.engine import bone_drive

    heads = np.array([b.head for b in scene.skeleton.skeleton.bones])
    drive = bone_drive.BoneDrive(scene.skeleton, heads, None, False)
    return np.array([np.concatenate(drive.animated(k * scene.dt), axis=1) for k in range(scene.frames + 1)])
