"""The sidebar panels draw without errors against a recording layout: every property they
show exists and every button names a registered operator (a typo there would only show up as
a broken panel in a real Blender window)."""

import pytest

bpy = pytest.importorskip("bpy")

from blender_helpers import open_copy


class Recorder:
    """Stands in for bpy.types.UILayout: checks and records what a panel draws."""

    def __init__(self, log):
        self.log = log

    def _child(self, *args, **kwargs):
        return Recorder(self.log)

    row = column = box = grid_flow = split = _child

    def prop(self, data, name, **kwargs):
        assert name in data.bl_rna.properties, f"{type(data).__name__} has no property '{name}'"
        self.log.append(("prop", name))

    def operator(self, idname, **kwargs):
        module, name = idname.split(".")
        assert name in dir(getattr(bpy.ops, module)), f"operator {idname} is not registered"
        self.log.append(("operator", idname))

        class Props:
            pass
        return Props()

    def label(self, text="", **kwargs):
        self.log.append(("label", text))

    def separator(self, **kwargs):
        pass

    def progress(self, **kwargs):
        self.log.append(("progress", kwargs.get("factor")))


class FakePanel:
    def __init__(self, log):
        self.layout = Recorder(log)


def draw_all(context):
    from haptic_hand.blender import panel

    log = []
    for cls in panel.classes:
        cls.draw(FakePanel(log), context)
    return log


def test_panels_draw_empty_and_rigged_scenes(addon, built_scenes, tmp_path):
    log = draw_all(addon)  # nothing authored yet
    assert ("operator", "haptic_hand.tetrahedralize") in log and ("operator", "haptic_hand.bake") in log

    context = open_copy(built_scenes("bunny_press"), tmp_path)
    bunny = bpy.data.objects["bunny"]
    context.view_layer.objects.active = bunny
    s = context.scene.haptic_hand
    log = draw_all(context)
    labels = [text for kind, text in log if kind == "label"]
    assert f"Handle captures {s.captured_nodes} nodes" in labels
    assert any(text.startswith("bunny: soft") for text in labels)
    assert ("prop", "young_modulus") in log
    # a bake in progress and a finished one change what the Bake section offers
    s.bake_running, s.bake_progress = True, 0.4
    assert ("operator", "haptic_hand.bake_cancel") in draw_all(context)
    s.bake_running = False
    s.bake_frame_end = 3
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
    assert ("operator", "haptic_hand.free_bake") in draw_all(context)
