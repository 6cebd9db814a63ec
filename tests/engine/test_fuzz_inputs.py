"""Property-based guard (Hypothesis): arbitrary JSON scenes and arbitrary arrays either run or
end in a clean error (the user errors the command line prints as `error: ...`), never in any
other exception. Derandomized and bounded, so `make test` stays fast and repeatable."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from haptic_hand.engine import mesh, native, params, rig_check, simulate
from haptic_hand.engine import scene as scenes

SAMPLES = Path(__file__).resolve().parents[2] / "addon" / "engine" / "sample_scenes"
FUZZ = settings(max_examples=200, deadline=None, derandomize=True, database=None,
                suppress_health_check=list(HealthCheck))

json_scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**12, 10**12),
                         st.floats(allow_nan=False, width=64), st.text(max_size=8),
                         st.sampled_from(["box", "procedural", "procedural:bunny", "procedural:letter:H", "soft",
                                          "plane", "bottom", "cholesky", "playback:x.csv", "5e4", "no"]))
json_values = st.recursive(json_scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=4)), max_leaves=10)
FIELDS = [p.json for p in params.table() if not p.element and not p.flags & params.INTERNAL]
BODY_FIELDS = [p.json[len(params.BODY):] for p in params.table() if p.body]
BONE_FIELDS = [p.json[len(params.BONE):] for p in params.table() if p.element == params.BONE]


def sections(defaults: dict, where: str = "") -> list[str]:
    """Every object of the defaults by its path (hand, hand.tetrahedralize, ...): whole sections
    a scene may give as any JSON value."""
    out = []
    for key, value in defaults.items():
        if isinstance(value, dict):
            out += [where + key] + sections(value, f"{where}{key}.")
    return out


SECTIONS = sections(params.defaults()) + ["bodies", "device.trajectory"]
BODY_SECTIONS = sections(params.defaults(body=True)) + ["trajectory"]


def put(data: dict, path: str, value) -> None:
    node = data
    keys = path.split(".")
    for k in keys[:-1]:
        if not isinstance(node.get(k), dict):
            node[k] = {}
        node = node[k]
    node[keys[-1]] = value


@st.composite
def bodies(draw):
    body = {"type": draw(st.sampled_from(["soft", "rigid", "kinematic", "static", "plane", "jelly"])),
            "mesh": draw(st.sampled_from(["box", "procedural:letter:I", None, "missing.obj"])),
            "position": [0.3, 0.0, 0.0], "cells": [1, 1, 1], "size": [0.02, 0.02, 0.02]}
    for path, value in draw(st.lists(st.tuples(st.sampled_from(BODY_FIELDS + ["junk"]), json_values), max_size=3)):
        put(body, path, value)
    if draw(st.integers(0, 3)) == 0:  # a whole section of any JSON type: the material as a list, ...
        put(body, draw(st.sampled_from(BODY_SECTIONS)), draw(json_values))
    return draw(st.one_of(st.just(body), json_values)) if draw(st.integers(0, 9)) == 0 else body


@st.composite
def bone_lists(draw):
    """Bone lists near a valid palm and finger of the procedural hand, fields changed at random."""
    out = [{"name": "palm", "head": [0, 0, 0], "tail": [0, 0, -0.075], "radius": 0.03},
           {"name": "index_1", "parent": "palm", "head": [0, 0.033, -0.095], "tail": [0, 0.036, -0.161],
            "radius": 0.0098}]
    for path, value in draw(st.lists(st.tuples(st.sampled_from(BONE_FIELDS + ["junk"]), json_values), max_size=2)):
        put(out[draw(st.integers(0, 1))], path, value)
    return draw(st.one_of(st.just(out), st.just(out[:1]), json_values)) if draw(st.integers(0, 4)) == 0 else out


@st.composite
def skeleton_section(draw):
    keys = [{"t": 0.0, "bones": {"index_1": {"quaternion": [0, 0, 0, 1]}}},
            {"t": 0.05, "bones": {"index_1": {"quaternion": [0, 0.2, 0, 0.98]}, "palm": {"position": [0, 0, 0.001]}}}]
    section = {"targets": keys, "root_device": draw(st.booleans()), "drive": {"prescribed": draw(st.booleans())}}
    for path, value in draw(st.lists(st.tuples(st.sampled_from(["targets", "targets.0", "targets.1.bones",
                                                                "targets.1.bones.index_1", "tracking", "tracking_map",
                                                                "root_device", "drive.prescribed"]), json_values),
                                     max_size=2)):
        keys_path = path.split(".")
        if len(keys_path) > 1 and keys_path[1].isdigit():  # inside a key of the list, if it still is one
            targets = section["targets"]
            key = targets[int(keys_path[1])] if isinstance(targets, list) and len(targets) > int(keys_path[1]) else None
            if isinstance(key, dict):
                put(key, ".".join(keys_path[2:]) or "t", value)
        else:
            put(section, path, value)
    return section


@st.composite
def haptics_section(draw):
    """A skeleton hand's haptic session: on or off, its feedback and groups, the glove, the device."""
    groups = st.sampled_from([None, None, {"index": ["index_1"], "palm": ["palm"]}, {"a": ["index_1"], "b": ["index_1"]},
                              {"a": "index_1"}, ["palm"]])
    return {"enabled": draw(st.booleans()), "feedback": draw(st.sampled_from(["palm", "bones", "groups", "groups", "digits"])),
            "groups": draw(groups), "device": draw(st.sampled_from(["simulated", "external", "hid"])),
            "glove": {"stiffness": draw(st.sampled_from([50.0, 3e4, 50.0, 3e4, -1.0])),
                      "mass": draw(st.sampled_from([0.02, 1.0, 0.02, 1.0, 0.0]))}}


@st.composite
def scenes_json(draw):
    data = {"format": "haptic_hand.scene/1", "hand": {"mesh": "procedural", "tets": "hand_tets.npz"}, "frames": 2}
    for path, value in draw(st.lists(st.tuples(st.sampled_from(FIELDS + ["junk", "hand.junk"]), json_values),
                                     max_size=4)):
        put(data, path, value)
    if draw(st.booleans()):
        data["bodies"] = draw(st.lists(bodies(), max_size=2))
    if draw(st.integers(0, 2)) == 0:  # a skeleton: the procedural one or a bone list, and what drives it
        data["hand"]["skeleton"] = draw(st.one_of(st.just("procedural"), bone_lists()))
        data["skeleton"] = draw(skeleton_section())
    if draw(st.integers(0, 3)) == 0:  # a whole section of any JSON type: the hand as a string, ...
        put(data, draw(st.sampled_from(SECTIONS)), draw(json_values))
    return draw(json_values) if draw(st.integers(0, 19)) == 0 else data


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz")
    shutil.copy(SAMPLES / "procedural_hand_tets.npz", d / "hand_tets.npz")
    return d


@FUZZ
@given(data=scenes_json())
def test_an_arbitrary_scene_runs_or_is_refused_cleanly(scene_dir, data):
    try:
        scene = scenes.from_dict(json.loads(json.dumps(data)), scene_dir)
        if not scene.data["hand"]["tets"]:
            return  # tetrahedralizing takes seconds: the meshes have tests of their own
        scene.data["frames"] = min(scene.frames, 2)
        rig_check.prepare(scene)
        simulate.run(scene)
    except rig_check.USER_ERRORS as e:
        assert str(e)  # a message, never an empty one


@settings(FUZZ, max_examples=60)
@given(skeleton=st.one_of(st.just("procedural"), bone_lists()), section=skeleton_section(), haptics=haptics_section())
def test_an_arbitrary_skeleton_scene_runs_or_is_refused_cleanly(scene_dir, skeleton, section, haptics):
    """Only the skeleton's fields and its haptic session's changed, so most of these scenes reach the run."""
    data = {"format": "haptic_hand.scene/1", "frames": 2, "skeleton": section, "haptics": haptics,
            "hand": {"mesh": "procedural", "tets": "hand_tets.npz", "skeleton": skeleton}}
    try:
        scene = scenes.from_dict(json.loads(json.dumps(data)), scene_dir)
        rig_check.prepare(scene)
        simulate.run(scene)
    except rig_check.USER_ERRORS as e:
        assert str(e)


any_float = st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=False, width=64)
ELEMENTS = {  # mostly values a mesh could hold (small coordinates, indices near the array sizes), some not
    np.float64: st.one_of(st.floats(-0.1, 0.1, width=64), any_float),
    np.float32: st.floats(allow_subnormal=False, width=32),
    np.int32: st.integers(-2, 14), np.int64: st.one_of(st.integers(-2, 14), st.integers(-2**63, 2**63 - 1)),
    np.uint8: st.integers(0, 255), np.bool_: st.booleans(),
}


def arrays(shape_cols):
    return st.sampled_from(list(ELEMENTS)).flatmap(
        lambda dt: hnp.arrays(dt, st.tuples(st.integers(0, 12), shape_cols), elements=ELEMENTS[dt]))


CLEAN = (mesh.MeshError, native.NativeError)


@FUZZ
@given(V=arrays(st.sampled_from([3, 3, 2])), F=arrays(st.sampled_from([3, 3, 4])))
def test_arbitrary_surfaces_are_checked_or_refused_cleanly(V, F):
    for check in (mesh.check_closed_surface, mesh.self_intersections):
        try:
            check(V, F)
        except CLEAN as e:
            assert str(e)


@FUZZ
@given(nodes=arrays(st.sampled_from([3, 3, 2])), tets=arrays(st.sampled_from([4, 4, 3])),
       points=arrays(st.just(3)), seed=st.lists(any_float, min_size=3, max_size=3), radius=any_float)
def test_arbitrary_tet_meshes_are_used_or_refused_cleanly(nodes, tets, points, seed, radius):
    calls = (lambda: mesh.check_tets(nodes, tets), lambda: mesh.embed_points(nodes, tets, points),
             lambda: native.count_captured(nodes, seed, radius),
             lambda: native.HandModel(nodes, tets, palm_seed=seed, handle_radius=radius))
    for call in calls:
        try:
            call()
        except CLEAN as e:
            assert str(e)
