"""Writes the skeleton sample scenes of addon/engine/sample_scenes/ (docs/skeleton.md, Section 8):

- procedural_hand_close.json: the rigged procedural hand (16 bones) closes its fingers and
  thumb by keyed targets, its fingertips pressing a soft block;
- grasp_ball.json: a soft two-finger hand (palm, thumb, index: gripper.py's, as an explicit
  bone list) closes on a soft ball resting on the ground, lifts it 3 cm and holds it;
- pinch_letter.json: the same hand pinches a soft letter I, gravity off, and holds it;
- pinch_letter_hand.json: the grasping hand (16 bones, docs/skeleton.md Section 9) bends its
  index finger and thumb onto a small soft letter I between their pads, gravity off;
- grasp_ball_hand.json: the grasping hand closes its index finger and thumb on a soft 4 cm ball
  on the ground, lifts it 3 cm, holds it 2 s by friction (gravity square to the squeeze) and
  opens, dropping it.

    .venv/bin/python scripts/skeleton_samples.py [--meshes]

--meshes also writes the meshes the scenes read (two_finger_hand.obj and _tets.npz, ball.obj
and ball_tets.npz, grasping_hand.obj and _tets.npz, pinch_letter_I.obj and _tets.npz, hand_ball.obj
and _tets.npz); the balls and the grasping hand are tetrahedralized by pytetwild, which is not deterministic, so the
stored files are what the scenes replay.
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
    return curled_about(flexion_axis(skeleton, digit), digit, angles)


def curled_about(axis, digit: str, angles) -> dict:
    """curled()'s turns about a given axis."""
    total, out = 0.0, {}
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


# --------------------------------------------------------------------------------------------
# The grasping hand (16 bones): pinch
# --------------------------------------------------------------------------------------------

# The pinch pose (degrees at each joint, proximal first): the capsules of the index finger's and
# the thumb's last phalanges 1.9 mm apart, so each pad presses about 3 mm into the 8 mm letter.
PINCH_INDEX, PINCH_THUMB = (24.0, 24.0, 14.0), (16.0, 16.0, 10.0)
PINCH_LETTER = (0.016, 0.008)  # m: the letter I's height and its depth (between the pads)
# Tet edge lengths (m) of the grasping hand: 6.5 mm in the digits, 20 mm deep in the palm.
GRASPING_EDGE, GRASPING_PALM_EDGE = 0.0065, 0.02


def thumb_axis(skeleton: sk.Skeleton) -> np.ndarray:
    """The axis the grasping thumb curls about: square to it, turning it towards the index tip."""
    thumb, index = skeleton.bones[skeleton.index("thumb_1")], skeleton.bones[skeleton.index("index_3")]
    axis = np.cross(thumb.tail - thumb.head, index.tail - thumb.head)
    return axis / np.linalg.norm(axis)


def posed_digit(skeleton: sk.Skeleton, digit: str, axis, angles) -> list:
    """(head, tail) of a digit's three bones curled by `angles` about `axis` (as curled())."""
    bones = [skeleton.bones[skeleton.index(f"{digit}_{k}")] for k in (1, 2, 3)]
    head, total, out = bones[0].head, 0.0, []
    for bone, angle in zip(bones, angles):
        total += math.radians(angle)
        tail = head + quat.to_matrix(quat.from_rotation_vector(axis * total)) @ (bone.tail - bone.head)
        out.append((head, tail))
        head = tail
    return out


def closest_points(a0, a1, b0, b1, samples: int = 401):
    """The closest points of two segments (sampled along the first)."""
    a = a0 + np.linspace(0, 1, samples)[:, None] * (a1 - a0)
    t = np.clip((a - b0) @ (b1 - b0) / ((b1 - b0) @ (b1 - b0)), 0, 1)
    b = b0 + t[:, None] * (b1 - b0)
    k = np.argmin(np.linalg.norm(a - b, axis=1))
    return a[k], b[k]


def pinch_frame(skeleton: sk.Skeleton):
    """Where the letter goes: the midpoint of the two pads at the pinch pose, the direction from
    the index pad to the thumb's (n) and the index's last phalanx's direction square to it (h)."""
    index = posed_digit(skeleton, "index", flexion_axis(skeleton, "index"), PINCH_INDEX)[2]
    thumb = posed_digit(skeleton, "thumb", thumb_axis(skeleton), PINCH_THUMB)[2]
    on_thumb, on_index = closest_points(*thumb, *index)
    n = (on_thumb - on_index) / np.linalg.norm(on_thumb - on_index)
    centre = 0.5 * ((on_index + n * digit_radius(skeleton, "index")) + (on_thumb - n * digit_radius(skeleton, "thumb")))
    u = index[1] - index[0]
    h = u - (u @ n) * n
    return centre, n, h / np.linalg.norm(h)


def pinch_letter_mesh():
    """The letter I, PINCH_LETTER tall and deep, centred on the origin, its depth along the pinch
    direction and its height along the index's last phalanx (its nodes, tets and surface)."""
    from haptic_hand.engine import shapes

    height, depth = PINCH_LETTER
    _, n, h = pinch_frame(sk.grasping_hand_skeleton())
    turn = np.column_stack([np.cross(n, h), n, h])  # the letter's x, y (depth), z (height) in the world
    v, f = shapes.procedural_letter("I", height=height, depth=depth)
    nodes, tets = shapes.letter_tets("I", height=height, depth=depth)
    middle = np.array([0.0, 0.0, height / 2])
    return (nodes - middle) @ turn.T, tets, (v - middle) @ turn.T, f


# The grasping hand's solver: its 2078 nodes are over the size where an earlier step's factor,
# preconditioning CG, costs less than a factor every step, and with every bone prescribed its
# contact responses come from the blocks that factor keeps (docs/skeleton.md, Section 9)
GRASPING_HAND_SOLVER = {"name": "reused_cholesky"}


def pinch_letter_hand() -> dict:
    """Gravity off: the index finger and the thumb bend to the pinch pose over 1/2 s, then hold 1 s."""
    skeleton = sk.grasping_hand_skeleton()
    centre, _, _ = pinch_frame(skeleton)
    closed = {**curled(skeleton, "index", PINCH_INDEX), **curled_about(thumb_axis(skeleton), "thumb", PINCH_THUMB)}
    still = {name: {"quaternion": [0.0, 0.0, 0.0, 1.0]} for name in closed}
    bones = grasping_bones(skeleton)
    letter = {"name": "letter", "type": "soft", "mesh": "pinch_letter_I.obj", "tets": "pinch_letter_I_tets.npz",
              "position": rounded(centre), "material": {"young_modulus": 5e4, "poisson_ratio": 0.3, "density": 1000.0},
              "friction": 0.8}
    return {"format": FORMAT,
            "hand": {"mesh": "grasping_hand.obj", "tets": "grasping_hand_tets.npz", "skeleton": bones,
                     "friction": 0.8, "self_collision": False},
            "material": HAND_MATERIAL, "springs": {"stiffness": 1e4, "damping": 10.0},
            "solver": GRASPING_HAND_SOLVER, "dt": DT, "frames": 45, "gravity": [0.0, 0.0, 0.0],
            "skeleton": {"targets": [{"t": 0.0, "bones": still}, {"t": 0.5, "bones": closed}],
                         "drive": {"prescribed": True}},
            "bodies": [letter]}


# --------------------------------------------------------------------------------------------
# The grasping hand (16 bones): ball grasp
# --------------------------------------------------------------------------------------------

HAND_BALL_RADIUS = 0.02  # m: a 4 cm soft ball
# The pose (degrees, proximal first) at which the index finger's last phalanx and the thumb's
# touch a ball HAND_BALL_RADIUS across set between them (their axes 46 mm apart less the two
# digits' radii: the ball clears the open hand by 3 mm); the grasp bends both GRASP_SQUEEZE
# further at each joint, each pad moving about 5 mm into the ball.
GRASP_INDEX, GRASP_THUMB, GRASP_SQUEEZE = (10.0, 10.0, 5.0), (0.0, 0.0, 0.0), 4.0
# Keyed times (s): closed by, lift starts, lifted by, opening starts, open by; the end
GRASP_TIMES, GRASP_END = (0.5, 0.7, 1.2, 3.2, 3.5), 4.0


def digit_radius(skeleton: sk.Skeleton, digit: str) -> float:
    """The digit's own radius (its bones' capsules are sk.GRASPING_BONE_RADIUS of it)."""
    return skeleton.bones[skeleton.index(f"{digit}_3")].radius / sk.GRASPING_BONE_RADIUS


def squeezed(angles) -> tuple:
    return tuple(a + GRASP_SQUEEZE for a in angles)


def ball_grasp_frame(skeleton: sk.Skeleton, hand_nodes):
    """Where the ball goes and which way is up: the ball's centre midway between the index's
    and the thumb's last phalanges at the touch pose (n: from the index pad to the thumb's), and
    `up` square to n (so the squeeze cannot hold the ball's weight: friction must), turned about
    n so that the hand at rest and its digits at the grasp pose stand highest above the ground
    under the ball."""
    index = posed_digit(skeleton, "index", flexion_axis(skeleton, "index"), GRASP_INDEX)[2]
    thumb = posed_digit(skeleton, "thumb", thumb_axis(skeleton), GRASP_THUMB)[2]
    on_thumb, on_index = closest_points(*thumb, *index)
    n = (on_thumb - on_index) / np.linalg.norm(on_thumb - on_index)
    centre = 0.5 * ((on_index + n * digit_radius(skeleton, "index")) + (on_thumb - n * digit_radius(skeleton, "thumb")))
    digits = [(d, posed_digit(skeleton, d, thumb_axis(skeleton) if d == "thumb" else flexion_axis(skeleton, d),
                              squeezed(GRASP_THUMB if d == "thumb" else GRASP_INDEX) if d in ("index", "thumb")
                              else (0.0, 0.0, 0.0))) for d in sk.DIGITS]

    def clearance(up):
        ground = centre @ up - HAND_BALL_RADIUS
        lowest = [min(min(p @ up for p in bone) for bone in bones) - digit_radius(skeleton, d) for d, bones in digits]
        return min([(hand_nodes @ up).min()] + lowest) - ground

    e1 = np.cross(n, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    ups = [math.cos(a) * e1 + math.sin(a) * np.cross(n, e1) for a in np.radians(np.arange(360))]
    return centre, n, max(ups, key=clearance)


def grasp_ball_hand() -> dict:
    """Gravity square to the squeeze: the index finger and the thumb close on the ball over 1/2 s,
    the palm lifts it LIFT over the next 1/2 s (after 0.2 s still), holds it 2 s, then the fingers
    open over 0.3 s and the ball drops."""
    skeleton = sk.grasping_hand_skeleton()
    nodes = np.load(SAMPLES / "grasping_hand_tets.npz")["nodes"]
    centre, _, up = ball_grasp_frame(skeleton, nodes)
    closed = {**curled(skeleton, "index", squeezed(GRASP_INDEX)),
              **curled_about(thumb_axis(skeleton), "thumb", squeezed(GRASP_THUMB))}
    open_ = {name: {"quaternion": [0.0, 0.0, 0.0, 1.0]} for name in closed}

    def key(t, bones, lift):
        return {"t": t, "bones": {**bones, "palm": {"position": rounded(up * lift)}}}

    t_closed, t_lift, t_lifted, t_open, t_opened = GRASP_TIMES
    targets = [key(0.0, open_, 0.0), key(t_closed, closed, 0.0), key(t_lift, closed, 0.0),
               key(t_lifted, closed, LIFT), key(t_open, closed, LIFT), key(t_opened, open_, LIFT)]
    ground = centre @ up - HAND_BALL_RADIUS - 0.0005  # the ball 0.5 mm into the 1 mm contact thickness
    bodies = [{"name": "ground", "type": "plane", "point": rounded(up * ground), "normal": rounded(up),
               "friction": 0.8},
              {"name": "ball", "type": "soft", "mesh": "hand_ball.obj", "tets": "hand_ball_tets.npz",
               "position": rounded(centre), "material": {"young_modulus": 3e4, "poisson_ratio": 0.3, "density": 500.0},
               "friction": 0.8}]
    return {"format": FORMAT,
            "hand": {"mesh": "grasping_hand.obj", "tets": "grasping_hand_tets.npz", "skeleton": grasping_bones(skeleton),
                     "friction": 0.8, "self_collision": False},
            "material": HAND_MATERIAL, "springs": {"stiffness": 1e4, "damping": 10.0},
            "solver": GRASPING_HAND_SOLVER, "dt": DT, "frames": round(GRASP_END / DT), "gravity": rounded(-9.81 * up),
            "skeleton": {"targets": targets, "drive": {"prescribed": True}},
            "bodies": bodies}


def grasping_bones(skeleton: sk.Skeleton) -> list:
    return [{"name": b.name, "parent": b.parent, "head": rounded(b.head), "tail": rounded(b.tail),
             "radius": round(b.radius, 6)} for b in skeleton.bones]


def ball_mesh(radius: float):
    """A soft ball of `radius`: an icosphere's surface, pytetwild's tets."""
    import pyvista

    sphere = pyvista.Icosphere(radius=radius, nsub=2)
    v, f = np.asarray(sphere.points), np.asarray(sphere.faces).reshape(-1, 4)[:, 1:].astype(np.int32)
    nodes, tets = mesh.tetrahedralize(v, f, edge_length_fac=0.5, coarsen=True, epsilon=0.01)
    return v, f, nodes, tets


def grasping_hand_tets():
    """The grasping hand's tets by pytetwild with a sizing field: GRASPING_EDGE outside the palm
    slab (the digits, where the joints bend), growing to GRASPING_PALM_EDGE 8 mm inside it."""
    v, f = mesh.procedural_hand(thumb=mesh.GRASPING_THUMB)
    lower, upper = v.min(axis=0) - 0.01, v.max(axis=0) + 0.01
    background, background_tets = mesh.structured_box(upper - lower, np.ceil((upper - lower) / 0.004).astype(int),
                                                      lower)
    depth = -mesh._rounded_box_distance(background, mesh._PALM_CENTRE, mesh._PALM_HALF_EXTENTS, mesh._PALM_ROUNDING)
    edge = GRASPING_EDGE + np.clip(depth / 0.008, 0, 1) * (GRASPING_PALM_EDGE - GRASPING_EDGE)
    nodes, tets = mesh.tetrahedralize(v, f, edge_length_fac=0.05, coarsen=False, epsilon=0.002,
                                      sizing=(background, background_tets, edge))
    return v, f, nodes, tets


def write_meshes() -> None:
    nodes, tets, _ = gr.gripper(GAP)
    faces = mesh.tet_boundary_faces(tets)
    used = np.unique(faces)
    number = np.full(len(nodes), -1)
    number[used] = np.arange(len(used))
    mesh.save_obj(SAMPLES / "two_finger_hand.obj", nodes[used], number[faces])
    np.savez_compressed(SAMPLES / "two_finger_hand_tets.npz", nodes=nodes, tets=tets)
    v, f, ball_nodes, ball_tets = ball_mesh(BALL_RADIUS)
    mesh.save_obj(SAMPLES / "ball.obj", v, f)
    np.savez_compressed(SAMPLES / "ball_tets.npz", nodes=ball_nodes, tets=ball_tets)
    v, f, nodes, tets = grasping_hand_tets()
    mesh.save_obj(SAMPLES / "grasping_hand.obj", v, f)
    np.savez_compressed(SAMPLES / "grasping_hand_tets.npz", nodes=nodes, tets=tets)
    nodes, tets, v, f = pinch_letter_mesh()
    mesh.save_obj(SAMPLES / "pinch_letter_I.obj", v, f)
    np.savez_compressed(SAMPLES / "pinch_letter_I_tets.npz", nodes=nodes, tets=tets)
    write_hand_ball()


def write_hand_ball() -> None:
    v, f, nodes, tets = ball_mesh(HAND_BALL_RADIUS)
    mesh.save_obj(SAMPLES / "hand_ball.obj", v, f)
    np.savez_compressed(SAMPLES / "hand_ball_tets.npz", nodes=nodes, tets=tets)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--meshes", action="store_true", help="write the meshes too")
    args = parser.parse_args(argv)
    if args.meshes:
        write_meshes()
    for name, scene in (("procedural_hand_close", procedural_hand_close()), ("grasp_ball", grasp_ball()),
                        ("pinch_letter", pinch_letter()), ("pinch_letter_hand", pinch_letter_hand()),
                        ("grasp_ball_hand", grasp_ball_hand())):
        (SAMPLES / f"{name}.json").write_text(json.dumps(scene, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
