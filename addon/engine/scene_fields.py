"""The scene file's fields as the scene and its bodies read them (docs/scene_format.md): given
fields merged over the table's defaults, each field against its JSON type and the library's
range, vectors, and timed poses. Messages name the field and the fix."""

from __future__ import annotations

import json

import numpy as np

from . import native, params


class SceneError(ValueError):
    """A scene file that cannot be used; the message names the field and the fix."""


def merge(defaults: dict, given: dict, where: str) -> dict:
    """The defaults with the given fields over them (nested objects merged); an unknown field,
    or a value where an object belongs, is refused. `where` prefixes the field's name."""
    out = dict(defaults)
    for key, value in given.items():
        if key not in defaults:
            raise SceneError(f"unknown field '{where}{key}'; known fields here: {', '.join(defaults)}")
        if isinstance(defaults[key], dict) and isinstance(value, dict):
            out[key] = merge(defaults[key], value, f"{where}{key}.")
        elif isinstance(defaults[key], dict):
            raise SceneError(f"{where}{key} = {json.dumps(value)} is invalid: it must be an object with the fields "
                             f"{', '.join(defaults[key])}")
        else:
            out[key] = value
    return out


def check_fields(data: dict, body: bool = False, where=None, element: str | None = None) -> None:
    """Every table field of a scene (or of one body, body=True, or of one object of the list
    `element`) against its JSON type and range; `where` turns a field's path into the name the
    message gives."""
    element = (params.BODY if body else "") if element is None else element
    for p in params.table():
        if p.element == element and not p.flags & params.INTERNAL:
            try:
                params.check(p, params.get(data, p), where(p) if where else None)
            except params.ParamError as e:
                raise SceneError(str(e)) from None


def vector(value, n: int, name: str) -> np.ndarray:
    numbers = isinstance(value, (list, tuple)) and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) for x in value)
    if not numbers:
        raise SceneError(f"{name} must be a list of {n} numbers, got {json.dumps(value, default=str)[:60]}")
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise SceneError(f"{name} must be {n} finite numbers, got {json.dumps(value, default=str)[:60]}")
    return v


def timed_poses(points, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times, positions, unit quaternions) of a JSON list of {t, position, quaternion} objects;
    SceneError naming `where` (e.g. device.trajectory) for anything else. The JSON types are
    checked here, the values (times increasing, quaternions non-zero) by the library."""
    shape = f"{where} must be a non-empty list of {{t, position, quaternion}} objects"
    if not isinstance(points, list) or not points:
        raise SceneError(f"{shape}, got {json.dumps(points)[:60]}")
    for i, p in enumerate(points):
        if not isinstance(p, dict):
            raise SceneError(f"{where}[{i}] = {json.dumps(p)[:60]} is not an object: give each point as "
                             "{\"t\": seconds, \"position\": [x, y, z], \"quaternion\": [x, y, z, s]}")
        unknown = set(p) - {"t", "position", "quaternion"}
        if unknown:
            raise SceneError(f"{where}[{i}] has unknown fields {', '.join(sorted(unknown))}: use t, position, quaternion")
        t = p.get("t")
        if isinstance(t, bool) or not isinstance(t, (int, float)):
            raise SceneError(f"{where}[{i}].t = {json.dumps(t)} is invalid: it must be a finite number of seconds")
    times = np.array([float(p["t"]) for p in points])
    pos = np.array([vector(p.get("position", [0, 0, 0]), 3, f"{where}[{i}].position") for i, p in enumerate(points)])
    quat = np.array([vector(p.get("quaternion", [0, 0, 0, 1]), 4, f"{where}[{i}].quaternion")
                     for i, p in enumerate(points)])
    try:
        native.check_trajectory(times, pos, quat)
    except native.InvalidInput as e:
        raise SceneError(str(e).replace("trajectory", where, 1)) from None
    return times, pos, quat / np.linalg.norm(quat, axis=1)[:, None]
