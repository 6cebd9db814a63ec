"""Bad input gets a clear error that names the problem (and the fix), never a crash."""

import math

import numpy as np
import pytest

from haptic_hand.engine import mesh, native


def make(rig, **params):
    base = dict(palm_seed=rig.seed, handle_radius=rig.radius)
    base.update(params)
    return native.HandModel(rig.nodes, rig.tets, **base)


def test_open_mesh_is_refused_before_tetrahedralizing():
    v, f = mesh.procedural_hand()
    with pytest.raises(mesh.MeshError, match="open"):
        mesh.tetrahedralize(v, f[1:])


def test_inverted_tet_is_named(procedural_rig):
    tets = procedural_rig.tets.copy()
    tets[17] = tets[17][[0, 2, 1, 3]]
    with pytest.raises(native.InvalidInput, match=r"tetrahedron 17 .*inverted"):
        native.HandModel(procedural_rig.nodes, tets, palm_seed=procedural_rig.seed, handle_radius=0.03)


def test_zero_volume_tet_is_named(procedural_rig):
    nodes = procedural_rig.nodes.copy()
    tets = procedural_rig.tets.copy()
    # move vertex 3 of tet 5 onto the plane of the other three
    a, b, c, d = tets[5]
    nodes[d] = (nodes[a] + nodes[b] + nodes[c]) / 3
    with pytest.raises(native.InvalidInput, match="zero volume|inverted"):
        native.HandModel(nodes, tets, palm_seed=procedural_rig.seed, handle_radius=0.03)


def test_seed_outside_the_hand(procedural_rig):
    outside = procedural_rig.nodes.max(axis=0) + 0.05
    with pytest.raises(native.InvalidInput, match="outside the hand"):
        make(procedural_rig, palm_seed=outside)


@pytest.mark.parametrize("radius, words", [(1e-4, "at least 4"), (10.0, "all")])
def test_radius_catching_too_few_or_all_nodes(procedural_rig, radius, words):
    with pytest.raises(native.InvalidInput, match=words):
        make(procedural_rig, handle_radius=radius)


@pytest.mark.parametrize("name", ["young_modulus", "density", "spring_stiffness", "handle_radius", "dt"])
@pytest.mark.parametrize("value", [math.nan, 0.0, -1.0])
def test_nan_or_non_positive_parameters(procedural_rig, name, value):
    with pytest.raises(native.InvalidInput, match=name):
        make(procedural_rig, **{name: value})


@pytest.mark.parametrize("name", ["poisson_ratio", "spring_damping", "rayleigh_beta"])
def test_out_of_range_parameters(procedural_rig, name):
    with pytest.raises(native.InvalidInput, match=name):
        make(procedural_rig, **{name: -0.1 if name != "poisson_ratio" else 0.5})


def test_too_large_time_step(procedural_rig):
    with pytest.raises(native.InvalidInput, match="dt"):
        make(procedural_rig, dt=0.5)


def test_array_shapes_are_checked(procedural_rig):
    model = make(procedural_rig)
    sim = native.HandSimulation(model)
    with pytest.raises(native.InvalidInput, match="shape"):
        sim.set_state(positions=np.zeros((3, 3)))
    with pytest.raises(native.InvalidInput, match="NaN"):
        sim.set_device([np.nan, 0, 0])


def test_rejected_state_leaves_the_simulation_as_it_was(procedural_rig):
    model = make(procedural_rig)
    sim = native.HandSimulation(model)
    sim.step()
    before = sim.positions()
    with pytest.raises(native.InvalidInput):
        sim.set_state(velocities=np.full(model.nodes.shape, np.inf))
    assert np.array_equal(sim.positions(), before)


# --- scenes through the command line: a message naming the problem, never a traceback, and
# check-rig refusing what simulate refuses with the same message ---------------------------

import json  # noqa: E402
import shutil  # noqa: E402
from pathlib import Path  # noqa: E402

from haptic_hand.__main__ import main  # noqa: E402
from haptic_hand.engine import params, rig_check, scene as scenes  # noqa: E402

SAMPLES = Path(__file__).resolve().parents[2] / "addon" / "engine" / "sample_scenes"
HAND_TETS = SAMPLES / "procedural_hand_tets.npz"


def base_scene() -> dict:
    return {"format": "haptic_hand.scene/1", "hand": {"mesh": "procedural", "tets": "hand_tets.npz"}, "frames": 2}


def put(scene: dict, path: str, value) -> dict:
    node = scene
    keys = path.split(".")
    for k in keys[:-1]:
        node = node.setdefault(k, {})
    node[keys[-1]] = value
    return scene


def write_npz(d: Path, name: str, **arrays) -> str:
    np.savez(d / name, **arrays)
    return name


def write_text(d: Path, name: str, text: str) -> str:
    (d / name).write_text(text)
    return name


def shifted_box_tets(d: Path) -> str:
    """A box's tets centred 5 cm away from where its surface is."""
    nodes, tets = mesh.structured_box([0.04] * 3, [2] * 3, [0.03, -0.02, -0.02])
    return write_npz(d, "box_tets.npz", nodes=nodes, tets=tets)


def overlapping_shells_obj(d: Path) -> str:
    v, f = mesh.procedural_hand()
    mesh.save_obj(d / "two_hands.obj", np.concatenate([v, v + [0.01, 0.0, 0.0]]), np.concatenate([f, f + len(v)]))
    return "two_hands.obj"


def hand_obj_with(d: Path, name: str, edit) -> str:
    """The procedural hand as an OBJ file whose lines `edit` changes (a list of str in, out)."""
    v, f = mesh.procedural_hand()
    mesh.save_obj(d / name, v, f)
    (d / name).write_text("".join(edit((d / name).read_text().splitlines(keepends=True))))
    return name


def wrapped_face(lines: list) -> list:
    """The first face's first corner moved up by 2^32: wrapped to 32 bits it is the same vertex."""
    k = next(i for i, line in enumerate(lines) if line.startswith("f "))
    corners = lines[k].split()[1:]
    lines[k] = f"f {int(corners[0]) + 2**32} {corners[1]} {corners[2]}\n"
    return lines


def hand_tets(d: Path):
    stored = np.load(HAND_TETS)
    return stored["nodes"], stored["tets"]


def soft_box(**fields) -> dict:
    return {"name": "b", "type": "soft", "mesh": "box", "position": [0.3, 0, 0], **fields}


# (name, how the base scene changes given the scene's folder, words the message must hold)
BAD_SCENES = [
    # whole sections of the wrong JSON type: the field, what it must be
    ("hand a string", lambda d, s: put(s, "hand", "hand.obj"), 'hand = "hand.obj" is invalid: it must be an object'),
    ("material a list", lambda d, s: put(s, "material", [5e4, 0.3]), "material = [50000.0, 0.3] is invalid: it must "
     "be an object with the fields young_modulus"),
    ("haptics a number", lambda d, s: put(s, "haptics", 1), "haptics = 1 is invalid: it must be an object"),
    ("device null", lambda d, s: put(s, "device", None), "device = null is invalid: it must be an object"),
    ("trajectory an object", lambda d, s: put(s, "device.trajectory", {"t": 0}),
     "device.trajectory must be a non-empty list"),
    ("hand.tetrahedralize a list", lambda d, s: put(s, "hand.tetrahedralize", [0.2]),
     "hand.tetrahedralize = [0.2] is invalid: it must be an object"),
    ("bodies an object", lambda d, s: put(s, "bodies", soft_box()), "bodies = {\"name\": \"b\""),
    ("bodies a string", lambda d, s: put(s, "bodies", "box"), 'bodies = "box" is invalid: it must be a list of body '
     "objects"),
    ("a body a string", lambda d, s: put(s, "bodies", ["box"]), 'bodies[0] = "box" is invalid: each body must be an '
     "object"),
    ("a body null", lambda d, s: put(s, "bodies", [soft_box(), None]), "bodies[1] = null is invalid"),
    ("a body's material a list", lambda d, s: put(s, "bodies", [soft_box(material=[1e5])]),
     "bodies[0] ('b').material = [100000.0] is invalid: it must be an object"),
    ("a body's solver a string", lambda d, s: put(s, "bodies", [soft_box(solver="cg")]),
     "bodies[0] ('b').solver = \"cg\" is invalid: it must be an object"),
    ("the scene a list", lambda d, s: [s], "the scene is [{"),
    ("the scene null", lambda d, s: None, "the scene is null, not a JSON object"),
    ("trajectory point not an object", lambda d, s: put(s, "device.trajectory", [1, 2]), "device.trajectory[0]"),
    ("trajectory time a string", lambda d, s: put(s, "device.trajectory", [{"t": "x"}]), "device.trajectory[0].t"),
    ("trajectory position of strings", lambda d, s: put(s, "device.trajectory", [{"t": 0, "position": ["1", "2", "3"]}]),
     "position must be a list of 3 numbers"),
    ("kinematic script point not an object",
     lambda d, s: put(s, "bodies", [{"name": "k", "type": "kinematic", "mesh": "box", "position": [0.3, 0, 0],
                                     "trajectory": [3]}]), "body 'k': trajectory[0]"),
    ("fixed nodes a word", lambda d, s: put(s, "bodies", [{"name": "b", "type": "soft", "mesh": "box",
                                                           "position": [0.3, 0, 0], "fixed": "top"}]), "fixed"),
    ("fixed nodes floats", lambda d, s: put(s, "bodies", [{"name": "b", "type": "soft", "mesh": "box",
                                                           "position": [0.3, 0, 0], "fixed": [1.5]}]), "whole numbers"),
    ("tets file missing", lambda d, s: put(s, "hand.tets", "nope.npz"), "hand.tets file"),
    ("tets key missing", lambda d, s: put(s, "hand.tets", write_npz(d, "k.npz", nodes=hand_tets(d)[0])),
     "no 'tets' array"),
    ("tets corrupt zip", lambda d, s: put(s, "hand.tets", write_text(d, "c.npz", "PK\x03\x04garbage")),
     "not a readable .npz"),
    ("tets out of range", lambda d, s: put(s, "hand.tets", write_npz(
        d, "r.npz", nodes=hand_tets(d)[0], tets=np.where(hand_tets(d)[1] == 0, 5000, hand_tets(d)[1]))), "outside 0..936"),
    ("tets floats", lambda d, s: put(s, "hand.tets", write_npz(
        d, "f.npz", nodes=hand_tets(d)[0], tets=hand_tets(d)[1] + 0.25)), "refused rather than rounded"),
    ("tets 3 columns", lambda d, s: put(s, "hand.tets", write_npz(
        d, "3.npz", nodes=hand_tets(d)[0], tets=hand_tets(d)[1][:, :3])), "shape"),
    ("tets empty", lambda d, s: put(s, "hand.tets", write_npz(
        d, "e.npz", nodes=hand_tets(d)[0], tets=np.zeros((0, 4), np.int32))), "at least one tet"),
    ("tet index beyond 32 bits", lambda d, s: put(s, "hand.tets", write_npz(
        d, "64.npz", nodes=hand_tets(d)[0], tets=hand_tets(d)[1].astype(np.int64) + (2**32) * (
            np.arange(hand_tets(d)[1].size).reshape(-1, 4) == 0))), "node [429496"),
    ("body tets corrupt", lambda d, s: put(s, "bodies", [{"name": "b", "type": "soft", "mesh": "box",
                                                          "tets": write_text(d, "c.npz", "junk")}]), "body 'b'"),
    ("unknown letter", lambda d, s: put(s, "bodies", [{"name": "o", "type": "soft", "mesh": "procedural:letter:O"}]),
     "no procedural letter 'O'"),
    ("soft surface away from its tets",
     lambda d, s: put(s, "bodies", [{"name": "cube", "type": "soft", "mesh": "box", "size": [0.04] * 3,
                                     "cells": [2] * 3, "position": [0.3, 0, 0], "tets": shifted_box_tets(d)}]),
     "outside its tets"),
    ("soft body inside the hand",
     lambda d, s: put(s, "bodies", [{"name": "cube", "type": "soft", "mesh": "box", "size": [0.01] * 3,
                                     "cells": [1] * 3, "position": [0.0, 0.0, -0.0425]}]),
     "starts inside the hand"),
    ("box 6 mm into the ground",
     lambda d, s: put(s, "bodies", [{"name": "ground", "type": "plane", "point": [0, 0, -0.3]},
                                    {"name": "cube", "type": "soft", "mesh": "box", "size": [0.04] * 3,
                                     "cells": [2] * 3, "position": [0.3, 0, -0.3 + 0.02 - 0.006]}]),
     "6 mm deep"),
    ("hand of two overlapping shells", lambda d, s: put(put(s, "hand.mesh", overlapping_shells_obj(d)),
                                                        "hand.palm_seed", [0, 0, -0.0425]), "intersects itself"),
    ("OBJ vertex of two coordinates", lambda d, s: put(s, "hand.mesh", hand_obj_with(
        d, "two.obj", lambda lines: ["v 0.01 0.02\n"] + lines)), "two.obj:1: cannot read 'v' line (a vertex needs 3 "
     "coordinates x y z, this one has 2)"),
    ("OBJ face of two corners", lambda d, s: put(s, "hand.mesh", hand_obj_with(
        d, "edge.obj", lambda lines: lines + ["f 1 2\n"])), "a face needs at least 3 corners"),
    ("OBJ face index beyond 32 bits", lambda d, s: put(s, "hand.mesh", hand_obj_with(d, "wide.obj", wrapped_face)),
     "face refers to vertex [42949"),
    ("playback file missing", lambda d, s: put(s, "haptics", {"enabled": True, "device": "playback:nope.csv"}),
     "does not exist"),
    ("playback file corrupt", lambda d, s: put(s, "haptics", {"enabled": True,
                                                              "device": "playback:" + write_text(d, "p.npz", "junk")}),
     "not a readable .npz"),
    ("playback file with NaN", lambda d, s: put(s, "haptics", {"enabled": True, "device": "playback:" + write_text(
        d, "n.csv", "0,0,0,0\n1,nan,0,0\n")}), "finite"),
    ("playback file with NaN times", lambda d, s: put(s, "haptics", {"enabled": True, "device": "playback:" + write_text(
        d, "nt.csv", "0,0,0,0\nnan,0,0,0\n")}), "finite"),
    ("playback file empty", lambda d, s: put(s, "haptics", {"enabled": True, "device": "playback:" + write_text(
        d, "e.csv", "")}), "holds no rows"),
    ("playback times not increasing", lambda d, s: put(s, "haptics", {"enabled": True, "device": "playback:" + write_text(
        d, "m.csv", "0,0,0,0\n1,0,0,0\n0.5,0,0,0\n")}), "increase strictly"),
]


def bones(**change) -> list:
    """Two bones of the procedural hand's palm and index finger as a scene's bone list; `change`:
    {index: {field: value}} edits."""
    out = [{"name": "palm", "head": [0, 0, 0], "tail": [0, 0, -0.075], "radius": 0.03},
           {"name": "index", "parent": "palm", "head": [0, 0.033, -0.095], "tail": [0, 0.036, -0.161],
            "radius": 0.0098}]
    for i, fields in change.items():
        out[int(i[1:])].update(fields)
    return out


def skeletal(s: dict, **section) -> dict:
    """The scene with the procedural skeleton and these skeleton.* fields."""
    return put(put(s, "hand.skeleton", "procedural"), "skeleton", section)


def index_keys(name="index_1", **pose) -> list:
    return [{"t": 0.0, "bones": {name: {"quaternion": [0, 0, 0, 1], **pose}}},
            {"t": 1.0, "bones": {"index_1": {"quaternion": [0, 0.3, 0, 0.95]}}}]


# (name, change, words): the skeleton fields (docs/skeleton.md, Section 8)
BAD_SKELETONS = [
    ("skeleton a number", lambda d, s: put(s, "hand.skeleton", 3), 'hand.skeleton = 3 is invalid: use null (the '
     'palm handle), "procedural"'),
    ("no bones", lambda d, s: put(s, "hand.skeleton", []), "hand.skeleton = [] has no bones"),
    ("a bone a string", lambda d, s: put(s, "hand.skeleton", ["palm"]), 'hand.skeleton[0] = "palm" is invalid: each '
     "bone must be an object"),
    ("a bone's radius a string", lambda d, s: put(s, "hand.skeleton", bones(b1={"radius": "1"})),
     "hand.skeleton[1] ('index').radius = \"1\" is invalid: it must be a number or null (m)"),
    ("a bone without head", lambda d, s: put(s, "hand.skeleton", [{"name": "palm", "tail": [0, 0, -0.07],
                                                                    "radius": 0.03}]),
     "hand.skeleton[0] ('palm').head = null is invalid: it must be a list of 3 numbers (m)"),
    ("a bone's unknown field", lambda d, s: put(s, "hand.skeleton", bones(b1={"length": 0.05})),
     "unknown field 'hand.skeleton[1] ('index').length'"),
    ("an unknown parent", lambda d, s: put(s, "hand.skeleton", bones(b1={"parent": "wrist"})),
     "hand.skeleton[1] ('index').parent = 'wrist' is not a bone of the list (its bones: palm, index)"),
    ("two bones of one name", lambda d, s: put(s, "hand.skeleton", bones(b1={"name": "palm", "parent": None})),
     "hand.skeleton[1] is named 'palm' as bone 0 is"),
    ("the first bone not a root", lambda d, s: put(s, "hand.skeleton", bones(b0={"parent": "index"})),
     "hand.skeleton[0] ('palm') has parent 'index': the first bone must be a root"),
    ("a bone with radius and nodes", lambda d, s: put(s, "hand.skeleton", bones(b1={"nodes": [1, 2, 3, 4]})),
     "hand.skeleton[1] ('index') has both a radius and nodes"),
    ("a bone with neither", lambda d, s: put(s, "hand.skeleton", bones(b1={"radius": None})),
     "hand.skeleton[1] ('index') has neither a radius nor nodes"),
    ("a node in two bones", lambda d, s: put(s, "hand.skeleton", bones(b0={"radius": None, "nodes": [0, 1, 2, 3, 4]},
                                                                       b1={"radius": None, "nodes": [4, 5, 6, 7]})),
     "hand.skeleton[1] ('index').nodes holds node 4, which bone 'palm' holds too"),
    ("node indices not whole", lambda d, s: put(s, "hand.skeleton", bones(b1={"radius": None, "nodes": [1.5]})),
     "hand.skeleton[1] ('index').nodes = [1.5] is invalid: give a list of tet node indices"),
    ("a node beyond the tets", lambda d, s: put(s, "hand.skeleton", bones(b1={"radius": None,
                                                                               "nodes": [1, 2, 3, 5000]})),
     "hand.skeleton[1] ('index').nodes holds node 5000, but the hand's tets have nodes 0..936"),
    ("a bone holding 3 nodes", lambda d, s: put(s, "hand.skeleton", bones(b1={"radius": 0.001})),
     "hand.skeleton: bone 'index'"),
    ("targets without a skeleton", lambda d, s: put(s, "skeleton.targets", index_keys()),
     "skeleton.targets drives a skeleton's bones, but hand.skeleton is null"),
    ("joints without a skeleton", lambda d, s: put(s, "skeleton.joints", {"stiffness": 1e4}),
     "skeleton.joints.stiffness ties bones to their parents, but hand.skeleton is null"),
    ("a negative joint stiffness", lambda d, s: skeletal(s, joints={"stiffness": -1.0}),
     "skeleton.joints.stiffness"),
    ("a target naming an unknown bone", lambda d, s: skeletal(s, targets=index_keys("indx_1")),
     "skeleton.targets[0].bones names 'indx_1', which is not a bone of hand.skeleton (its bones: palm, thumb_1"),
    ("targets an object", lambda d, s: skeletal(s, targets={"t": 0}), "skeleton.targets must be a list of keys"),
    ("a target time backwards", lambda d, s: skeletal(s, targets=index_keys()[::-1]),
     "skeleton.targets[1].t = 0.0 s comes after 1.0 s: key times must strictly increase"),
    ("a target quaternion of strings", lambda d, s: skeletal(s, targets=index_keys(quaternion=["0", 0, 0, 1])),
     "skeleton.targets[0].bones.index_1.quaternion must be a list of 4 numbers"),
    ("a target with a stray field", lambda d, s: skeletal(s, targets=index_keys(scale=[1, 1, 1])),
     "skeleton.targets[0].bones.index_1 = {"),
    ("a position in one key only", lambda d, s: skeletal(s, targets=index_keys(position=[0, 0, 0])),
     "skeleton.targets: bone 'index_1' has a position in some keys and not in others"),
    ("tracking file missing", lambda d, s: skeletal(s, tracking="hand.csv"), "skeleton.tracking: "),
    ("tracking file not a stream", lambda d, s: skeletal(s, tracking=write_text(d, "bad.csv", "t,joint\n")),
     "skeleton.tracking: "),
    ("tracking and targets", lambda d, s: skeletal(s, targets=index_keys(), tracking=write_mano(d)),
     "skeleton.targets and skeleton.tracking both drive the bones: give one of them"),
    ("a map without a stream", lambda d, s: skeletal(s, tracking_map={"wrist": "palm"}),
     "skeleton.tracking_map is given without skeleton.tracking"),
    ("a map to an unknown bone", lambda d, s: skeletal(s, tracking=write_mano(d), tracking_map={"wrist": "hand"}),
     "skeleton.tracking_map: joint map: joint 'wrist' drives 'hand', which is not a bone of the skeleton"),
    ("the procedural map on other bones", lambda d, s: put(put(s, "hand.skeleton", bones()), "skeleton.tracking",
                                                           write_mano(d)),
     "give skeleton.tracking_map for this skeleton's bones"),
]


def felt(s: dict, skeleton="procedural", **haptics) -> dict:
    """The scene with this skeleton and these haptics.* fields."""
    return put(put(s, "hand.skeleton", skeleton), "haptics", haptics)


INDEX = ["index_1", "index_2", "index_3"]
# (name, change, words): a skeleton hand's haptic session (haptics.feedback, .groups, .glove, the device)
BAD_HAPTIC_SKELETONS = [
    ("bones felt on the palm handle", lambda d, s: put(s, "haptics.feedback", "bones"),
     'haptics.feedback = "bones" needs a skeleton hand of several bones, and hand.skeleton is null (the palm handle): '
     'set haptics.feedback to "palm"'),
    ("groups felt on one bone", lambda d, s: felt(s, bones()[:1], feedback="groups"),
     'haptics.feedback = "groups" needs a skeleton hand of several bones, and hand.skeleton has one bone'),
    ("groups without feedback by groups", lambda d, s: felt(s, groups={"index": INDEX}),
     'haptics.groups is given but haptics.feedback is "palm": set haptics.feedback to "groups", or remove '
     "haptics.groups"),
    ("groups not an object", lambda d, s: felt(s, feedback="groups", groups=INDEX),
     'haptics.groups = ["index_1", "index_2", "index_3"] is invalid: give an object {group name: [bone names]}'),
    ("a group not a list", lambda d, s: felt(s, feedback="groups", groups={"index": "index_1"}),
     'haptics.groups.index = "index_1" is invalid: give a non-empty list of bone names'),
    ("a group naming an unknown bone", lambda d, s: felt(s, feedback="groups", groups={"index": ["index_1", "indx_2"]}),
     "haptics.groups.index names 'indx_2', which is not a bone of hand.skeleton (its bones: palm, thumb_1"),
    ("a bone in two groups", lambda d, s: felt(s, feedback="groups", groups={"index": INDEX,
                                                                             "pinch": ["thumb_3", "index_3"]}),
     "haptics.groups: bone 'index_3' is in group 'index' and in group 'pinch': a bone's feedback goes to one group: "
     "remove it from one of them"),
    ("a bone twice in a group", lambda d, s: felt(s, feedback="groups", groups={"index": INDEX + ["index_1"]}),
     "haptics.groups.index names bone 'index_1' twice: name it once"),
    ("the wrist and digits of a hand without digits",
     lambda d, s: felt(s, bones(b1={"parent": None}), feedback="groups"),
     'haptics.feedback = "groups" with haptics.groups null groups the wrist and the digits (the chains of bones '
     "leaving a root), but no bone of hand.skeleton has a parent, so it has no digit: list the groups in "
     'haptics.groups, e.g. {"palm": ["palm"], "index": ["index"]}, or set haptics.feedback to "bones"'),
    ("a one-frame device on a skeleton", lambda d, s: felt(s, enabled=True, device="openhaptics"),
     "haptics.device 'openhaptics' has one frame, and a skeleton hand's session has a device frame per bone: set "
     "skeleton.root_device to true (the device drives the wrist and the fingers are posed on it), or use "
     "'simulated' (the simulated glove user) or 'external'"),
    ("a wrench per bone on a one-frame wrist device",
     lambda d, s: put(felt(s, enabled=True, device="openhaptics", feedback="bones"), "skeleton", {"root_device": True}),
     'haptics.feedback = "bones" renders a wrench per bone, but with skeleton.root_device the device \'openhaptics\' '
     "is one frame on the wrist, which renders the whole hand's wrench: set haptics.feedback to \"palm\", or set "
     "skeleton.root_device to false for a glove of one frame per bone ('simulated' or 'external')"),
    ("groups on a one-frame wrist device",
     lambda d, s: put(felt(s, enabled=True, device="playback:x.csv", feedback="groups"), "skeleton",
                      {"root_device": True}),
     'haptics.feedback = "groups" renders a wrench per bone, but with skeleton.root_device the device '
     "'playback:x.csv' is one frame on the wrist"),
    ("a free bone in a haptic session", lambda d, s: felt(s, bones(b1={"drive_scale": 0}), enabled=True),
     "hand.skeleton[1] ('index').drive_scale = 0 frees the bone, but in a haptic session every bone follows its own "
     "device frame: set its drive_scale above 0, or haptics.enabled to false"),
    ("a glove finger of no mass", lambda d, s: felt(s, enabled=True, glove={"mass": 0}),
     "haptics.glove.mass = 0 is invalid"),
]
BAD_SKELETONS += BAD_HAPTIC_SKELETONS
BAD_SCENES += BAD_SKELETONS


def write_mano(d: Path) -> str:
    """A one-sample MANO stream at rest, every joint at the origin."""
    from haptic_hand.engine import tracking

    layout = tracking.MANO
    zeros, unit = np.zeros((1, len(layout.joints), 3)), np.tile([0.0, 0.0, 0.0, 1.0], (1, len(layout.joints), 1))
    tracking.write(d / "mano.csv", tracking.TrackingStream(layout, np.zeros(1), zeros, unit, zeros[0], unit[0]))
    return "mano.csv"


@pytest.fixture
def scene_dir(tmp_path):
    shutil.copy(HAND_TETS, tmp_path / "hand_tets.npz")
    return tmp_path


@pytest.mark.parametrize("name, change, words", BAD_SCENES, ids=[b[0] for b in BAD_SCENES])
def test_bad_scene_gets_a_message_and_check_rig_refuses_it_alike(scene_dir, capsys, name, change, words):
    path = scene_dir / "scene.json"
    path.write_text(json.dumps(change(scene_dir, base_scene())))
    assert main(["simulate", str(path), "--out", str(scene_dir / "result.npz"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err
    message = err.strip().splitlines()[-1].removeprefix("error: ")
    assert not (scene_dir / "result.npz").exists()
    assert main(["check-rig", str(path), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert not report["ok"] and [c["detail"] for c in report["checks"]] == [message]


def not_utf8(path: Path) -> Path:
    path.write_bytes(json.dumps(base_scene()).replace("procedural", "proc\u00e9dural").encode("latin-1"))
    return path


@pytest.mark.parametrize("make, words", [
    (not_utf8, "is not UTF-8 text (byte 0xe9 at offset"),
    (lambda p: p.mkdir() or p, "is a directory: give the path of a scene .json file"),
    (lambda p: p.with_name("missing.json"), "does not exist: give the path of a scene .json file"),
], ids=["not UTF-8", "a directory", "missing"])
def test_a_scene_file_that_cannot_be_read_gets_a_message(scene_dir, capsys, make, words):
    path = make(scene_dir / "scene.json")
    assert main(["simulate", str(path), "--out", str(scene_dir / "result.npz"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert words in err and "internal error" not in err and "Traceback" not in err
    assert main(["check-rig", str(path), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["checks"][0]["detail"] == err.strip().removeprefix("error: ")


def test_a_scene_file_with_a_byte_order_mark_is_read(scene_dir):
    path = scene_dir / "scene.json"
    path.write_bytes(b"\xef\xbb\xbf" + json.dumps(base_scene()).encode())
    assert scenes.load(path).frames == 2


def test_check_rig_json_reports_an_internal_error_with_every_key(scene_dir, capsys, monkeypatch):
    path = scene_dir / "scene.json"
    path.write_text(json.dumps(put(base_scene(), "hand.tets", "nope.npz")))
    assert main(["check-rig", str(path), "--json"]) == 1
    refused = json.loads(capsys.readouterr().out)

    def bug(scene):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(rig_check, "check", bug)
    assert main(["check-rig", str(path), "--json"]) == 3
    report = json.loads(capsys.readouterr().out)
    assert set(report) == set(refused) == {"ok", "checks", "warnings"}
    assert report["warnings"] == [] and "internal error (ZeroDivisionError: a bug)" in report["checks"][0]["detail"]


def test_check_rig_json_is_json_for_a_file_that_is_not_json(scene_dir, capsys):
    path = scene_dir / "broken.json"
    path.write_text("{not json")
    assert main(["check-rig", str(path), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert not report["ok"] and "not valid JSON" in report["checks"][0]["detail"]


def test_a_run_too_large_for_memory_is_refused_before_allocating(scene_dir):
    scene = scenes.from_dict(put(base_scene(), "frames", 1_000_000), scene_dir)
    need = scenes.result_bytes(scene, 937)
    assert need > 937 * 3 * 8 * 1_000_000  # every frame's hand positions at least
    with pytest.raises(scenes.SceneError, match=r"frames = 1000000 would need about 2\d\.\d GiB"):
        scenes.check_memory(scene, 937, available=16 * 2**30)
    scenes.check_memory(scenes.from_dict(base_scene(), scene_dir), 937, available=16 * 2**30)


@pytest.mark.parametrize("frames, shown", [(2e9, "2e+09"), (2_000_000_000, "2e+09"), (1_000_001, "1000001")])
def test_frames_beyond_the_cap_are_refused_before_anything_is_allocated(scene_dir, capsys, frames, shown):
    """frames = 2e9 once asked numpy for 40.9 TiB (a MemoryError); the table caps frames at 1e6
    (about 9 hours at 30 Hz), checked when the scene is read, before the tets are loaded."""
    import tracemalloc

    path = scene_dir / "scene.json"
    path.write_text(json.dumps(put(base_scene(), "frames", frames)))
    tracemalloc.start()
    try:
        code = main(["simulate", str(path), "--out", str(scene_dir / "result.npz"), "--quiet"])
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    err = capsys.readouterr().err
    assert code == 2 and f"frames = {shown} is invalid: it must be a whole number in [1, 1e+06]" in err
    assert peak < 32 * 2**20, f"{peak / 2**20:.0f} MiB allocated before refusing"  # the hand's tets alone are ~0.1 MiB
    assert main(["check-rig", str(path), "--json"]) == 1
    assert json.loads(capsys.readouterr().out)["checks"][0]["detail"] == err.strip().removeprefix("error: ")


def test_the_frames_cap_is_a_million():
    assert params.by_json("frames").max == 1e6
    assert scenes.from_dict(put(base_scene(), "frames", 1_000_000)).frames == 1_000_000
    with pytest.raises(scenes.SceneError, match=r"frames = 1000001 is invalid"):
        scenes.from_dict(put(base_scene(), "frames", 1_000_001))


def test_the_memory_estimate_covers_what_a_run_holds(scene_dir):
    from haptic_hand.engine import simulate

    scene = scenes.from_dict(put(put(base_scene(), "haptics", {"enabled": True}), "bodies", [
        {"name": "cube", "type": "soft", "mesh": "box", "size": [0.04] * 3, "cells": [2] * 3, "position": [0.3, 0, 0]}]),
        scene_dir)
    result = simulate.run(scene)
    per_run = ("positions", "handle_pose", "device_pose", "coupling_wrench", "body_cube_positions")
    held = sum(result[k].nbytes for k in per_run) + sum(v.nbytes for v in result["haptic"].values())
    assert held <= scenes.result_bytes(scene, len(scene.nodes)) <= 3 * held


def test_a_hand_in_millimetres_is_told_so(scene_dir):
    v, f = mesh.procedural_hand()
    mesh.save_obj(scene_dir / "hand_mm.obj", v * 1000, f)
    nodes, tets = hand_tets(scene_dir)
    np.savez(scene_dir / "tets_mm.npz", nodes=nodes * 1000, tets=tets)
    scene = scenes.from_dict(put(put(put(base_scene(), "hand.mesh", "hand_mm.obj"), "hand.tets", "tets_mm.npz"),
                                 "hand.palm_seed", [0.0, 0.0, -42.5]), scene_dir)
    with pytest.raises(native.InvalidInput, match=r"captures 0 node.*looks modelled in millimetres.*scale it by 0.001"):
        scenes.build_model(scene)
    assert "millimetres" in scene.warnings[0]
    assert "millimetres" in rig_check.format_report(rig_check.check(scene))


def test_a_hand_of_human_size_gets_no_scale_warning():
    v, _ = mesh.procedural_hand()
    assert mesh.scale_warning(v) is None
    assert "centimetres" in mesh.scale_warning(v * 100) and "inches" in mesh.scale_warning(v / 0.0254)


def test_a_float_or_wide_tet_index_is_refused_by_the_bindings(procedural_rig):
    tets = procedural_rig.tets.astype(np.int64)
    tets[3, 1] += 2**32
    with pytest.raises(native.InvalidInput, match="beyond 32 bits"):
        native.HandModel(procedural_rig.nodes, tets, palm_seed=procedural_rig.seed)
    with pytest.raises(native.InvalidInput, match="not truncated"):
        native.HandModel(procedural_rig.nodes, procedural_rig.tets + 0.5, palm_seed=procedural_rig.seed)
