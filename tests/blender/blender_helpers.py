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
