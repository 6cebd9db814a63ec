"""The sidebar panels draw without errors against a recording layout: every property they
show exists and every button names a registered operator (a typo there would only show up as
a broken panel in a real Blender window); every row of the parameter table kept in Blender is
drawn; docs/blender.md names every control the panel draws, and no other; and its picture of
the panel shows what the panel draws now."""

import importlib.util
import re
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")

from haptic_hand.blender import live, ops_bake, panel, param_props, runtime, scene_export
from haptic_hand.engine import params

from blender_helpers import (FakeSession, draw_panels, labels, open_copy, operators, props,
                             rig_procedural_armature)

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "blender.md"
# emphasised words in docs/blender.md that are Blender's own, not the add-on panel's
BLENDER_NAMES = {"Mesh Cache", "Graph Editor", "Get Extensions", "Install from Disk...", "Shape Keys",
                 "Object Data", "Custom Properties", "File > Import > Haptic Hand Scene (.json)",
                 "Edit > Preferences > Get Extensions > ⌄ > Install from Disk...", "Mesh > Clean Up", "Deform",
                 "Bone Properties", "Inverse Kinematics", "Weight Paint > Weights > Normalize All"}


def test_panels_draw_empty_and_rigged_scenes(addon, built_scenes, tmp_path):
    log = draw_panels(addon)  # nothing authored yet
    assert "haptic_hand.tetrahedralize" in operators(log) and "haptic_hand.bake" in operators(log)

    context = open_copy(built_scenes("bunny_press"), tmp_path)
    bunny = bpy.data.objects["bunny"]
    context.view_layer.objects.active = bunny
    s = context.scene.haptic_hand
    log = draw_panels(context)
    assert f"Handle captures {s.captured_nodes} nodes" in labels(log)
    assert any(text.startswith("bunny: soft") for text in labels(log))
    assert "young_modulus" in props(log)
    # a bake in progress and a finished one change what the Bake section offers
    s.bake_frame_end = 61
    job = ops_bake.prepare(context)
    runtime.state.bake = job.start()
    try:
        log = draw_panels(context)
        assert "haptic_hand.bake_cancel" in operators(log) and "haptic_hand.bake" not in operators(log)
        assert any(kind == "progress" for kind, _, _ in log)
    finally:
        job.cancel()
        assert ops_bake.poll_job(context, job) == "CANCELLED"
    s.bake_frame_end = 3
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
    assert "haptic_hand.free_bake" in operators(draw_panels(context))


def drawn_settings(context) -> set:
    """(the owner's address, property) of every setting the panels draw now."""
    return {(data.id_data.as_pointer(), name) for kind, name, data in draw_panels(context) if kind == "prop"}


def shown(owner, rows) -> set:
    """What drawing these rows of `owner` (an ID) means: each row's property, and the switch of
    a nullable number."""
    out = set()
    for p in rows:
        out.add((owner.as_pointer(), p.name))
        if p.nullable and p.kind in params.NUMERIC_KINDS:
            out.add((owner.as_pointer(), f"use_{p.name}"))
    return out


def test_the_panel_draws_every_row_of_the_parameter_table(addon, built_scenes, tmp_path):
    """Rows reach the panel from the table (a new row needs no panel edit): every scene row, the
    hand's rows with the hand active, each body type's rows with such a body active."""
    context = open_copy(built_scenes("bunny_press"), tmp_path)
    scene, hand = context.scene, context.scene.haptic_hand.hand
    scene_rows = param_props.rows(params.UI_SCENE)
    assert {"drive_frequency", "drive_damping_ratio", "external_timeout", "cg_tolerance"} <= \
        {p.name for p in scene_rows}, "the check reads the table"
    context.view_layer.objects.active = hand
    expected = shown(scene, scene_rows) | shown(hand, param_props.selected(params.UI_OBJECT, prefix="hand."))
    missing = expected - drawn_settings(context)
    for role in ("SOFT", "RIGID", "MOVING", "STATIC", "PLANE"):
        bpy.ops.mesh.primitive_cube_add(size=0.02, location=(0.3, 0.3, 0.3))
        body = context.active_object
        body.haptic_hand.role = role
        rows = list(param_props.selected(params.UI_OBJECT, scene_export.BODY_TYPES[role]))
        assert rows, role
        missing |= shown(body, rows) - drawn_settings(context)
    assert not missing, f"rows the panel does not draw: {sorted(n for _, n in missing)}"


def drawn_names(context) -> tuple[set, set]:
    """The names the panel shows, in the states it can be in: (its controls: the settings' and
    buttons' names and the sections' titles, all of which the docs must name; everything it
    shows: those, the menus' items and the labels)."""
    controls = {cls.bl_label for cls in panel.classes}
    shown = set(controls)
    switches = {f"use_{p.name}" for p in params.table() if p.nullable}  # drawn unlabelled before their value

    def collect():
        for kind, what, extra in draw_panels(context):
            if kind == "prop":
                rna = extra.bl_rna.properties[what]
                if what not in switches:
                    controls.add(rna.name)
                if rna.type == "ENUM":  # its menu's items
                    shown.update(item.name for item in rna.enum_items)
            elif kind == "operator":
                module, name = what.split(".")
                controls.add(extra or getattr(getattr(bpy.ops, module), name).get_rna_type().name)
            elif kind == "label":
                shown.add(what)

    s = context.scene.haptic_hand
    collect()
    for obj in ("bunny", "ground", "Hand"):
        context.view_layer.objects.active = bpy.data.objects[obj]
        collect()
    bpy.ops.mesh.primitive_cube_add(size=0.02, location=(0.3, 0.3, 0.3))
    context.active_object.haptic_hand.role = "RIGID"
    collect()
    for device in ("PLAYBACK", "HID", "TARGET"):
        s.device = device
        collect()
    s.device = "SIMULATED"
    runtime.state.live = live.start(context, session_factory=FakeSession)
    collect()
    runtime.state.stop_all()

    class Running:  # a bake and a tetrahedralization under way, as the panel sees them
        progress, message = 0.4, "frame 12/30"

        def cancel(self):
            pass

        release = cancel

    runtime.state.bake, runtime.state.tetrahedralize = Running(), Running()
    context.view_layer.objects.active = bpy.data.objects["bunny"]
    collect()
    runtime.state.stop_all()
    s.bake_frame_end = 3
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
    collect()
    bpy.ops.haptic_hand.free_bake()
    arm = rig_procedural_armature(context, s.hand)  # a skeleton, its active bone's settings
    arm.data.bones.active = arm.data.bones["index_1"]
    collect()
    return controls, shown | controls


def doc_names() -> set:
    """The names docs/blender.md puts in bold (buttons, sections) or italics (settings), and the
    sections its table of the panel lists; code left out."""
    text = re.sub(r"```.*?```", "", DOC.read_text(), flags=re.S)
    text = re.sub(r"`[^`]*`", "", text)
    bold = re.findall(r"\*\*([^*]+?)\*\*", text)
    italic = re.findall(r"(?<![*\w])\*([^*\s][^*]*?)\*(?![*\w])", re.sub(r"\*\*[^*]+?\*\*", "", text))
    sections = re.findall(r"^\| ([^|*]+?) \|", text, flags=re.M)  # the first column of the panel's table
    return {" ".join(n.split()) for n in bold + italic + sections} - {"section"}


def test_docs_name_what_the_panel_draws_and_nothing_else(addon, built_scenes, tmp_path):
    context = open_copy(built_scenes("bunny_press"), tmp_path)
    controls, shown = drawn_names(context)
    named = doc_names()
    assert {"Tetrahedralize", "Haptic loop", "Bake Recording", "Record", "Confirm above"} <= named, \
        "the check reads the docs' names"
    assert {"Bone drive frequency", "External timeout", "Check Rig"} <= controls, "the check reads the panel's"
    missing = sorted(n for n in named - BLENDER_NAMES if n not in shown)
    assert not missing, f"docs/blender.md names controls the panel does not draw: {missing}"
    unnamed = sorted(controls - named)
    assert not unnamed, f"the panel draws controls docs/blender.md does not name: {unnamed}"
    # and the docs' table of the panel has a row for every section of the tab
    for cls in panel.classes:
        if getattr(cls, "bl_parent_id", "") == "HAPTIC_HAND_PT_main":
            assert f"| {cls.bl_label} |" in DOC.read_text(), cls.bl_label


def test_the_panel_picture_shows_what_the_panel_draws_now(addon, built_scenes, tmp_path):
    """blender_scenes/docs_images.py saves the rows it drew beside docs/images/blender_panel.png;
    the panel drawn the same way now (the bunny scene, the bunny selected) must give that list."""
    spec = importlib.util.spec_from_file_location("docs_images", ROOT / "blender_scenes" / "docs_images.py")
    docs_images = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(docs_images)
    context = open_copy(built_scenes("bunny_press"), tmp_path)
    context.view_layer.objects.active = bpy.data.objects["bunny"]
    now = docs_images.listing(docs_images.draw_sections(context))
    assert "External timeout" in now and "Bone drive frequency" in now, "the listing reads the panel"
    saved = (ROOT / "docs" / "images" / "blender_panel.txt").read_text()
    assert now == saved, ("docs/images/blender_panel.png is stale: `.venv/bin/python blender_scenes/docs_images.py "
                          "--only panel` draws it again")

