"""A rigged hand's armature as the engine's skeleton (docs/blender.md, "Rigging"; the scene
file's `hand.skeleton`, docs/skeleton.md Section 1).

Every deforming bone of the armature chosen in Rig > Skeleton becomes a bone of the skeleton:
its rest head and tail in world metres (the armature's rest pose through its object's matrix
and the scene's unit scale), its parent the nearest deforming ancestor, and what it holds:

- *Capsule* (the default): the tet nodes within its radius of its rest segment (the nearest
  bone wins). Its *Radius* is the bone's own when set; otherwise 1.15 times the limb's own
  radius there, the median distance from the segment of the render-mesh vertices nearest to
  it (among all the bones), as the procedural hand's bones are 1.15 times its fingers.
- *Vertex group*: the tet nodes of the group named like the bone. A group of that name on the
  tet mesh gives its nodes exactly (an imported scene's node lists come back this way);
  otherwise the hand mesh's own group (Blender's skinning groups are named after the bones):
  its vertices weighted above *Group weight*, and the tet nodes whose nearest render vertex is
  one of them (the group's region of the flesh, inside as well as on the skin).

`rig(scene)` gathers the bones and what they capture with engine/skeleton.py's rule, and lists
each problem (a bone holding fewer than 4 nodes or nodes on a line, a node in two bones' groups,
a missing group, every node held) with its fix; the panel lists it, Check Rig reports it and
the export refuses it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..engine import params
from ..engine import skeleton as sk
from . import hand_source, meshdata, param_props

CAPTURES = [
    ("CAPSULE", "Capsule", "The bone holds the tet nodes within its radius of its rest segment (the nearest bone "
                           "wins)"),
    ("GROUP", "Vertex group", "The bone holds the tet nodes of the vertex group named like it (the tet mesh's, or "
                              "the hand's skinning group above Group weight)"),
]
# The automatic capsule radius over the limb's own radius: the procedural hand's finger bones
# are 1.15 times their fingers (docs/skeleton.md, Section 9), so they reach the skin's nodes.
LIMB_MARGIN = 1.15


class RigError(ValueError):
    """An armature that cannot be the hand's skeleton; the message names the bone and the fix."""


@dataclass
class RigBone:
    name: str
    parent: str | None
    head: np.ndarray          # m, world, rest
    tail: np.ndarray
    radius: float | None      # m: a capsule's radius (its own or automatic); None for a group
    nodes: np.ndarray | None  # the tet nodes of its group
    drive_scale: float
    limits: np.ndarray | None = None  # (2, 3) rad from its IK limits (engine/skeleton.Bone.limits)
    axes: np.ndarray | None = None    # (3, 3) its rest axes in the world, the frame of its limits
    auto_radius: bool = False
    source: str = ""          # where a group bone's nodes come from
    exact: bool = False       # they are a group of the tet mesh (else of the hand's skinning weights)
    count: int = 0            # nodes it captures
    problems: list = field(default_factory=list)


@dataclass
class Rig:
    bones: list
    owner: np.ndarray         # each tet node's bone (-1: flesh only)
    problems: list            # every problem, each with its fix

    def specs(self) -> list[dict]:
        """The scene file's bone list (hand.skeleton), numbers as Blender keeps them (single
        precision, shortest decimals), so an export read back exports the same."""
        out = []
        for b in self.bones:
            out.append({"name": b.name, "parent": b.parent, "head": _decimals(b.head), "tail": _decimals(b.tail),
                        "radius": None if b.radius is None else param_props.decimal(b.radius),
                        "nodes": None if b.nodes is None else [int(i) for i in b.nodes],
                        "drive_scale": param_props.decimal(b.drive_scale)})
            if b.limits is not None:
                out[-1]["limits"] = {key: [None if math.isinf(x) else param_props.decimal(x) for x in row]
                                     for key, row in zip(("min", "max"), b.limits)}
                out[-1]["axes"] = [[float(x) for x in row] for row in b.axes]
        return out


def _decimals(v) -> list[float]:
    return [param_props.decimal(x) for x in v]


def bone_rows() -> dict[str, params.Param]:
    """The parameter table's rows a bone's settings show: its radius and drive scale."""
    return {key: params.by_json(f"{params.BONE}{key}") for key in ("radius", "drive_scale")}


def deform_bones(arm_obj) -> list[tuple[object, str | None]]:
    """(bone, parent name) of the armature's deforming bones, every parent before its children
    (the armature's order otherwise), the parent being the nearest deforming ancestor."""
    bones = [b for b in arm_obj.data.bones if b.use_deform]
    names = {b.name for b in bones}

    def parent(bone):
        p = bone.parent
        while p is not None and p.name not in names:
            p = p.parent
        return None if p is None else p.name

    out, placed = [], set()
    while len(out) < len(bones):
        for b in bones:
            p = parent(b)
            if b.name not in placed and (p is None or p in placed):
                out.append((b, p))
                placed.add(b.name)
    return out


def ik_limits(pose_bone) -> np.ndarray | None:
    """The pose bone's IK limits as angular limits (2, 3) rad, in its own axes: a locked axis
    [0, 0], a limited one [ik_min, ik_max], any other free; None when no axis is limited."""
    out = np.array([[-np.inf] * 3, [np.inf] * 3])
    for i, axis in enumerate("xyz"):
        if getattr(pose_bone, f"lock_ik_{axis}"):
            out[:, i] = 0.0
        elif getattr(pose_bone, f"use_ik_limit_{axis}"):
            out[:, i] = getattr(pose_bone, f"ik_min_{axis}"), getattr(pose_bone, f"ik_max_{axis}")
    return None if np.isinf(out).all() else out


def limits_text(limits: np.ndarray | None) -> str:
    """The bone list's words for its limits, in degrees as Blender shows angles: each limited
    axis's range, a locked one as locked; '' without limits."""
    if limits is None:
        return ""
    parts = []
    for axis, lo, hi in zip("xyz", limits[0], limits[1]):
        if lo == hi == 0:
            parts.append(f"{axis} locked")
        elif np.isfinite(lo) or np.isfinite(hi):
            parts.append(f"{axis} {math.degrees(lo):.0f}°..{math.degrees(hi):.0f}°")
    return "limits " + ", ".join(parts)


def rest_axes(arm_obj, bone) -> np.ndarray:
    """The bone's rest axes in the world (columns x, y, z): its rest matrix through the armature
    object's, without the object's scale (the orthogonal factor of their polar decomposition; a
    reflection when the armature is mirrored)."""
    m = meshdata.matrix(arm_obj)[:3, :3] @ np.array(bone.matrix_local, dtype=np.float64)[:3, :3]
    u, _, vt = np.linalg.svd(m)
    return u @ vt


def rest_segments(arm_obj, bones, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Rest heads and tails (B, 3) in world metres."""
    m = meshdata.matrix(arm_obj)
    heads = np.array([b.head_local for b in bones], dtype=np.float64).reshape(-1, 3)
    tails = np.array([b.tail_local for b in bones], dtype=np.float64).reshape(-1, 3)
    return meshdata.transform(m, heads) * scale, meshdata.transform(m, tails) * scale


_radii_memo: dict = {}  # the last auto_radii, by its arguments' bytes (the panel and the viewport redraw)


def auto_radii(heads: np.ndarray, tails: np.ndarray, surface: np.ndarray) -> np.ndarray:
    """LIMB_MARGIN times each segment's limb radius: the median distance to it of the surface
    points nearest to it; a bone no point is nearest to gets a tenth of its length (it will
    hold too few nodes, and says so)."""
    key = hash(heads.tobytes() + tails.tobytes() + surface.tobytes())
    if key not in _radii_memo:
        _radii_memo.clear()
        _radii_memo[key] = _limb_radii(heads, tails, surface)
    return _radii_memo[key].copy()


def _limb_radii(heads: np.ndarray, tails: np.ndarray, surface: np.ndarray) -> np.ndarray:
    d = np.stack([sk.segment_distance(surface, h, t) for h, t in zip(heads, tails)], axis=1)
    nearest = np.argmin(d, axis=1)
    out = np.empty(len(heads))
    for b in range(len(heads)):
        mine = d[nearest == b, b]
        out[b] = LIMB_MARGIN * np.median(mine) if len(mine) else 0.1 * np.linalg.norm(tails[b] - heads[b])
    return np.maximum(out, 1e-4)


def vertex_weights(obj) -> dict[str, np.ndarray]:
    """Each vertex group of obj by name: every vertex's weight in it (0 outside), one pass."""
    if not obj.vertex_groups:
        return {}
    weights = np.zeros((len(obj.data.vertices), len(obj.vertex_groups)))
    for v in obj.data.vertices:
        for g in v.groups:
            weights[v.index, g.group] = g.weight
    return {group.name: weights[:, group.index] for group in obj.vertex_groups}


class _Groups:
    """The tet nodes of bones captured by vertex groups (see the module's docstring)."""

    def __init__(self, hand, tet_obj, nodes: np.ndarray, surface: np.ndarray, threshold: float):
        self.hand, self.tet_obj, self.threshold = hand, tet_obj, threshold
        self.nodes, self.surface = nodes, surface
        self._nearest = None
        self._weights = {}

    def weights(self, obj) -> dict[str, np.ndarray]:
        if obj.name not in self._weights:
            self._weights[obj.name] = vertex_weights(obj)
        return self._weights[obj.name]

    def nearest_vertex(self) -> np.ndarray:
        if self._nearest is None:
            from scipy.spatial import cKDTree

            self._nearest = cKDTree(self.surface).query(self.nodes)[1]
        return self._nearest

    def nodes_of(self, name: str) -> tuple[np.ndarray | None, str, bool]:
        """(the bone's nodes, None when no group has its name; where they come from; whether
        they are the tet mesh's group, exactly)."""
        exact = self.weights(self.tet_obj).get(name) if self.tet_obj is not None else None
        if exact is not None:
            return np.flatnonzero(exact > 0), f"the group '{name}' of '{self.tet_obj.name}'", True
        weights = self.weights(self.hand).get(name)
        if weights is None:
            return None, "", False
        rigid = weights > self.threshold
        return np.flatnonzero(rigid[self.nearest_vertex()]), f"the group '{name}' of '{self.hand.name}'", False


def chain_of(scene) -> list[tuple[object, str | None]]:
    """The deforming bones of the scene's skeleton armature (deform_bones); RigError without."""
    arm_obj = scene.haptic_hand.armature
    if arm_obj is None or arm_obj.type != "ARMATURE":
        raise RigError("No armature is chosen: pick the hand's armature in Haptic Hand > Rig > Skeleton")
    chain = deform_bones(arm_obj)
    if not chain:
        raise RigError(f"The armature '{arm_obj.name}' has no deforming bone: turn on Deform (Bone Properties) for "
                       "the bones that move the hand")
    return chain


def radii(scene, bones, heads: np.ndarray, tails: np.ndarray) -> list[tuple[float | None, bool]]:
    """Each bone's capsule radius (m; None: it holds a vertex group's nodes) and whether it is
    the automatic one (the hand's surface is read only when a bone needs it)."""
    out, auto = [], None
    for i, bone in enumerate(bones):
        h = bone.haptic_hand
        if h.capture == "GROUP":
            out.append((None, False))
        elif h.use_bone_radius:
            out.append((float(h.bone_radius_si), False))
        else:
            if auto is None:
                auto = auto_radii(heads, tails, meshdata.world_vertices(scene.haptic_hand.hand, scene))
            out.append((float(auto[i]), True))
    return out


def rig(scene, nodes: np.ndarray | None = None) -> Rig:
    """The armature's bones, what each captures of the hand's tet nodes (world metres; read
    from the scene when not given) and every problem; RigError when there is no skeleton to
    speak of (no armature, no deforming bone, no tets)."""
    s = scene.haptic_hand
    chain = chain_of(scene)
    if nodes is None:
        nodes, _ = hand_source.hand_tets_world(scene)
    hand = s.hand
    heads, tails = rest_segments(s.armature, [b for b, _ in chain], meshdata.unit_scale(scene))
    capsules = radii(scene, [b for b, _ in chain], heads, tails)
    groups = None
    bones = []
    for i, (bone, parent) in enumerate(chain):
        b = RigBone(bone.name, parent, heads[i], tails[i], capsules[i][0], None,
                    float(bone.haptic_hand.bone_drive_scale), auto_radius=capsules[i][1])
        # (a root turns with its target: its IK limits, against a bone outside the skeleton, stay out)
        b.limits = None if parent is None else ik_limits(s.armature.pose.bones[bone.name])
        b.axes = None if b.limits is None else rest_axes(s.armature, bone)
        if b.axes is not None and np.linalg.det(b.axes) < 0:
            b.problems.append(f"bone '{bone.name}' has IK limits, but the armature '{s.armature.name}' is mirrored (a "
                              "negative scale), so the limits' axes turn the other way: apply its scale (Object > "
                              "Apply > Scale) or remove the IK limits")
        if b.radius is None:
            if groups is None:
                groups = _Groups(hand, hand.haptic_hand.tet_object, nodes, meshdata.world_vertices(hand, scene),
                                 s.group_weight)
            b.nodes, b.source, b.exact = groups.nodes_of(bone.name)
            if b.nodes is None:
                b.problems.append(f"bone '{bone.name}' captures by vertex group, but neither '{hand.name}' nor its tet "
                                  f"mesh has a group named '{bone.name}': name a vertex group after the bone, or set "
                                  "its Capture to Capsule")
                b.nodes = np.zeros(0, dtype=np.int64)
        bones.append(b)
    return _captured(bones, nodes, s.group_weight)


def _captured(bones: list, nodes: np.ndarray, threshold: float) -> Rig:
    """Each node's bone by engine/skeleton.py's rule, and the problems of what each bone holds.
    A node two groups claim is reported and counted for the first."""
    problems = [p for b in bones for p in b.problems]
    taken, exact = {}, {b.name: b.exact for b in bones}
    for b in bones:
        if b.nodes is None:
            continue
        shared = {}
        for n in b.nodes:
            shared.setdefault(taken.setdefault(int(n), b.name), []).append(int(n))
        for other, clash in shared.items():
            if other != b.name:
                painted = exact[b.name] or exact[other]
                problems.append(_clash(b.name, other, clash, threshold if not painted else 1.0))
                b.problems.append(problems[-1])
        b.nodes = np.array([n for n in b.nodes if taken[int(n)] == b.name], dtype=np.int64)
    engine_bones = [sk.Bone(b.name, b.parent, b.head, b.tail, b.radius or 0.0, b.nodes) for b in bones]
    owner = sk.Skeleton(engine_bones).assign(nodes)
    counts = np.bincount(owner[owner >= 0], minlength=len(bones))
    for i, b in enumerate(bones):
        b.count = int(counts[i])
        problem = _holding_problem(b, nodes[owner == i], threshold)
        if problem:
            b.problems.append(problem)
            problems.append(problem)
    if counts.sum() == len(nodes):
        problems.append(f"the bones capture all {len(nodes)} tet nodes, so nothing of the hand is soft: lower the "
                        "bones' radii (Rig > Skeleton) or their groups")
    return Rig(bones, owner, problems)


def _clash(name: str, other: str, nodes: list, threshold: float) -> str:
    """Nodes two groups claim; the fix for skinning weights below 0.5, else for the groups."""
    fix = ("normalize the hand's weights (Weight Paint > Weights > Normalize All) or raise Group weight above 0.5"
           if threshold < 0.5 else "remove them from one of the two groups")
    return (f"{len(nodes)} tet node(s) are in the vertex groups of both '{other}' and '{name}' (node {nodes[0]}); a "
            f"node belongs to at most one bone: {fix}")


def _holding_problem(b: RigBone, held: np.ndarray, threshold: float) -> str:
    """Fewer than 4 nodes, or nodes on a line (the engine's rules, docs/skeleton.md Section 1)."""
    if b.radius is not None:
        fix = "set a larger Radius (Rig > Skeleton)" if b.count < sk.MIN_BONE_NODES else \
            "set a larger Radius so it holds nodes off its axis"
    else:
        fix = f"add vertices to its vertex group (or lower Group weight, now {threshold:g})"
    if b.count < sk.MIN_BONE_NODES:
        return f"bone '{b.name}' captures {b.count} node(s); a rigid bone needs at least {sk.MIN_BONE_NODES}: {fix}"
    r = held - held.mean(axis=0)
    spread = r.T @ r  # the inertia of unit masses, as build_handle tests it (masses only scale it)
    eig = np.linalg.eigvalsh(np.trace(spread) * np.eye(3) - spread)
    if eig[0] <= 1e-12 * eig[-1]:
        return f"bone '{b.name}': its {b.count} nodes lie on a line: {fix}"
    return ""


def skinning(obj) -> list:
    """obj's Armature modifiers: what deforms a skinned hand's own vertices by the pose."""
    return [m for m in obj.modifiers if m.type == "ARMATURE"]


def mute_skinning(obj) -> list[str]:
    """Turns off obj's Armature modifiers that are on, so positions written into its mesh (a
    live frame, a baked shape key) are not deformed by the pose a second time; returns their
    names for unmute_skinning."""
    muted = [m for m in skinning(obj) if m.show_viewport or m.show_render]
    for m in muted:
        m.show_viewport = m.show_render = False
    return [m.name for m in muted]


def unmute_skinning(obj, names) -> None:
    for name in names:
        m = obj.modifiers.get(name)
        if m is not None:
            m.show_viewport = m.show_render = True
