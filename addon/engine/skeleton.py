"""A skeleton of rigid bones, each a handle of the paper's Section 4 (issue 40; docs/skeleton.md).

A bone is a rest segment (head, tail) with a capsule radius, or an explicit node set (a Blender
vertex group turned into tet nodes). It captures tet nodes: a node in a bone's explicit set is
that bone's; any other node goes to the nearest bone segment among the capsules that contain it
(ties to the bone listed first). So a node belongs to at most one bone. Each bone's mass and
inertia come from its nodes' lumped masses (Eq. 3), its body frame is the world frame at rest
centred at its nodes' centre of mass, as the palm handle's (native/src/rigid/handle.cpp).

Pure numpy; the native engine will implement the same rule (docs/skeleton.md, Section 1).
"""

from __future__ import annotations

import math

from dataclasses import dataclass, field

import numpy as np

from . import quaternion as quat

#: A rigid bone needs at least this many nodes (the palm handle's rule, per bone).
MIN_BONE_NODES = 4

# The smallest eigenvalue of a bone's inertia, relative to its largest, below which its nodes
# count as collinear (the same test as build_handle's).
_COLLINEAR = 1e-12


class SkeletonError(ValueError):
    """A skeleton that cannot be used; the message names the bone and the fix."""


@dataclass(frozen=True)
class Bone:
    name: str
    parent: str | None
    head: np.ndarray  # (3,) m, rest
    tail: np.ndarray  # (3,) m, rest
    radius: float     # m, capsule radius of the capture by distance
    nodes: np.ndarray | None = field(default=None, repr=False)  # explicit node set, or None
    # angular limits (docs/skeleton.md Section 5): (2, 3) rad, the minimum and maximum of its
    # rotation relative to its parent as a rotation vector in its rest axes (-inf / +inf: a free
    # axis), or None; `axes` (3, 3) those rest axes as columns x, y, z (None: the world axes)
    limits: np.ndarray | None = field(default=None, repr=False)
    axes: np.ndarray | None = field(default=None, repr=False)


def segment_distance(points: np.ndarray, head: np.ndarray, tail: np.ndarray) -> np.ndarray:
    """Distance of each point (n, 3) to the segment [head, tail]; a point when head == tail,
    computed then as |p - head| exactly (so a zero-length bone is the palm handle's sphere)."""
    ab = tail - head
    length2 = float(ab @ ab)
    if length2 == 0.0:
        return np.linalg.norm(points - head, axis=1)
    t = np.clip(((points - head) @ ab) / length2, 0.0, 1.0)
    return np.linalg.norm(points - (head + t[:, None] * ab), axis=1)


@dataclass
class BoneBody:
    """A bone's rigid body (Eq. 3): its nodes, mass, rest centre of mass, inertia about it
    (world axes at rest) and each node's r_B = X_i - com."""

    nodes: np.ndarray
    mass: float
    com: np.ndarray
    inertia: np.ndarray
    r_body: np.ndarray


def bone_body(rest: np.ndarray, masses: np.ndarray, nodes: np.ndarray) -> BoneBody:
    """Eq. 3 for one bone from the lumped masses of its nodes (summed in node order)."""
    nodes = np.asarray(nodes, dtype=np.int64)
    m = masses[nodes]
    mass = float(m.sum())
    com = (m[:, None] * rest[nodes]).sum(axis=0) / mass
    r = rest[nodes] - com
    inertia = np.einsum("i,ij,ik->jk", m, r, r)
    inertia = np.trace(inertia) * np.eye(3) - inertia  # sum m (|r|^2 I - r r^T)
    return BoneBody(nodes, mass, com, inertia, r)


class Skeleton:
    """Bones in a tree (parents listed by name; several roots allowed)."""

    def __init__(self, bones):
        self.bones = tuple(bones)
        if not self.bones:
            raise SkeletonError("a skeleton needs at least one bone")
        names = [b.name for b in self.bones]
        for i, bone in enumerate(self.bones):
            self._check_bone(i, bone, names)
        self.names = tuple(names)
        self._index = {name: i for i, name in enumerate(names)}
        self.parents = np.array([-1 if b.parent is None else self._index[b.parent] for b in self.bones])
        self._check_tree()
        self.order = parents_first(self)  # (pose_bones runs every visual-loop step)
        self.heads = np.array([np.asarray(b.head, dtype=float) for b in self.bones])

    @staticmethod
    def _check_bone(i: int, bone: Bone, names: list[str]) -> None:
        if not isinstance(bone.name, str) or not bone.name:
            raise SkeletonError(f"bone {i} has no name: give every bone a unique, non-empty name")
        if names.count(bone.name) > 1:
            raise SkeletonError(f"two bones are named '{bone.name}': bone names must be unique")
        if bone.parent is not None and bone.parent not in names:
            raise SkeletonError(f"bone '{bone.name}' has parent '{bone.parent}', which is not a bone of the "
                                f"skeleton: name an existing bone or none (a root)")
        for label, point in (("head", bone.head), ("tail", bone.tail)):
            p = np.asarray(point, dtype=float)
            if p.shape != (3,) or not np.isfinite(p).all():
                raise SkeletonError(f"bone '{bone.name}' has {label} {point!r}: give three finite coordinates in metres")
        if bone.nodes is None and not (np.isfinite(bone.radius) and bone.radius > 0):
            raise SkeletonError(f"bone '{bone.name}' has capsule radius {bone.radius} m and no vertex group: give "
                                f"it a positive radius (a few millimetres for a phalanx) or a vertex group")

    def _check_tree(self) -> None:
        for i in range(len(self.bones)):
            seen, j = set(), i
            while j >= 0:
                if j in seen:
                    raise SkeletonError(f"bone '{self.names[i]}' is its own ancestor: the parents must form a tree")
                seen.add(j)
                j = self.parents[j]

    def __len__(self) -> int:
        return len(self.bones)

    def index(self, name: str) -> int:
        if name not in self._index:
            raise SkeletonError(f"no bone is named '{name}'; the bones are: {', '.join(self.names)}")
        return self._index[name]

    def capture(self, rest: np.ndarray) -> np.ndarray:
        """Each rest node's bone (n,), -1 for flesh only; checks every rule (docs/skeleton.md)."""
        owner = self.assign(rest)
        self._check_capture(owner, len(owner))
        return owner

    def assign(self, rest: np.ndarray) -> np.ndarray:
        """Each rest node's bone (n,) by the capture rule, without the checks on what each bone
        holds (at least 4 nodes, not every node): what Blender lists while a rig is authored."""
        rest = _rest_nodes(rest)
        n = len(rest)
        owner = self._explicit_owners(n)
        distances = np.full((n, len(self.bones)), np.inf)
        for b, bone in enumerate(self.bones):
            if bone.nodes is None:
                d = segment_distance(rest, np.asarray(bone.head, float), np.asarray(bone.tail, float))
                distances[:, b] = np.where(d <= bone.radius, d, np.inf)
        free = owner < 0
        nearest = np.argmin(distances, axis=1)  # the first of equal distances: the bone listed first
        inside = np.isfinite(distances[np.arange(n), nearest])
        owner[free & inside] = nearest[free & inside]
        return owner

    def _explicit_owners(self, n: int) -> np.ndarray:
        owner = np.full(n, -1, dtype=np.int64)
        for b, bone in enumerate(self.bones):
            if bone.nodes is None:
                continue
            nodes = np.asarray(bone.nodes)
            if nodes.ndim != 1 or (nodes.size and not np.issubdtype(nodes.dtype, np.integer)):
                raise SkeletonError(f"bone '{bone.name}': its node set must be a list of node indices")
            bad = nodes[(nodes < 0) | (nodes >= n)]
            if bad.size:
                raise SkeletonError(f"bone '{bone.name}': node {int(bad[0])} of its vertex group is not a tet node "
                                    f"(0..{n - 1}): map the vertex group to the tet nodes again")
            nodes = np.unique(nodes)
            taken = nodes[owner[nodes] >= 0]
            if taken.size:
                other = self.names[owner[taken[0]]]
                raise SkeletonError(f"node {int(taken[0])} is in the vertex groups of both '{other}' and "
                                    f"'{bone.name}'; a node belongs to at most one bone: remove it from one group")
            owner[nodes] = b
        return owner

    def _check_capture(self, owner: np.ndarray, n: int) -> None:
        counts = np.bincount(owner[owner >= 0], minlength=len(self.bones))
        for b, bone in enumerate(self.bones):
            if counts[b] < MIN_BONE_NODES:
                how = ("its vertex group holds" if bone.nodes is not None
                       else f"its capsule of radius {bone.radius:g} m captures")
                fix = ("add vertices to its vertex group" if bone.nodes is not None
                       else "increase its radius or move its segment into the flesh")
                raise SkeletonError(f"bone '{bone.name}': {how} {counts[b]} node(s) of its own; a rigid bone needs "
                                    f"at least {MIN_BONE_NODES}: {fix}")
        if counts.sum() == n:
            raise SkeletonError(f"the bones capture all {n} nodes, so nothing of the hand is soft: decrease the "
                                f"capsule radii")

    def regions(self, rest: np.ndarray, owner: np.ndarray) -> np.ndarray:
        """Each node's bone for reporting (n,): the bone that holds it (owner >= 0), else the bone
        whose rest segment is nearest (what a finger's contact forces are summed over)."""
        rest = _rest_nodes(rest)
        distances = np.stack([segment_distance(rest, np.asarray(b.head, float), np.asarray(b.tail, float))
                              for b in self.bones], axis=1)
        return np.where(np.asarray(owner) >= 0, owner, np.argmin(distances, axis=1)).astype(np.int32)

    def bodies(self, rest: np.ndarray, masses: np.ndarray, owner: np.ndarray | None = None) -> list[BoneBody]:
        """Eq. 3 per bone from the lumped masses (n,) (native HandModel.lumped_masses())."""
        rest = _rest_nodes(rest)
        masses = np.asarray(masses, dtype=float)
        if masses.shape != (len(rest),) or not (np.isfinite(masses).all() and (masses > 0).all()):
            raise SkeletonError(f"the lumped masses must be {len(rest)} positive numbers, one per node "
                                f"(got shape {masses.shape})")
        owner = self.capture(rest) if owner is None else owner
        out = []
        for b, bone in enumerate(self.bones):
            body = bone_body(rest, masses, np.flatnonzero(owner == b))
            eig = np.linalg.eigvalsh(body.inertia)
            if eig[0] <= _COLLINEAR * eig[-1]:
                raise SkeletonError(f"bone '{bone.name}': its {len(body.nodes)} nodes lie on a line, so its inertia "
                                    f"is singular: increase its radius so it holds nodes off its axis")
            out.append(body)
        return out

    def feedback_groups(self) -> tuple[np.ndarray, list[str]]:
        """A glove's feedback groups (docs/skeleton.md, Section 6): the roots alone (the wrist's
        frame), then one group per chain leaving a root (a digit), each holding that chain's
        bones. Returns each bone's group (B,) and the groups' names (the root's, then each
        chain's first bone's)."""
        group = np.full(len(self.bones), -1, dtype=np.int32)
        names = [self.names[int(np.flatnonzero(self.parents < 0)[0])]]
        for b in range(len(self.bones)):  # (a tree: walk up to the bone below the root)
            j = b
            while self.parents[j] >= 0 and self.parents[self.parents[j]] >= 0:
                j = self.parents[j]
            if self.parents[j] < 0:
                group[b] = 0
                continue
            if self.names[j] not in names:
                names.append(self.names[j])
            group[b] = names.index(self.names[j])
        return group, names


def pose_bones(skeleton: Skeleton, coms: np.ndarray, turns: list, heads: list) -> tuple[np.ndarray, np.ndarray]:
    """Forward kinematics of the rig: each bone's handle pose (positions (B, 3) of its centre of
    mass, quaternions (B, 4)) when bone b turns from rest by turns[b] about its head and its head
    moves to heads[b]. A None turn turns with the parent (a root: no turn); a None head rides on
    the parent at the bone's rest head (a root: stays at rest), so the rig keeps its own bone
    lengths. coms: the bones' rest centres of mass (B, 3)."""
    motion = [None] * len(skeleton)  # each bone's rigid motion: (turn, its matrix, rest head, moved head)
    positions, quaternions = np.empty((len(skeleton), 3)), np.empty((len(skeleton), 4))
    still = (np.array([0.0, 0.0, 0.0, 1.0]), np.eye(3))
    for b in skeleton.order:
        head, parent = skeleton.heads[b], skeleton.parents[b]
        inherited = motion[parent] if parent >= 0 else (*still, head, head)
        if turns[b] is None:
            turn, matrix = inherited[0], inherited[1]
        else:
            turn = np.asarray(turns[b], dtype=float)
            turn = turn / math.sqrt(turn @ turn)  # (np.linalg.norm's value, without its overhead)
            matrix = quat.to_matrix(turn)
        moved = _moved(inherited, head) if heads[b] is None else np.asarray(heads[b], dtype=float)
        motion[b] = (turn, matrix, head, moved)
        positions[b] = _moved(motion[b], coms[b])
        quaternions[b] = turn
    return positions, quaternions


def _moved(motion, x) -> np.ndarray:
    _, matrix, pivot, moved = motion
    return moved + matrix @ (x - pivot)


def parents_first(skeleton: Skeleton) -> list[int]:
    """The bones' indices, every parent before its children."""
    order, placed = [], set()
    while len(order) < len(skeleton):
        for b in range(len(skeleton)):
            p = skeleton.parents[b]
            if b not in placed and (p < 0 or p in placed):
                order.append(b)
                placed.add(b)
    return order


def _rest_nodes(rest) -> np.ndarray:
    rest = np.asarray(rest, dtype=float)
    if rest.ndim != 2 or rest.shape[1] != 3:
        raise SkeletonError(f"rest node positions must be an (n, 3) array, got shape {rest.shape}")
    return rest


def palm_handle_skeleton(seed, radius: float) -> Skeleton:
    """The one-bone skeleton that is today's palm handle: a zero-length bone at the seed."""
    seed = np.asarray(seed, dtype=float)
    return Skeleton([Bone("palm", None, seed.copy(), seed.copy(), float(radius))])


# --------------------------------------------------------------------------------------------
# The rigged procedural hand: 16 bones on mesh.procedural_hand()'s capsules
# --------------------------------------------------------------------------------------------

#: Names of the procedural hand's bones, root first; digits as MANO and OpenXR name them.
DIGITS = ("thumb", "index", "middle", "ring", "little")

# Where each finger's visible axis (knuckle line to the tip's centre) is cut into phalanges,
# and the thumb's whole axis (its root lies inside the palm, like a metacarpal): human
# proportions, proximal to distal.
_FINGER_CUTS = (0.0, 0.45, 0.75, 1.0)
_THUMB_CUTS = (0.0, 0.40, 0.73, 1.0)
# Capsule radius over the finger's: the tetrahedralized skin lies within ~5% of the capsule,
# and the coarse sample hand has too few nodes inside a finger for a thinner bone
# (docs/skeleton.md, Section 9).
_FINGER_BONE_RADIUS = 1.15
# The palm bone: the slab's long axis from the wrist to near the knuckles, today's handle radius.
_PALM_HEAD = np.array([0.0, 0.0, 0.0])
_PALM_TAIL = np.array([0.0, 0.0, -0.075])
_PALM_RADIUS = 0.03


# The grasping hand's bones (docs/skeleton.md, Section 9): capsules 0.6 times each digit's radius
# (its finer tets hold 10-36 nodes in each, off one line), and a palm bone that ends 15 mm short of
# the knuckle line, so that a layer of flesh at each knuckle bends.
GRASPING_BONE_RADIUS = 0.6
_GRASPING_PALM_TAIL = np.array([0.0, 0.0, -0.06])
_GRASPING_PALM_RADIUS = 0.02


def _cut(root, tip, cuts):
    return [root + c * (tip - root) for c in cuts]


def procedural_hand_skeleton(thumb=None, bone_radius: float = _FINGER_BONE_RADIUS) -> Skeleton:
    """16 bones fitted to mesh.procedural_hand(thumb=thumb): 'palm' (the root), 'thumb_1..3'
    and '<finger>_1..3' (proximal to distal) for index, middle, ring and little; each digit's
    capsules `bone_radius` times its own radius."""
    from . import mesh

    segments = mesh._finger_segments(mesh.THUMB if thumb is None else thumb)  # little, ring, middle, index, thumb: (root, tip, radius, blend)
    by_digit = dict(zip(("little", "ring", "middle", "index", "thumb"), segments))
    bones = [Bone("palm", None, _PALM_HEAD.copy(), _PALM_TAIL.copy(), _PALM_RADIUS)]
    for digit in DIGITS:
        root, tip, radius, _ = by_digit[digit]
        if digit == "thumb":
            points = _cut(root, tip, _THUMB_CUTS)
        else:
            # the axis starts inside the palm; its visible part starts at the knuckle line
            s = (mesh._KNUCKLE_Z - root[2]) / (tip[2] - root[2])
            points = _cut(root + s * (tip - root), tip, _FINGER_CUTS)
        parent = "palm"
        for k in range(3):
            name = f"{digit}_{k + 1}"
            bones.append(Bone(name, parent, points[k], points[k + 1], bone_radius * radius))
            parent = name
    return Skeleton(bones)


def grasping_hand_skeleton() -> Skeleton:
    """16 bones fitted to mesh.procedural_hand(thumb=mesh.GRASPING_THUMB), named as
    procedural_hand_skeleton()'s: thinner digit bones and a shorter palm bone, for the finer
    tets of sample_scenes/grasping_hand_tets.npz (docs/skeleton.md, Section 9)."""
    from . import mesh

    digits = procedural_hand_skeleton(mesh.GRASPING_THUMB, GRASPING_BONE_RADIUS).bones[1:]
    palm = Bone("palm", None, _PALM_HEAD.copy(), _GRASPING_PALM_TAIL.copy(), _GRASPING_PALM_RADIUS)
    return Skeleton([palm, *digits])
