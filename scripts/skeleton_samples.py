"""Writes the skeleton sample scenes of addon/engine/sample_scenes/ (docs/skeleton.md, Section 8):

- procedural_hand_close.json: the rigged procedural hand (16 bones) closes its fingers and
  thumb by keyed targets, its fingertips pressing a soft block;
- grasp_ball.json: a soft two-finger hand (palm, thumb, index: gripper.py's, as an explicit
  bone list) closes on a soft ball resting on the ground, lifts it 3 cm and holds it;
- pinch_letter.json: the same hand pinches a soft letter I, gravity off, and holds it.

    .venv/bin/python scripts/skeleton_samples.py [--meshes]

--meshes also writes the meshes the scenes read (two_finger_hand.obj and _tets.npz, ball.obj
and ball_tets.npz); the ball is tetrahedralized by pytetwild, which is not deterministic, so
the stored files are what the scenes replay.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "addon" / "engine" / "sample_scenes"
sys.path.insert(0, str(ROOT / "tests"))
import conftest  # noqa: E402,F401  (maps addon/ to the package haptic_hand)
from haptic_hand.engine import gripper as gr  # noqa: E402
from haptic_hand.engine import mesh  # noqa: E402
from haptic_hand.engine import quaternion as quat  # noqa: E402
from haptic_hand.engine import skeleton as sk  # noqa: E402

FORMAT = "haptic_hand.scene/1"
DT = 1.0 / 30.0
BALL_RADIUS = 0.008   # m: 16 mm across in the 20 mm gap, 2 mm clear of each finger (as the letter I)
GAP = 0.02            # m between the two fingers
SQUEEZE = 0.002       # m each finger presses into the ball past touching it
LIFT = 0.03           # m the palm rises with the ball
# Joint angles (degrees) the procedural hand closes to: each finger 20/20/15 at its three joints,
# the thumb 15/15/10. Beyond about 25 degrees at a knuckle the stored 937-node tets invert
# (docs/skeleton.md, Section 9).
FINGER_CLOSE, THUMB_CLOSE = (20.0, 20.0, 15.0), (15.0, 15.0, 10.0)
HAND_MATERIAL = {"young_modulus": 5e4, "poisson_ratio": 0.3, "density": 1000.0, "rayleigh_alpha": 8.0,
                 "rayleigh_beta": 0.01}


def rounded(values, digits: int = 6) -> list:
    return [round(float(v), digits) for v in values]


# --------------------------------------------------------------------------------------------
# The procedural hand closing
# --------------------------------------------------------------------------------------------


def flexion_axis(skeleton: sk.Skeleton, digit: str) -> np.ndarray:
    """The axis a digit curls about: square to its rest direction, turning it towards -x (the
    side the palm faces)."""
    bone = skeleton.bones[skeleton.index(f"{digit}_1")]
    direction = (bone.tail - bone.head) / np.linalg.norm(bone.tail - bone.head)
    axis = np.cross(direction, [-1.0, 0.0, 0.0])
    return axis / np.linalg.norm(axis)


def curled(skeleton: sk.Skeleton, digit: str, angles) -> dict:
    """Each phalanx's turn from rest (world frame) for its joint angles (degrees), proximal first:
    a phalanx turns by the sum of the angles up to its own joint."""
    axis, total, out = flexion_axis(skeleton, digit), 0.0, {}
    for k, angle in enumerate(angles):
        total += math.radians(angle)
        out[f"{digit}_{k + 1}"] = {"quaternion": rounded(quat.from_rotation_vector(axis * total))}
    return out


def procedural_hand_close() -> dict:
    skeleton = sk.procedural_hand_skeleton()
    closed = {}
    for digit in sk.DIGITS:
        closed.update(curled(skeleton, digit, THUMB_CLOSE if digit == "thumb" else FINGER_CLOSE))
    still = {name: {"quaternion": [0.0, 0.0, 0.0, 1.0]} for name in closed}
    return {"format": FORMAT,
            "hand": {"mesh": "procedural", "tets": "procedural_hand_tets.npz", "skeleton": "procedural"},
            "dt": DT, "frames": 45,
            "skeleton": {"targets": [{"t": 0.0, "bones": still}, {"t": 1.0, "bones": closed}],
                         "drive": {"frequency": 40.0}},
            # a soft block in front of the fingertips, its bottom held: the closing fingers press it
            "bodies": [{"name": "block", "type": "soft", "mesh": "box", "size": [0.04, 0.08, 0.04], "cells": [3, 6, 3],
                        "position": [-0.04, 0.0, -0.17], "fixed": "bottom",
                        "material": {"young_modulus": 2e4, "poisson_ratio": 0.3, "density": 300.0}}]}


# --------------------------------------------------------------------------------------------
# The two-finger hand: grasp and pinch
# --------------------------------------------------------------------------------------------


def two_finger_bones() -> list:
    """gripper.py's bones as a scene's bone list, its fingers named thumb and index."""
    _, _, skeleton = gr.gripper(GAP)
    names = {"palm": "palm", "left": "thumb", "right": "index"}
    return [{"name": names[b.name], "parent": None if b.parent is None else names[b.parent],
             "head": rounded(b.head), "tail": rounded(b.tail), "radius": b.radius} for b in skeleton.bones]


def keyed(times_offsets) -> list:
    """Keys from (t, {bone: head offset}) pairs."""
    return [{"t": round(t, 6), "bones": {name: {"position": rounded(offset)} for name, offset in offsets.items()}}
            for t, offsets in times_offsets]


def two_finger_scene(frames: int, gravity, targets: list, bodies: list) -> dict:
    return {"format": FORMAT,
            "hand": {"mesh": "two_finger_hand.obj", "tets": "two_finger_hand_tets.npz", "skeleton": two_finger_bones(),
                     "friction": 0.8, "self_collision": False},
            "material": HAND_MATERIAL, "springs": {"stiffness": 1e4, "damping": 10.0},
            "dt": DT, "frames": frames, "gravity": gravity,
            "skeleton": {"targets": targets, "drive": {"prescribed": True}},
            "bodies": bodies}


def grasp_ball() -> dict:
    """The fingers close over 1/3 s, the hand rises LIFT over the next 1/2 s, then holds 1.2 s."""
    # the ground 1.5 mm under the fingertips (the contact thickness is 1 mm), the ball on it
    ground = -gr.LENGTH - 0.0015
    centre = [gr.FINGER + GAP / 2, 0.0, ground + 0.0005 + BALL_RADIUS]
    squeeze = GAP / 2 - BALL_RADIUS + SQUEEZE
    open_, closed = {"palm": [0, 0, 0], "thumb": [0, 0, 0], "index": [0, 0, 0]}, \
        {"palm": [0, 0, 0], "thumb": [squeeze, 0, 0], "index": [-squeeze, 0, 0]}
    lifted = {name: np.add(offset, [0, 0, LIFT]) for name, offset in closed.items()}
    targets = keyed([(0.0, open_), (1 / 3, closed), (5 / 6, lifted)])
    bodies = [{"name": "ground", "type": "plane", "point": [0.0, 0.0, round(ground, 6)], "normal": [0, 0, 1],
               "friction": 0.8},
              {"name": "ball", "type": "soft", "mesh": "ball.obj", "tets": "ball_tets.npz", "position": rounded(centre),
               "material": {"young_modulus": 3e4, "poisson_ratio": 0.3, "density": 500.0}, "friction": 0.8}]
    return two_finger_scene(60, [0.0, 0.0, -9.81], targets, bodies)


def pinch_letter() -> dict:
    """Gravity off: each finger moves in 1.5 mm past the letter's face over 1/2 s, then holds 1 s."""
    squeeze = (GAP - 0.016) / 2 + 0.0015  # the letter I is 16 mm wide
    open_ = {"palm": [0, 0, 0], "thumb": [0, 0, 0], "index": [0, 0, 0]}
    closed = {"palm": [0, 0, 0], "thumb": [squeeze, 0, 0], "index": [-squeeze, 0, 0]}
    bodies = [{"name": "letter", "type": "soft", "mesh": "procedural:letter:I",
               "position": [gr.FINGER + GAP / 2, 0.0, -0.045],
               "material": {"young_modulus": 5e4, "poisson_ratio": 0.3, "density": 1000.0}, "friction": 0.8}]
    return two_finger_scene(45, [0.0, 0.0, 0.0], keyed([(0.0, open_), (0.5, closed)]), bodies)


def write_meshes() -> None:
    nodes, tets, _ = gr.gripper(GAP)
    faces = mesh.tet_boundary_faces(tets)
    used = np.unique(faces)
    number = np.full(len(nodes), -1)
    number[used] = np.arange(len(used))
    mesh.save_obj(SAMPLES / "two_finger_hand.obj", nodes[used], number[faces])
    np.savez_compressed(SAMPLES / "two_finger_hand_tets.npz", nodes=nodes, tets=tets)
    import pyvista

    sphere = pyvista.Icosphere(radius=BALL_RADIUS, nsub=2)
    v, f = np.asarray(sphere.points), np.asarray(sphere.faces).reshape(-1, 4)[:, 1:].astype(np.int32)
    ball_nodes, ball_tets = mesh.tetrahedralize(v, f, edge_length_fac=0.5, coarsen=True, epsilon=0.01)
    mesh.save_obj(SAMPLES / "ball.obj", v, f)
    np.savez_compressed(SAMPLES / "ball_tets.npz", nodes=ball_nodes, tets=ball_tets)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--meshes", action="store_true", help="write the meshes too")
    args = parser.parse_args(argv)
    if args.meshes:
        write_meshes()
    for name, scene in (("procedural_hand_close", procedural_hand_close()), ("grasp_ball", grasp_ball()),
                        ("pinch_letter", pinch_letter())):
        (SAMPLES / f"{name}.json").write_text(json.dumps(scene, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
