"""The parameter table seen from Python: one default per parameter in C, in the ctypes
structures and in the scene format; every field's JSON type and range refused with a message
that names it; the docs' table is the library's."""

import ctypes
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from haptic_hand.engine import native, params
from haptic_hand.engine import scene as scenes

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_FILL = {params.STRUCT_PARAMS: "hh_default_params", params.STRUCT_WORLD_PARAMS: "hh_default_world_params",
                params.STRUCT_MATERIAL: "hh_default_material",
                params.STRUCT_SESSION_PARAMS: "hh_default_session_params"}


def c_defaults(struct_id: int) -> dict:
    """The C default of every field, read from raw bytes at the header's offsets (not through
    the ctypes structure the bindings build from the same table)."""
    size = ctypes.c_int()
    native.library().hh_struct_size(struct_id, ctypes.byref(size))
    raw = (ctypes.c_char * size.value)()
    fn = getattr(native.library(), DEFAULT_FILL[struct_id])
    fn.argtypes, fn.restype = [ctypes.c_void_p], None
    fn(raw)
    data = bytes(raw)
    assert np.frombuffer(data[:4], np.int32)[0] == size.value  # struct_size first
    out = {}
    for p in params.rows():
        if p.structure == struct_id:
            dtype = np.float64 if p.kind == params.KIND_DOUBLE else np.int32
            out[p.json or p.name] = np.frombuffer(data, dtype, p.count, p.offset).tolist()
    return out


@pytest.mark.parametrize("struct_id", sorted(DEFAULT_FILL))
def test_c_defaults_equal_the_scene_defaults(struct_id):
    scene = scenes.defaults()
    bodies = params.defaults(body=True)
    for key, values in c_defaults(struct_id).items():
        p = next(r for r in params.rows() if (r.json or r.name) == key)
        if p.flags & params.INTERNAL:
            continue
        json_value = params.get(bodies if p.body else scene, p)
        if json_value is None:  # nullable: the scene resolves null (palm_seed: the procedural hand's)
            assert p.nullable
            continue
        c_value = [p.from_number(v) for v in values]
        assert (c_value if p.count > 1 else c_value[0]) == json_value, key


def test_the_ctypes_structures_have_the_header_layout():
    for struct_id in DEFAULT_FILL:
        cls = params.structure(struct_id)
        size = ctypes.c_int()
        native.library().hh_struct_size(struct_id, ctypes.byref(size))
        assert ctypes.sizeof(cls) == size.value
        for p in cls.rows:
            assert getattr(cls, p.name).offset == p.offset


def test_a_default_filled_scene_is_the_table():
    scene = scenes.from_dict({"format": scenes.FORMAT})
    for p in params.table():
        if not p.element and not p.flags & params.INTERNAL and not p.flags & params.REQUIRED:
            assert params.get(scene.data, p) == p.default, p.json
    # and its engine parameters are the C defaults, field for field
    c = c_defaults(params.STRUCT_PARAMS)
    for name, value in scene.engine_params().items():
        p = next(r for r in params.structure(params.STRUCT_PARAMS).rows if r.name == name)
        expected = c[p.json] if p.count > 1 else c[p.json][0]
        if name != "palm_seed":
            assert np.allclose(value, expected), name


def _wrong_types(p):
    if p.kind == params.KIND_BOOL:
        return ["no", 1, None]
    if p.kind == params.KIND_ENUM:
        return ["nonsense", 0]
    if p.kind == params.KIND_INT:
        return ["5", 2.5, True]
    if p.kind == params.KIND_DOUBLE and p.count == 1:
        return ["5e4", [1.0], True] + ([] if p.nullable else [None])
    if p.kind == params.KIND_DOUBLE:
        return [[0.0, 0.0], "up", [0, 0, "1"]]
    return []


def _outside(p) -> float:
    """A number just outside the row's range."""
    if p.flags & params.ZERO_OR_RANGE:
        return 0.5 * p.min
    if math.isfinite(p.min):
        return p.min if p.flags & params.OPEN_MIN else p.min - 1
    if math.isfinite(p.max):
        return p.max if p.flags & params.OPEN_MAX else p.max + 1
    return math.inf


SCENE_ROWS = [p for p in params.table() if not p.element and not p.flags & params.INTERNAL
              and p.kind in params.NUMERIC_KINDS]


@pytest.mark.parametrize("p", SCENE_ROWS, ids=lambda p: p.json)
def test_every_field_refuses_a_wrong_type_naming_itself(p):
    for bad in _wrong_types(p):
        data = {"format": scenes.FORMAT}
        params.put(data, p, bad)
        with pytest.raises(scenes.SceneError, match=f"^{p.json.replace('.', '[.]')} = "):
            scenes.from_dict(data)


@pytest.mark.parametrize("p", SCENE_ROWS, ids=lambda p: p.json)
def test_every_field_refuses_a_value_out_of_range_with_the_fix(p):
    if p.kind in (params.KIND_BOOL, params.KIND_ENUM):
        return
    bad = _outside(p)
    data = {"format": scenes.FORMAT}
    params.put(data, p, [bad] * p.count if p.count > 1 else bad)
    with pytest.raises(scenes.SceneError) as info:
        scenes.from_dict(data)
    message = str(info.value)
    assert message.startswith(p.json) and "it must be" in message and p.advice in message


def test_a_body_field_is_named_with_its_body():
    data = {"format": scenes.FORMAT, "bodies": [
        {"name": "ground", "type": "plane"},
        {"name": "bunny", "type": "soft", "mesh": "procedural:bunny", "material": {"young_modulus": "5e4"}}]}
    with pytest.raises(scenes.SceneError, match=r"bodies\[1\] \('bunny'\)\.material\.young_modulus = \"5e4\""):
        scenes.from_dict(data)


def test_format_is_required():
    with pytest.raises(scenes.SceneError, match='no "format"'):
        scenes.from_dict({"dt": 0.01})


def test_the_docs_hold_the_librarys_table():
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "param_docs.py"), "--check"], capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr
    doc = (ROOT / "docs" / "scene_format.md").read_text()
    for p in params.table():
        if not p.flags & params.INTERNAL:
            assert f"`{p.json}`" in doc
    assert json.dumps(params.by_json("coupling.stiffness").default) in doc
