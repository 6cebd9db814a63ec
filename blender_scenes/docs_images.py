"""The pictures of docs/blender.md, rendered headless with Workbench:

    .venv/bin/python blender_scenes/docs_images.py [--out docs/images]

blender_rig.png: the hand see-through, its tets as wires, the handle sphere around the palm
seed; blender_bake.png: frames of a bake of the bunny scene side by side (the hand at rest,
pressing, stroking). Each is a render of the .blend the scripts build, not a mock-up.
"""

from __future__ import annotations

import argparse
import pathlib
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


def bake_picture(out: pathlib.Path, work: pathlib.Path, frames=(1, 31, 76)) -> None:
    import bpy
    from PIL import Image

    common.build("bunny", work / "bake.blend", resolution=(480, 400))
    scene = bpy.context.scene
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
    strip.save(out / "blender_bake.png", optimize=True)
    print(f"wrote {out / 'blender_bake.png'}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=str(common.ROOT / "docs" / "images"))
    args = parser.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    haptic_hand = common.import_addon()
    haptic_hand.register()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            rig_picture(out, pathlib.Path(tmp))
            bake_picture(out, pathlib.Path(tmp))
    finally:
        haptic_hand.unregister()
    return 0


if __name__ == "__main__":
    sys.exit(main())
