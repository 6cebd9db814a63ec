"""The parameter table (native/include/haptic_hand_params.h), as the library exports it.

Every layer above the C structs derives from these rows: the ctypes structures (checked against
the library's struct sizes), the scene format's defaults and JSON type checks, the Blender
properties and the docs' parameter table. Value ranges are checked by the library
(`check`), so a range and its message live in the table alone.
"""

from __future__ import annotations

import ctypes
import json
import math
from dataclasses import dataclass
from functools import lru_cache

from . import native_library

KIND_DOUBLE, KIND_INT, KIND_BOOL, KIND_ENUM, KIND_STRING, KIND_PATH, KIND_JSON = range(7)
NUMERIC_KINDS = (KIND_DOUBLE, KIND_INT, KIND_BOOL, KIND_ENUM)
OPEN_MIN, OPEN_MAX, ZERO_OR_RANGE, NULLABLE, REQUIRED = 0x1, 0x2, 0x4, 0x8, 0x10
UI_SCENE, UI_OBJECT, UI_DERIVED, UI_ADVANCED, INTERNAL = 0x20, 0x40, 0x80, 0x100, 0x200
FOR_TYPES = {"soft": 0x1000, "rigid": 0x2000, "kinematic": 0x4000, "static": 0x8000, "plane": 0x10000}
STRUCT_NONE, STRUCT_PARAMS, STRUCT_WORLD_PARAMS, STRUCT_MATERIAL, STRUCT_SESSION_PARAMS = map(
    native_library.STRUCT_NAMES.index, ("", "hh_params", "hh_world_params", "hh_material", "hh_session_params"))
BODY = "bodies[]."  # the fields of each body
BONE = "hand.skeleton[]."  # the fields of each bone of a skeleton given as a list
ELEMENTS = (BODY, BONE)  # lists of objects whose fields are rows: each object is merged over their defaults


class ParamError(ValueError):
    """A value of the wrong JSON type or out of its row's range; the message names the field,
    what it must be and a good value."""


class ParamInfo(ctypes.Structure):
    _fields_ = [("struct_size", ctypes.c_int)] + [
        (name, ctypes.c_char_p) for name in ("name", "json", "unit", "label", "text", "description", "advice")
    ] + [(name, ctypes.c_int) for name in ("kind", "count", "flags", "structure", "offset")] + [
        ("default_value", ctypes.c_double * 3)
    ] + [(name, ctypes.c_double) for name in ("min", "max", "soft_min", "soft_max")]


@dataclass(frozen=True)
class Param:
    name: str
    json: str
    unit: str
    label: str
    text: str
    description: str
    advice: str
    kind: int
    count: int
    flags: int
    structure: int
    offset: int
    default_value: tuple
    min: float
    max: float
    soft_min: float
    soft_max: float

    @property
    def choices(self) -> list[str]:
        return self.text.split("|") if self.kind == KIND_ENUM else []

    @property
    def nullable(self) -> bool:
        return bool(self.flags & NULLABLE)

    @property
    def element(self) -> str:
        """The list whose objects hold this field (BODY, BONE), or "" for a field of the scene."""
        return next((e for e in ELEMENTS if self.json.startswith(e)), "")

    @property
    def body(self) -> bool:
        return self.element == BODY

    @property
    def keys(self) -> tuple[str, ...]:
        """The path of keys in the scene (within a body or bone for their fields)."""
        return tuple(self.json[len(self.element):].split("."))

    def applies_to(self, body_type: str) -> bool:
        return bool(self.flags & FOR_TYPES.get(body_type, 0))

    @property
    def default(self):
        """The default as a JSON value (None for required and nullable fields)."""
        if self.nullable or self.flags & REQUIRED:
            return None
        if self.kind in (KIND_STRING, KIND_PATH, KIND_JSON):
            return json.loads(self.text)
        values = [self.from_number(v) for v in self.default_value[: self.count]]
        return values if self.count > 1 else values[0]

    def from_number(self, v: float):
        """A C number as its JSON value."""
        if self.kind == KIND_BOOL:
            return bool(v)
        if self.kind == KIND_ENUM:
            return self.choices[int(v)]
        if self.kind == KIND_INT:
            return int(v)
        return float(v)

    def to_number(self, v) -> float:
        """A JSON value (already type-checked) as the C number."""
        if self.kind == KIND_ENUM:
            return float(self.choices.index(v))
        return float(v)

    def rule(self) -> str:
        """What a value must be, for messages about JSON types."""
        if self.kind == KIND_BOOL:
            return "true or false"
        if self.kind == KIND_ENUM:
            return "one of " + ", ".join(f'"{c}"' for c in self.choices)
        if self.kind in (KIND_STRING, KIND_PATH):
            return "a string" + (" or null" if self.nullable else "")
        noun = "whole number" if self.kind == KIND_INT else "number"
        shape = f"a list of {self.count} {noun}s" if self.count > 1 else f"a {noun}"
        return shape + (" or null" if self.nullable else "") + (f" ({self.unit})" if self.unit else "")


@lru_cache(maxsize=None)
def rows() -> tuple[Param, ...]:
    """Every row the library declares (a row two structs share comes once for each)."""
    lib = native_library.library()
    out = []
    for i in range(lib.hh_param_count()):
        info = ParamInfo()
        info.struct_size = ctypes.sizeof(ParamInfo)
        native_library._check(lib.hh_param_info_get(i, ctypes.byref(info)))
        strings = {k: getattr(info, k).decode() for k in ("name", "json", "unit", "label", "text", "description",
                                                           "advice")}
        numbers = {k: getattr(info, k) for k in ("kind", "count", "flags", "structure", "offset", "min", "max",
                                                  "soft_min", "soft_max")}
        out.append(Param(**strings, **numbers, default_value=tuple(info.default_value)))
    return tuple(out)


@lru_cache(maxsize=None)
def table() -> tuple[Param, ...]:
    """The scene file's parameters, once each, in the table's order."""
    seen, out = set(), []
    for p in rows():
        if p.json and p.json not in seen:
            seen.add(p.json)
            out.append(p)
    return tuple(out)


def by_json(path: str) -> Param:
    for p in table():
        if p.json == path:
            return p
    raise KeyError(path)


@lru_cache(maxsize=None)
def structure(struct_id: int) -> type:
    """The ctypes structure of a C parameter struct, field by field from the table, checked
    against the library's size of it."""
    fields = sorted({p.offset: p for p in rows() if p.structure == struct_id}.values(), key=lambda p: p.offset)
    layout = [("struct_size", ctypes.c_int)]
    for p in fields:
        ctype = ctypes.c_double if p.kind == KIND_DOUBLE else ctypes.c_int
        layout.append((p.name, ctype * p.count if p.count > 1 else ctype))
    c_name = native_library.STRUCT_NAMES[struct_id]
    cls = type(c_name, (ctypes.Structure,), {"_fields_": layout, "rows": tuple(fields)})
    native_library.check_layout(cls, c_name)
    if not all(getattr(cls, p.name).offset == p.offset for p in fields):
        raise native_library.NativeError(f"{c_name}'s fields lie elsewhere in the native library than its table "
                                         "says (a stale build?): rebuild it with `make native`")
    return cls


def new_struct(struct_id: int, values: dict | None = None):
    """A C parameter struct with the table's defaults, then `values` (C field name -> C value)."""
    s = structure(struct_id)()
    fill = {STRUCT_PARAMS: "hh_default_params", STRUCT_WORLD_PARAMS: "hh_default_world_params",
            STRUCT_MATERIAL: "hh_default_material", STRUCT_SESSION_PARAMS: "hh_default_session_params"}[struct_id]
    getattr(native_library.library(), fill)(ctypes.byref(s))
    names = {p.name: p for p in s.rows}
    for name, value in (values or {}).items():
        if name not in names:
            raise native_library.InvalidInput(f"unknown parameter '{name}'; known: {', '.join(names)}")
        p = names[name]
        if p.count > 1:
            value = (ctypes.c_double * p.count)(*[float(v) for v in value])
        elif p.kind != KIND_DOUBLE:
            value = int(value)
        else:
            value = float(value)
        setattr(s, name, value)
    return s


def struct_values(s) -> dict:
    """A C parameter struct's fields as {C name: value} (vectors as lists)."""
    out = {}
    for p in s.rows:
        v = getattr(s, p.name)
        out[p.name] = list(v) if isinstance(v, ctypes.Array) else v
    return out


def defaults(body: bool = False, element: str | None = None) -> dict:
    """The scene's defaults as nested dicts (a body's with body=True, or those of the objects of
    the list `element`, BODY or BONE), from the table."""
    element = (BODY if body else "") if element is None else element
    out: dict = {}
    for p in table():
        if p.element != element or p.flags & INTERNAL:
            continue
        node = out
        for k in p.keys[:-1]:
            node = node.setdefault(k, {})
        node[p.keys[-1]] = p.default
    return out


def get(data: dict, p: Param):
    node = data
    for k in p.keys:
        node = node[k]
    return node


def put(data: dict, p: Param, value) -> None:
    node = data
    for k in p.keys[:-1]:
        node = node.setdefault(k, {})
    node[p.keys[-1]] = value


def _json_type_ok(p: Param, v) -> bool:
    def number(x):
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            return False
        return p.kind != KIND_INT or (math.isfinite(x) and x == int(x))

    if v is None:
        return p.nullable or p.kind == KIND_JSON
    if p.kind == KIND_BOOL:
        return isinstance(v, bool)
    if p.kind == KIND_ENUM:
        return isinstance(v, str) and v in p.choices
    if p.kind in (KIND_STRING, KIND_PATH):
        return isinstance(v, str)
    if p.kind == KIND_JSON:
        return True
    if p.count > 1:
        return isinstance(v, (list, tuple)) and len(v) == p.count and all(number(x) for x in v)
    return number(v)


def check(p: Param, value, where: str | None = None) -> None:
    """Refuses a value of the wrong JSON type (here) or out of range (the library's check, the
    same the C structs get). `where` names the field in the message (e.g. bodies[2].friction)."""
    where = where or p.json
    if not _json_type_ok(p, value):
        raise ParamError(f"{where} = {json.dumps(value)} is invalid: it must be {p.rule()}; {p.advice}")
    if value is None or p.kind not in NUMERIC_KINDS:
        return
    numbers = [p.to_number(v) for v in (value if p.count > 1 else [value])]
    values = (ctypes.c_double * len(numbers))(*numbers)
    status = native_library.library().hh_param_check(p.json.encode(), values, len(numbers))
    if status != native_library.HH_OK:
        message = native_library.library().hh_last_error().decode("utf-8", "replace")
        raise ParamError(message.replace(p.json, where, 1) if where != p.json else message)
