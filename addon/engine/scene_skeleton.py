"""A scene's skeleton (docs/skeleton.md, Section 8): `hand.skeleton` (null, "procedural" or a
list of bones) and the `skeleton` section that drives the bones (keyed targets, a tracking
stream and its joint map, the root on the device), read and checked with messages that name
the field and the fix. What needs the tet nodes (each bone's capture) is checked when the
model is built, by the library, with the field named here (`capture_error`)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import params, tracking
from . import skeleton as sk
from .scene_fields import SceneError, check_fields, merge, vector

PROCEDURAL = "procedural"
SKELETON_FIELD = "hand.skeleton"
_EXAMPLE = ('{"name": "palm", "parent": null, "head": [0, 0, 0], "tail": [0, 0, -0.07], "radius": 0.03}')
_POSE_FIELDS = ("position", "quaternion")


@dataclass
class BoneTrack:
    """One bone's keys: times (k,), turns from rest (k, 4) and head offsets from rest (k, 3),
    or None when its keys give no position (its head then rides on its parent)."""

    times: np.ndarray
    quaternions: np.ndarray
    positions: np.ndarray | None


@dataclass
class SceneSkeleton:
    skeleton: sk.Skeleton
    drive_scales: np.ndarray
    tracks: dict = field(default_factory=dict)  # bone index -> BoneTrack (skeleton.targets)
    stream: tracking.TrackingStream | None = None
    tracking_map: dict | None = None  # {joint: bone} of the stream
    root_device: bool = False
    prescribed: bool = False  # every driven bone reaches its target (skeleton.drive.prescribed)


def parse(data: dict, base_dir: Path) -> SceneSkeleton | None:
    """The scene's skeleton and what drives it; None for the palm handle (hand.skeleton null)."""
    given = data["hand"]["skeleton"]
    section = data["skeleton"]
    if given is None:
        _refuse_drive_without_skeleton(section)
        return None
    if given == PROCEDURAL:
        skeleton, scales = sk.procedural_hand_skeleton(), np.ones(16)
    elif isinstance(given, list):
        skeleton, scales = bones(given)
    else:
        raise SceneError(f"{SKELETON_FIELD} = {json.dumps(given)[:60]} is invalid: use null (the palm handle), "
                         f'"{PROCEDURAL}" (the procedural hand\'s 16 bones) or a list of bones, e.g. [{_EXAMPLE}]')
    out = SceneSkeleton(skeleton, scales, root_device=bool(section["root_device"]),
                        prescribed=bool(section["drive"]["prescribed"]))
    out.tracks = targets(section["targets"], skeleton)
    if section["tracking"] is not None:
        if out.tracks:
            raise SceneError("skeleton.targets and skeleton.tracking both drive the bones: give one of them")
        out.stream, out.tracking_map = stream(section, skeleton, base_dir)
    elif section["tracking_map"] is not None:
        raise SceneError("skeleton.tracking_map is given without skeleton.tracking: give the stream it maps, or "
                         "remove the map")
    return out


def _refuse_drive_without_skeleton(section: dict) -> None:
    given = [name for name, value, default in (("targets", section["targets"], []),
                                               ("tracking", section["tracking"], None),
                                               ("tracking_map", section["tracking_map"], None),
                                               ("root_device", section["root_device"], False),
                                               ("drive.prescribed", section["drive"]["prescribed"], False))
             if value != default]
    if given:
        raise SceneError(f"skeleton.{given[0]} drives a skeleton's bones, but hand.skeleton is null (the palm "
                         f'handle): set hand.skeleton ("{PROCEDURAL}" or a list of bones) or remove it')
    joints = [name for name in ("stiffness", "damping", "limit_stiffness", "limit_damping")
              if section["joints"][name] != 0]
    if joints:  # the table's rows reach the model as they are; the palm handle has no joints to give them to
        raise SceneError(f"skeleton.joints.{joints[0]} ties bones to their parents, but hand.skeleton is null (the "
                         f'palm handle, one bone): set hand.skeleton ("{PROCEDURAL}" or a list of bones) or set '
                         f"it to 0")


# --------------------------------------------------------------------------------------------
# hand.skeleton as a list of bones
# --------------------------------------------------------------------------------------------


def bones(specs: list) -> tuple[sk.Skeleton, np.ndarray]:
    """A skeleton from the JSON list of bones, each merged over the table's bone defaults."""
    if not specs:
        raise SceneError(f"{SKELETON_FIELD} = [] has no bones: give at least one, e.g. [{_EXAMPLE}], or null for "
                         "the palm handle")
    out, scales, owners = [], [], {}
    for i, given in enumerate(specs):
        spec, label = _bone_spec(i, given)
        nodes = _explicit_nodes(spec, label, owners)
        if nodes is None and spec["radius"] is None:
            raise SceneError(f"{label} has neither a radius nor nodes: give its capsule radius (m) or the tet nodes "
                             "it holds")
        if nodes is not None and spec["radius"] is not None:
            raise SceneError(f"{label} has both a radius and nodes: give one (radius: it holds the nodes near its "
                             "segment; nodes: exactly those)")
        out.append(sk.Bone(spec["name"], spec["parent"], np.asarray(spec["head"], float),
                           np.asarray(spec["tail"], float), 0.0 if nodes is not None else float(spec["radius"]),
                           nodes, limits=_limits(spec, label), axes=_axes(spec, label)))
        scales.append(float(spec["drive_scale"]))
    _check_names(out)
    try:
        return sk.Skeleton(out), np.array(scales)
    except sk.SkeletonError as e:
        raise SceneError(f"{SKELETON_FIELD}: {e}") from None


def _bone_spec(i: int, given) -> tuple[dict, str]:
    if not isinstance(given, dict):
        raise SceneError(f"{SKELETON_FIELD}[{i}] = {json.dumps(given)[:60]} is invalid: each bone must be an object, "
                         f"e.g. {_EXAMPLE}")
    name = given.get("name")
    label = f"{SKELETON_FIELD}[{i}]" + (f" ('{name}')" if isinstance(name, str) else "")
    spec = merge(params.defaults(element=params.BONE), given, f"{label}.")
    check_fields(spec, where=lambda p: f"{label}.{p.json[len(params.BONE):]}", element=params.BONE)
    if not spec["name"]:
        raise SceneError(f"{label}.name is empty: give every bone a unique, non-empty name")
    return spec, label


def _limits(spec: dict, label: str) -> np.ndarray | None:
    """The bone's angular limits, (2, 3) rad (an axis null: free), or None."""
    given = spec["limits"]
    if given is None:
        return None
    example = '{"min": [-0.2, -1.5, -0.1], "max": [0.2, 0.1, 0.1]}'
    if not (isinstance(given, dict) and set(given) <= {"min", "max"}):
        raise SceneError(f"{label}.limits = {json.dumps(given)[:60]} is invalid: give {example} (radians, in the "
                         "bone's rest axes), or null for none")
    out = np.array([[-np.inf] * 3, [np.inf] * 3])
    for row, key in enumerate(("min", "max")):
        values = given.get(key)
        if values is None:
            continue
        if not (isinstance(values, list) and len(values) == 3 and
                all(v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)) for v in values)):
            raise SceneError(f"{label}.limits.{key} = {json.dumps(values)[:60]} is invalid: give three angles in "
                             f"radians (null for a free axis), e.g. {example}")
        for i, v in enumerate(values):
            if v is not None:
                out[row, i] = float(v)
    finite = out[np.isfinite(out)]
    if np.isnan(out).any() or (np.abs(finite) >= np.pi).any():
        raise SceneError(f"{label}.limits = {json.dumps(given)[:80]} is invalid: give angles within (-pi, pi) "
                         "radians (a rotation vector turns at most half a turn), or null for a free axis")
    if not (out[0] <= 0).all() or not (out[1] >= 0).all():
        raise SceneError(f"{label}.limits = {json.dumps(given)[:80]} does not hold the bone's rest pose: give each "
                         "axis a minimum <= 0 <= maximum")
    if spec["parent"] is None and np.isfinite(out).any():
        raise SceneError(f"{label} is a root with limits: a root turns with its target, not against a parent; "
                         "remove its limits")
    return out


def _axes(spec: dict, label: str) -> np.ndarray | None:
    """The bone's rest axes (3, 3), columns x, y, z, or None (the world's)."""
    given = spec["axes"]
    if given is None:
        return None
    try:
        axes = np.array(given, dtype=float)
    except (TypeError, ValueError):
        axes = None
    if axes is None or axes.shape != (3, 3) or not np.isfinite(axes).all() or \
            np.abs(axes.T @ axes - np.eye(3)).max() > 1e-6 or np.linalg.det(axes) <= 0:
        raise SceneError(f"{label}.axes = {json.dumps(given)[:80]} is not a rotation matrix: give the three rows of "
                         "the bone's rest rotation (its columns the x, y, z axes; orthonormal, right-handed), or "
                         "null for the world axes")
    return axes


def _explicit_nodes(spec: dict, label: str, owners: dict) -> np.ndarray | None:
    """The bone's explicit node list (None: capture by radius); a node already in another
    bone's list is refused (owners: node -> bone name so far)."""
    nodes = spec["nodes"]
    if nodes is None:
        return None
    whole = isinstance(nodes, list) and all(isinstance(i, int) and not isinstance(i, bool) and i >= 0 for i in nodes)
    if not whole:
        raise SceneError(f"{label}.nodes = {json.dumps(nodes)[:60]} is invalid: give a list of tet node indices "
                         "(whole numbers from 0), or null to capture by radius")
    for node in nodes:
        if owners.setdefault(node, spec["name"]) != spec["name"]:
            raise SceneError(f"{label}.nodes holds node {node}, which bone '{owners[node]}' holds too; a node "
                             "belongs to at most one bone: remove it from one of the lists")
    return np.array(sorted(set(nodes)), dtype=np.int64)


def _check_names(bone_list: list) -> None:
    names = [b.name for b in bone_list]
    for i, bone in enumerate(bone_list):
        if names.index(bone.name) != i:
            raise SceneError(f"{SKELETON_FIELD}[{i}] is named '{bone.name}' as bone {names.index(bone.name)} is: "
                             "give every bone a unique name")
        if bone.parent is not None and bone.parent not in names:
            raise SceneError(f"{SKELETON_FIELD}[{i}] ('{bone.name}').parent = '{bone.parent}' is not a bone of the "
                             f"list (its bones: {', '.join(names)}): name one of them, or null for a root")
    if bone_list[0].parent is not None:
        raise SceneError(f"{SKELETON_FIELD}[0] ('{bone_list[0].name}') has parent '{bone_list[0].parent}': the first "
                         "bone must be a root (parent null), the one the device and coupling.* drive")


def check_node_indices(skeleton: sk.Skeleton, n_nodes: int) -> None:
    """Every explicit node index names a tet node of the hand."""
    for i, bone in enumerate(skeleton.bones):
        if bone.nodes is not None and len(bone.nodes) and bone.nodes.max() >= n_nodes:
            raise SceneError(f"{SKELETON_FIELD}[{i}] ('{bone.name}').nodes holds node {int(bone.nodes.max())}, but the "
                             f"hand's tets have nodes 0..{n_nodes - 1}: give indices of hand.tets' nodes")


def capture_error(error: Exception) -> SceneError:
    """The library's refusal of a skeleton's capture (a bone holding fewer than 4 nodes, a node
    index out of range, every node held), with the field it comes from."""
    return SceneError(f"{SKELETON_FIELD}: {error}")


# --------------------------------------------------------------------------------------------
# skeleton.targets: timed bone poses
# --------------------------------------------------------------------------------------------


def targets(keys, skeleton: sk.Skeleton) -> dict[int, BoneTrack]:
    """{bone index: BoneTrack} from [{t, bones: {name: {position, quaternion}}}]."""
    where = "skeleton.targets"
    shape = f'{where} must be a list of keys {{"t": seconds, "bones": {{name: {{"quaternion": [x, y, z, w]}}}}}}'
    if not isinstance(keys, list):
        raise SceneError(f"{shape}, got {json.dumps(keys)[:60]}")
    samples: dict[int, list] = {}
    last = None
    for k, key in enumerate(keys):
        at = f"{where}[{k}]"
        t = _key_time(key, at, shape)
        if last is not None and not t > last:
            raise SceneError(f"{at}.t = {t} s comes after {last} s: key times must strictly increase")
        last = t
        for name, pose in key["bones"].items():
            if name not in skeleton.names:
                raise SceneError(f"{at}.bones names '{name}', which is not a bone of {SKELETON_FIELD} (its bones: "
                                 f"{', '.join(skeleton.names)})")
            samples.setdefault(skeleton.index(name), []).append((t,) + _bone_pose(pose, f"{at}.bones.{name}"))
    return {b: _track(rows, skeleton.names[b]) for b, rows in samples.items()}


def _key_time(key, at: str, shape: str) -> float:
    if not isinstance(key, dict):
        raise SceneError(f"{at} = {json.dumps(key)[:60]} is not an object: {shape}")
    unknown = set(key) - {"t", "bones"}
    if unknown:
        raise SceneError(f"{at} has unknown fields {', '.join(sorted(unknown))}: a key has t and bones")
    t = key.get("t")
    if isinstance(t, bool) or not isinstance(t, (int, float)) or not np.isfinite(t):
        raise SceneError(f"{at}.t = {json.dumps(t)} is invalid: it must be a finite number of seconds")
    if not isinstance(key.get("bones"), dict):
        raise SceneError(f"{at}.bones = {json.dumps(key.get('bones'))[:60]} is invalid: give an object "
                         '{bone name: {"position": [x, y, z], "quaternion": [x, y, z, w]}}')
    return float(t)


def _bone_pose(pose, at: str) -> tuple:
    if not isinstance(pose, dict) or set(pose) - set(_POSE_FIELDS):
        raise SceneError(f"{at} = {json.dumps(pose)[:60]} is invalid: give an object with quaternion (its turn from "
                         "rest, x, y, z, w) and, if its head moves on its own, position (the head's offset from rest, "
                         "m)")
    q = vector(pose.get("quaternion", [0, 0, 0, 1]), 4, f"{at}.quaternion")
    if not np.linalg.norm(q) > 1e-12:
        raise SceneError(f"{at}.quaternion is zero: give a unit quaternion (x, y, z, w); [0, 0, 0, 1] is no turn")
    p = vector(pose["position"], 3, f"{at}.position") if "position" in pose else None
    return q / np.linalg.norm(q), p


def _track(rows: list, name: str) -> BoneTrack:
    with_position = [p is not None for _, _, p in rows]
    if any(with_position) and not all(with_position):
        raise SceneError(f"skeleton.targets: bone '{name}' has a position in some keys and not in others: give it in "
                         "every key of the bone, or in none (its head then rides on its parent)")
    positions = np.array([p for _, _, p in rows]) if all(with_position) else None
    return BoneTrack(np.array([t for t, _, _ in rows]), np.array([q for _, q, _ in rows]), positions)


# --------------------------------------------------------------------------------------------
# skeleton.tracking and skeleton.tracking_map
# --------------------------------------------------------------------------------------------


def stream(section: dict, skeleton: sk.Skeleton, base_dir: Path) -> tuple[tracking.TrackingStream, dict]:
    path = Path(base_dir) / section["tracking"]
    try:
        read = tracking.read(path)
    except tracking.TrackingError as e:
        raise SceneError(f"skeleton.tracking: {e}") from None
    joint_map = section["tracking_map"]
    if joint_map is None:
        joint_map = tracking.PROCEDURAL_MAPS[read.layout.name]
        hint = (f"skeleton.tracking_map is null, so the {read.layout.name} layout's map onto the procedural hand's "
                "bones is used")
    else:
        hint = "skeleton.tracking_map"
        valid = isinstance(joint_map, dict) and all(isinstance(b, str) for b in joint_map.values())
        if not valid:
            raise SceneError(f"skeleton.tracking_map = {json.dumps(joint_map)[:60]} is invalid: give an object "
                             '{joint: bone name}, e.g. {"wrist": "palm"}, or null for the procedural hand\'s map')
    try:
        tracking.check_map(read.layout, skeleton, joint_map)
    except tracking.TrackingError as e:
        raise SceneError(f"{hint}: {e}" + ("; give skeleton.tracking_map for this skeleton's bones"
                                            if section["tracking_map"] is None else "")) from None
    return read, joint_map
