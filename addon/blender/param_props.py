"""The parameter table as Blender properties, and the one mapping between them and the scene.

Each row the table keeps in Blender (HH_UI_SCENE: the scene's settings; HH_UI_OBJECT: each
object's) becomes a property with the row's label, description (the tooltip, with the unit),
default, limits and unit. Lengths follow the scene's unit scale: the value is stored in metres
(a hidden `<name>_si`) and shown in the scene's units, so a radius typed as 2 in a centimetre
scene is 2 cm. A JSON row is a switch (JSON_SWITCHES) or its JSON as text. Values are read and
written in SI through `get_si` and `set_si`; `to_scene` and `from_scene` map a settings block to
and from the scene file's fields.
"""

from __future__ import annotations

import json
import math

import bpy
import numpy as np

from ..engine import params

# The table's units as Blender units (the rest are shown as numbers, the unit in the tooltip).
BLENDER_UNITS = {"m": "LENGTH", "s": "TIME_ABSOLUTE", "kg": "MASS", "m/s": "VELOCITY", "m/s^2": "ACCELERATION",
                 "Hz": "FREQUENCY"}


def _path_options() -> set:
    """Options of a file-path property: blend-relative paths (//) allowed where Blender asks
    (PATH_SUPPORTS_BLEND_RELATIVE, Blender 4.5 and newer; older ones take // everywhere and
    refuse the option when the property registers)."""
    if "is_path_supports_blend_relative" in bpy.types.Property.bl_rna.properties:
        return {"PATH_SUPPORTS_BLEND_RELATIVE"}
    return set()


PATH_OPTIONS = _path_options()


def rows(where: int) -> list[params.Param]:
    """The rows kept on the scene's settings (params.UI_SCENE) or each object's (UI_OBJECT), once
    per property name (two rows sharing a name share their declaration: the tetrahedralize
    settings of the hand and of a soft body, the density of soft and rigid bodies)."""
    out, seen = [], {}
    for p in params.table():
        if not p.flags & where:
            continue
        if p.name in seen:
            _require_same(seen[p.name], p)
            continue
        seen[p.name] = p
        out.append(p)
    return out


def _require_same(a: params.Param, b: params.Param) -> None:
    same = (a.kind, a.count, a.unit, a.default_value, a.min, a.max) == (b.kind, b.count, b.unit, b.default_value,
                                                                        b.min, b.max)
    if not same:
        raise RuntimeError(f"the parameter table gives '{a.json}' and '{b.json}' the same Blender name "
                           f"'{a.name}' but different values: rename one")


def _limits(p: params.Param) -> dict:
    """Blender's hard and soft limits from the row's range (an open bound just inside it)."""
    out = {}
    if math.isfinite(p.min):
        out["min"] = p.min + (max(abs(p.min) * 1e-9, 1e-12) if p.flags & params.OPEN_MIN else 0.0)
    if math.isfinite(p.max):
        out["max"] = p.max - (max(abs(p.max) * 1e-9, 1e-12) if p.flags & params.OPEN_MAX else 0.0)
    if p.flags & params.ZERO_OR_RANGE:
        out["min"] = 0.0
    lo, hi = out.get("min", -math.inf), out.get("max", math.inf)
    out["soft_min"] = min(max(p.soft_min, lo), hi)
    out["soft_max"] = max(min(p.soft_max, hi), out["soft_min"])
    return out


def tooltip(p: params.Param) -> str:
    """The row's description (less where Blender takes it from: the tooltip is on that place),
    its unit and its scene-file field."""
    unit = f" ({p.unit})" if p.unit and p.unit not in BLENDER_UNITS else ""
    return f"{p.description.split('; in Blender, ')[0]}{unit}. Scene file: {p.json}"


def _unit(p: params.Param) -> str:
    unit = BLENDER_UNITS.get(p.unit, "NONE")
    available = {i.identifier for i in bpy.types.FloatProperty.bl_rna.properties["unit"].enum_items}
    return unit if unit in available else "NONE"


def _scale(settings) -> float:
    """Metres per Blender unit of the scene that owns these settings."""
    scene = settings.id_data if isinstance(settings.id_data, bpy.types.Scene) else bpy.context.scene
    return float(scene.unit_settings.scale_length) if scene is not None else 1.0


def _length(p: params.Param, update) -> dict:
    """A length stored in metres (`<name>_si`) and shown in the scene's units."""
    si = f"{p.name}_si"

    def get(self):
        return getattr(self, si) / _scale(self)

    def set(self, value):
        setattr(self, si, value * _scale(self))

    limits = _limits(p)
    stored = bpy.props.FloatProperty(default=p.default_value[0], options={"HIDDEN"},
                                     description=f"{p.label} in metres (what the engine gets)",
                                     **{k: v for k, v in limits.items() if k in ("min", "max")})
    shown = bpy.props.FloatProperty(name=p.label, description=tooltip(p), get=get, set=set, unit="LENGTH",
                                    precision=4, update=update, **limits)
    return {si: stored, p.name: shown}


def _number(p: params.Param, update) -> dict:
    small = 0 < abs(p.default_value[0]) < 1e-2 or 0 < p.soft_min < 1e-2
    kw = dict(name=p.label, description=tooltip(p), default=p.default_value[0], update=update, **_limits(p))
    if p.kind == params.KIND_INT:
        kw = {k: int(v) if k != "update" and isinstance(v, float) else v for k, v in kw.items()}
        kw = {k: max(min(v, 2**31 - 1), -(2**31)) if isinstance(v, int) else v for k, v in kw.items()}
        return {p.name: bpy.props.IntProperty(**kw)}
    return {p.name: bpy.props.FloatProperty(unit=_unit(p), precision=6 if small else 3, **kw)}


def annotations(where: int, updates: dict | None = None) -> dict:
    """bpy property definitions for the rows kept at `where`, by name (`updates`: name ->
    callback run when the property changes)."""
    out = {}
    for p in rows(where):
        if p.nullable and p.kind in params.NUMERIC_KINDS:
            out[f"use_{p.name}"] = bpy.props.BoolProperty(
                name=f"Set {p.label.lower()}", default=False,
                description=f"Give {p.label.lower()} a value of its own (off: {p.description.split('(null: ')[-1]}")
        out.update(row_properties(p, (updates or {}).get(p.name)))
    return out


def row_properties(p: params.Param, update=None) -> dict:
    """The bpy property definitions of one row, by name (a length's two: shown and in metres)."""
    if p.kind == params.KIND_BOOL:
        return {p.name: bpy.props.BoolProperty(name=p.label, description=tooltip(p), default=bool(p.default_value[0]),
                                               update=update)}
    if p.kind == params.KIND_ENUM:
        items = [(c, c.replace("_", " ").capitalize(), f"{p.json} = \"{c}\"") for c in p.choices]
        return {p.name: bpy.props.EnumProperty(name=p.label, description=tooltip(p), items=items,
                                               default=p.choices[int(p.default_value[0])], update=update)}
    if p.kind in (params.KIND_PATH, params.KIND_STRING):
        path = {"subtype": "FILE_PATH", "options": PATH_OPTIONS} if p.kind == params.KIND_PATH else {}
        return {p.name: bpy.props.StringProperty(name=p.label, description=tooltip(p) + " (empty: null)", **path)}
    if p.kind == params.KIND_JSON and p.json in JSON_SWITCHES:
        return {p.name: bpy.props.BoolProperty(name=p.label, description=tooltip(p), default=False)}
    if p.kind == params.KIND_JSON:
        return {p.name: bpy.props.StringProperty(name=p.label, description=tooltip(p) + " (JSON; empty: null)")}
    if p.unit == "m":
        return _length(p, update)
    return _number(p, update)


def get_si(settings, p: params.Param):
    """The scene-file value of a row from Blender settings (SI, enums by name, None for null)."""
    if p.nullable and p.kind in params.NUMERIC_KINDS and not getattr(settings, f"use_{p.name}"):
        return None
    if p.kind == params.KIND_DOUBLE and p.unit == "m":
        return decimal(getattr(settings, f"{p.name}_si"))
    value = getattr(settings, p.name)
    if p.kind in (params.KIND_PATH, params.KIND_STRING):
        return bpy.path.abspath(value) if value and p.kind == params.KIND_PATH else (value or None)
    if p.kind == params.KIND_JSON and p.json in JSON_SWITCHES:  # a switch between null and one value
        return json_switch_value(p) if value else None
    if p.kind == params.KIND_JSON:
        return json_text_value(p, value)
    if p.kind == params.KIND_DOUBLE:
        return decimal(value)
    return value if p.kind == params.KIND_ENUM else (bool(value) if p.kind == params.KIND_BOOL else int(value))


def decimal(value: float) -> float:
    """Blender keeps floats in single precision: the shortest decimal that is the same single
    (0.03, not 0.029999999329447746), so a value typed or imported comes back as written."""
    return float(np.format_float_positional(np.float32(value), unique=True, trim="-"))


def set_si(settings, p: params.Param, value) -> None:
    """Writes a scene-file value of a row into Blender settings."""
    if p.nullable and p.kind in params.NUMERIC_KINDS:
        setattr(settings, f"use_{p.name}", value is not None)
        if value is None:
            return
    if p.kind == params.KIND_DOUBLE and p.unit == "m":
        setattr(settings, f"{p.name}_si", float(value))
    elif p.kind in (params.KIND_PATH, params.KIND_STRING):
        setattr(settings, p.name, "" if value is None else str(value))
    elif p.kind == params.KIND_JSON and p.json not in JSON_SWITCHES:
        setattr(settings, p.name, "" if value is None else json.dumps(value))
    elif p.kind == params.KIND_JSON:
        if value not in (None, json_switch_value(p)):
            raise ValueError(f"{p.json} = {value!r} cannot be kept in Blender: it takes null or "
                             f"{json_switch_value(p)!r} ({p.label})")
        setattr(settings, p.name, value is not None)
    else:
        setattr(settings, p.name, value)


# JSON rows Blender keeps as a switch: off is null, on is this value. The other JSON rows kept
# in Blender are kept as their JSON text (empty: null).
JSON_SWITCHES = {"bodies[].fixed": "bottom"}


def json_switch_value(p: params.Param):
    return JSON_SWITCHES[p.json]


class SettingError(ValueError):
    """A setting Blender keeps as text that does not read as its scene-file value."""


def json_text_value(p: params.Param, text: str):
    """A JSON row kept as text (the other JSON rows): its value, None when empty."""
    if not text.strip():
        return None
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise SettingError(f"{p.label} ({p.json}) is not valid JSON ({e.msg} at character {e.pos}): give "
                           f"{p.advice}, or leave it empty") from None


def selected(where: int, body_type: str | None = None, prefix: str | None = None):
    """The rows kept at `where`: a body's rows of type `body_type` when it is given, else the
    scene's; `prefix` limits them to JSON paths that start with it."""
    for p in params.table():
        if not p.flags & where or (prefix and not p.json.startswith(prefix)):
            continue
        if p.body == (body_type is not None) and (body_type is None or p.applies_to(body_type)):
            yield p


def to_scene(settings, data: dict, where: int, body_type: str | None = None, prefix: str | None = None) -> None:
    """Puts the fields kept at `where` into the scene dict `data` (see `selected`)."""
    for p in selected(where, body_type, prefix):
        params.put(data, p, get_si(settings, p))


def from_scene(settings, data: dict, where: int, body_type: str | None = None, prefix: str | None = None) -> None:
    """The reverse of to_scene: the fields of `data` kept at `where` into the settings."""
    for p in selected(where, body_type, prefix):
        set_si(settings, p, params.get(data, p))
