"""The pictures of docs/blender.md, rendered headless with Workbench:

    .venv/bin/python blender_scenes/docs_images.py [--out docs/images]

blender_rig.png: the hand see-through, its tets as wires, the handle sphere around the palm
seed; blender_bake.png: frames of a bake of the bunny scene side by side (the hand at rest,
pressing, stroking); blender_grasp.png: frames of a bake of the rigged grasping hand
(hand_grasp: open, closed on the ball, holding it lifted, open again). Each is a render of the .blend the scripts build, not a mock-up.
blender_panel.png: the Haptic Hand tab as its own draw code lays it out for the bunny scene with
the bunny selected (headless Blender draws no UI, so the panels draw into a recording layout
and matplotlib paints what they drew); blender_panel.txt beside it lists what it shows, so a
test (tests/blender/test_panel.py) finds the picture stale when the panel draws otherwise.

    .venv/bin/python blender_scenes/docs_images.py --only panel     # that picture alone
"""

from __future__ import annotations

import argparse
import pathlib
import re
import sys
import tempfile

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import common  # noqa: E402


def render(scene, path: pathlib.Path) -> None:
    import bpy

    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    print(f"wrote {path}")


def rig_picture(out: pathlib.Path, work: pathlib.Path) -> None:
    import bpy

    objects = common.build("bunny", work / "rig.blend", resolution=(800, 450))
    scene = bpy.context.scene
    s = scene.haptic_hand
    hand, tets = objects["hand"], objects["hand"].haptic_hand.tet_object
    for name in ("bunny", "ground"):
        objects[name].hide_render = True
    # tets as wires (a Wireframe modifier on the tet object), the hand see-through
    tets.hide_render = False
    tets.hide_select = False
    mod = tets.modifiers.new("wires", "WIREFRAME")
    mod.thickness = 0.0008
    tets.color = (0.05, 0.1, 0.3, 1.0)
    hand.color = (0.85, 0.62, 0.5, 0.35)
    scene.display.shading.show_xray = True
    scene.display.shading.xray_alpha = 0.4
    # the handle sphere
    bpy.ops.mesh.primitive_uv_sphere_add(radius=s.handle_radius, location=s.seed.matrix_world.translation,
                                         segments=32, ring_count=16)  # handle_radius is in the scene's units
    sphere = bpy.context.active_object
    sphere.color = (0.2, 0.85, 0.3, 1.0)
    cam = scene.camera
    centre = np.array(hand.matrix_world.translation) + np.array([0.0, 0.0, -0.07])
    import mathutils

    cam.location = mathutils.Vector(centre) + mathutils.Vector((-0.33, -0.2, 0.08))
    cam.rotation_euler = (mathutils.Vector(centre) - cam.location).to_track_quat("-Z", "Y").to_euler()
    render(scene, out / "blender_rig.png")


def bake_picture(out: pathlib.Path, work: pathlib.Path, name="bunny", frames=(1, 31, 76),
                 picture="blender_bake.png", camera=None) -> None:
    """Frames of a bake of the sample scene `name` side by side (camera: a function that places
    the scene's camera, given the built objects)."""
    import bpy
    from PIL import Image

    objects = common.build(name, work / f"{name}.blend", resolution=(480, 400))
    scene = bpy.context.scene
    if camera:
        camera(scene.camera, objects)
    s = scene.haptic_hand
    s.bake_frame_end = max(frames)
    assert bpy.ops.haptic_hand.bake() == {"FINISHED"}
    tiles = []
    for f in frames:
        scene.frame_set(f)
        path = work / f"frame_{f}.png"
        render(scene, path)
        tiles.append(Image.open(path).convert("RGB"))
    strip = Image.new("RGB", (sum(t.width for t in tiles), tiles[0].height))
    x = 0
    for t in tiles:
        strip.paste(t, (x, 0))
        x += t.width
    strip.save(out / picture, optimize=True)
    print(f"wrote {out / picture}")


VIEW_GRASP = (0.70, -0.71, -0.4)  # the grasp's camera: from the palm's side, a little towards the fingertips


def grasp_picture(out: pathlib.Path, work: pathlib.Path) -> None:
    """The rigged grasping hand's bake: open, closed on the ball, holding it lifted, opened;
    seen square to gravity, whose up is the picture's (the scene's gravity lies the hand on its
    thumb side, docs/skeleton.md 9)."""
    import bpy
    import mathutils

    def square_to_gravity(cam, objects):
        up = -mathutils.Vector(bpy.context.scene.gravity).normalized()
        look = mathutils.Vector(VIEW_GRASP).normalized()
        look = (look - look.dot(up) * up).normalized()
        ball = objects["ball"]
        centre = ball.matrix_world @ (sum((v.co for v in ball.data.vertices), mathutils.Vector()) / len(ball.data.vertices))
        centre += 0.02 * up + 0.045 * mathutils.Vector((0.0, 0.0, 1.0))  # the lift and the palm in view
        back = -look
        cam.matrix_world = mathutils.Matrix.Translation(centre + 0.27 * back) @ mathutils.Matrix(
            (up.cross(back), up, back)).transposed().to_4x4()

    bake_picture(out, work, "hand_grasp", (1, 21, 60, 121), "blender_grasp.png", square_to_gravity)


class PanelRecorder:
    """Stands in for bpy.types.UILayout: keeps each row the panels draw, in order."""

    def __init__(self, rows, depth=0):
        self.rows, self.depth, self.active = rows, depth, True

    def row(self, *args, **kwargs):
        return PanelRecorder(self.rows, self.depth)

    column = split = grid_flow = row

    def box(self, *args, **kwargs):
        return PanelRecorder(self.rows, self.depth + 1)

    def prop(self, data, name, text=None, **kwargs):
        rna = data.bl_rna.properties[name]
        value = getattr(data, name)
        if rna.type == "ENUM":
            shown = next((i.name for i in rna.enum_items if i.identifier == value), str(value))
        elif rna.type == "BOOLEAN":
            shown = "[x]" if value else "[ ]"
        elif rna.type == "POINTER":
            shown = value.name if value is not None else "-"
        elif rna.type == "FLOAT":
            shown = f"{value:.4g}" + (" m" if rna.unit == "LENGTH" else "")
        else:
            shown = str(value) if value != "" else "-"
        if self.rows and self.rows[-1][1] == "switch":  # an unlabelled switch before its value, on one row
            shown = f"{self.rows.pop()[3]} {shown}"
        kind = "switch" if text == "" and rna.type == "BOOLEAN" else "prop"
        self.rows.append((self.depth, kind, rna.name if text is None else text, shown))

    def operator(self, idname, text=None, **kwargs):
        import bpy

        module, name = idname.split(".")
        label = text or getattr(getattr(bpy.ops, module), name).get_rna_type().name
        self.rows.append((self.depth, "button", label, ""))

        class Props:
            pass
        return Props()

    def label(self, text="", **kwargs):
        self.rows.append((self.depth, "label", text, ""))

    def progress(self, factor=0.0, text="", **kwargs):
        self.rows.append((self.depth, "label", text, ""))

    def separator(self, **kwargs):
        pass


def draw_sections(context) -> list[tuple[str, str, list]]:
    """What each panel of the tab draws now: (title, parent panel, rows)."""
    from haptic_hand.blender import panel

    sections = []
    for cls in panel.classes:
        rows = []

        class Fake:
            layout = PanelRecorder(rows)
        cls.draw(Fake(), context)
        sections.append((cls.bl_label, getattr(cls, "bl_parent_id", ""), rows))
    return sections


def listing(sections) -> str:
    """The picture's sections and rows as text, numbers masked (the bunny's tets, and so some
    counts, differ from build to build)."""
    lines = []
    for title, _, rows in sections:
        lines.append(title)
        lines += [f"{'  ' * (depth + 1)}{kind}: {re.sub(r'[0-9]+([.][0-9]+)?', '#', label)}"
                  for depth, kind, label, _ in rows]
    return "\n".join(lines) + "\n"


def panel_picture(out: pathlib.Path, work: pathlib.Path) -> None:
    import bpy
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    objects = common.build("bunny", work / "panel.blend")
    bpy.context.view_layer.objects.active = objects["bunny"]
    sections = draw_sections(bpy.context)
    (out / "blender_panel.txt").write_text(listing(sections))
    # in rows of the picture: a first margin, then each section's title (1.4), rows (1 each), gap (0.4)
    units = 1.0 + sum(len(rows) + 1.8 for _, _, rows in sections)
    fig = plt.figure(figsize=(4.6, units * 0.2), dpi=110)
    fig.patch.set_facecolor("#303030")
    ax = fig.add_axes([0, 0, 1, 1])
    ax.set_xlim(0, 46)
    ax.set_ylim(-units, 0)
    ax.axis("off")
    y = -1.0
    text = dict(color="#e6e6e6", fontsize=7.5, va="center", family="DejaVu Sans")
    for title, parent, rows in sections:
        indent = 1.5 if parent and parent != "HAPTIC_HAND_PT_main" else 0.5
        ax.add_patch(plt.Rectangle((indent, y - 0.6), 45.5 - indent, 1.2, color="#3d3d3d"))
        ax.text(indent + 0.6, y, "v  " + title, fontweight="bold", **text)
        y -= 1.4
        for depth, kind, label, value in rows:
            x = indent + 1.0 + 1.2 * depth
            if kind == "button":
                ax.add_patch(plt.Rectangle((x, y - 0.5), 44.5 - x, 1.0, color="#545454"))
                ax.text((x + 44.5) / 2, y, label, ha="center", **text)
            elif kind == "prop":
                ax.text(x, y, label, **text)
                ax.add_patch(plt.Rectangle((24, y - 0.5), 20.5, 1.0, color="#1d1d1d"))
                ax.text(24.5, y, value, **text)
            else:
                ax.text(x, y, label, **dict(text, color="#b0b0b0"))
            y -= 1.0
        y -= 0.4
    fig.savefig(out / "blender_panel.png", facecolor=fig.get_facecolor())
    plt.close(fig)
    print(f"wrote {out / 'blender_panel.png'}")


PICTURES = {"rig": rig_picture, "bake": bake_picture, "grasp": grasp_picture, "panel": panel_picture}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=str(common.ROOT / "docs" / "images"))
    parser.add_argument("--only", choices=sorted(PICTURES), action="append", help="these pictures alone")
    args = parser.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    haptic_hand = common.import_addon()
    haptic_hand.register()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for name in args.only or PICTURES:
                PICTURES[name](out, pathlib.Path(tmp))
    finally:
        haptic_hand.unregister()
    return 0


if __name__ == "__main__":
    sys.exit(main())
