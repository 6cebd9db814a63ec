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
