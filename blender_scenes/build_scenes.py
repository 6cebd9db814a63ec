"""Build the sample .blend scenes from the engine's sample scenes (procedural hand with its
stored tets, procedural bunny and letters, boxes): hand + soft bunny on the ground, hand +
soft letters, fingers squeezed between two moving pads, and the rigged hands, armatures of 16
bones (engine/skeleton.py) whose actions close the procedural hand's fingers onto a soft block
(procedural_hand_close.json), lift a soft ball with the grasping hand (grasp_ball_hand.json)
and pinch a soft letter with it (pinch_letter_hand.json).

    .venv/bin/python blender_scenes/build_scenes.py [bunny letters fingers hand_close hand_grasp hand_pinch] [--out DIR]

Writes DIR/<name>.blend (default DIR: blender_scenes/), and for the rigged hand_close also its
export, DIR/hand_close/scene.json with its meshes (common.EXPORTED): the scene a bake of the .blend simulates,
which the command line runs too. The bunny's coarse tets are made by pytetwild when the scene
is built (not deterministic) and stored in the .blend, so every bake of one .blend gives the
same result.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import common  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("names", nargs="*", help=f"scenes to build: {', '.join(common.SCENES)} (default: all)")
    parser.add_argument("--out", default=str(pathlib.Path(__file__).resolve().parent))
    args = parser.parse_args(argv)
    unknown = [n for n in args.names if n not in common.SCENES]
    if unknown:
        parser.error(f"unknown scene(s) {', '.join(unknown)}: choose from {', '.join(common.SCENES)}")
    haptic_hand = common.import_addon()
    haptic_hand.register()
    try:
        for name in args.names or common.SCENES:
            path = pathlib.Path(args.out) / f"{name}.blend"
            objects = common.build(name, path)
            print(f"{name}: {path} ({path.stat().st_size / 1e6:.1f} MB)")
            if name in common.EXPORTED:
                common.export(pathlib.Path(args.out) / name)
                print(f"{name}: its export in {pathlib.Path(args.out) / name}/scene.json")
    finally:
        haptic_hand.unregister()
    return 0


if __name__ == "__main__":
    sys.exit(main())
