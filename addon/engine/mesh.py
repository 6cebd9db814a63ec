"""Surface and tetrahedral meshes of the hand: a procedural hand, OBJ input/output, surface
checks, tetrahedralization with pytetwild, and barycentric embedding of a render mesh in the
tet mesh.

Conventions: SI units (metres); positions are float64 arrays of shape (n, 3); triangles and
tets are int32 index arrays of shape (m, 3) and (m, 4). A tet (x0, x1, x2, x3) is positively
oriented when det[x1 - x0, x2 - x0, x3 - x0] > 0. Never imports bpy.
"""

from __future__ import annotations

import math
import pathlib
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

#: Smallest tet volume (m^3) accepted as non-degenerate: a regular tet with 20 um edges.
MIN_TET_VOLUME = 1e-15

# Relative tolerance of the barycentric containment test (weights are dimensionless).
_INSIDE_TOLERANCE = 1e-10

# Simplices (tets, boundary faces) with the nearest centroids tried first for each point.
_NEAREST_CANDIDATES = 8

# The file fTetWild leaves in the working directory on every run.
_FTETWILD_STRAY_FILE = "__tracked_surface.stl"

#: A surface vertex whose shortest edge is this many times the surface's median edge length is
#: a spike (hand.obj's longest shortest edge is 3.4x its median; a vertex read as 0 is 20x).
SPIKE_FACTOR = 8.0

#: A surface enclosing less than this fraction of its bounding-box diagonal cubed is flat.
FLAT_VOLUME = 1e-6

#: The largest extent (m) of a human hand, from a child's to a large glove's, and a typical one.
HAND_SIZE_RANGE = (0.05, 0.5)
TYPICAL_HAND_SIZE = 0.19

# Outward faces of a positively oriented tet, as local vertex indices.
_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)


class MeshError(ValueError):
    """A mesh that cannot be used; the message names the problem and how to fix it."""


# --------------------------------------------------------------------------------------------
# Procedural hand
# --------------------------------------------------------------------------------------------
# Right hand, palm facing -X, thumb towards +Y, fingertips towards -Z (as hand.obj).

_PALM_CENTRE = np.array([0.0, 0.0, -0.0425])
_PALM_HALF_EXTENTS = np.array([0.0125, 0.045, 0.0525])  # 2.5 cm thick, 9 cm wide, 10.5 cm long
_PALM_ROUNDING = 0.012
_FINGER_ROOT_Z = -0.075  # finger capsules start inside the palm so the blend hides their ends
_KNUCKLE_Z = _PALM_CENTRE[2] - _PALM_HALF_EXTENTS[2]

# (y of the root, radius, length beyond the knuckle line, fan angle in the y-z plane):
# little, ring, middle, index. Neighbours are 5 mm apart at the root; the fan widens the gap.
_FINGERS = (
    (-0.0335, 0.0075, 0.062, -0.12),
    (-0.0125, 0.0085, 0.080, -0.045),
    (0.0095, 0.0090, 0.085, 0.0),
    (0.0320, 0.0085, 0.075, 0.05),
)
_FINGER_GAP = 0.005
_FINGER_BLEND = 0.010

_THUMB_ROOT = np.array([-0.002, 0.028, -0.025])
_THUMB_DIRECTION = np.array([-0.35, 0.8, -0.55])  # out to the side, down, towards the palm
_THUMB_LENGTH = 0.06
_THUMB_RADIUS = 0.0105
_THUMB_BLEND = 0.015


class Thumb(NamedTuple):
    """The thumb's capsule: its root inside the palm (m), the direction it points, its axis
    length from the root (m) and its radius (m)."""

    root: tuple
    direction: tuple
    length: float
    radius: float


#: The default hand's thumb: out to the side, its tip 60 mm from a root high on the palm.
THUMB = Thumb(tuple(_THUMB_ROOT), tuple(_THUMB_DIRECTION), _THUMB_LENGTH, _THUMB_RADIUS)
#: A thumb that opposes the index finger: 85 mm long from a root 20 mm lower on the palm, pointing
#: in front of the palm and down, so that its pad meets the index finger's pad with the index bent
#: 24/24/14 degrees at its three joints and the thumb 16/16/10 (the pinch sample; docs/skeleton.md,
#: Section 9).
GRASPING_THUMB = Thumb((-0.006, 0.032, -0.045), (-0.5, 0.5, -0.7), 0.085, 0.0105)


def _rounded_box_distance(p, centre, half_extents, rounding):
    q = np.abs(p - centre) - (half_extents - rounding)
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    inside = np.minimum(q.max(axis=-1), 0.0)
    return outside + inside - rounding


def capsule_distance(p, a, b, radius):
    ab = b - a
    t = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1) - radius


def smooth_union(d1, d2, k):
    # Polynomial smooth minimum: a fillet of width about k where the two shapes meet.
    h = np.maximum(k - np.abs(d1 - d2), 0.0) / k
    return np.minimum(d1, d2) - h * h * k / 4.0


def _finger_segments(thumb: Thumb = THUMB):
    """Capsule axis end points (root, tip centre), radius and blend width of each finger
    (little, ring, middle, index) and the thumb."""
    segments = []
    for root_y, radius, length, angle in _FINGERS:
        root = np.array([0.0, root_y, _FINGER_ROOT_Z])
        direction = np.array([0.0, math.sin(angle), -math.cos(angle)])
        # The tip reaches `length` below the knuckle line, measured along the finger.
        axis_length = (_FINGER_ROOT_Z - _KNUCKLE_Z) + length - radius
        segments.append((root, root + axis_length * direction, radius, _FINGER_BLEND))
    root = np.asarray(thumb.root, dtype=np.float64)
    direction = np.asarray(thumb.direction, dtype=np.float64)
    direction = direction / np.linalg.norm(direction)
    segments.append((root, root + thumb.length * direction, thumb.radius, _THUMB_BLEND))
    return segments


def _hand_distance(p, thumb: Thumb = THUMB):
    palm = _rounded_box_distance(p, _PALM_CENTRE, _PALM_HALF_EXTENTS, _PALM_ROUNDING)
    # Each finger is blended with the palm only, never with its neighbours, so the gaps
    # between fingers stay open.
    return np.min(
        [
            smooth_union(palm, capsule_distance(p, a, b, r), k)
            for a, b, r, k in _finger_segments(thumb)
        ],
        axis=0,
    )


def procedural_hand(resolution: float = 0.004, thumb: Thumb = THUMB):
    """Closed, outward-wound, genus-0 triangle surface of a right hand (about 19 cm long).

    The hand is a smooth union of a rounded palm slab and five capsules, sampled as a signed
    distance field on a grid of spacing `resolution` (m) and contoured by marching cubes;
    `thumb` is the thumb's capsule (THUMB, or GRASPING_THUMB for a hand that pinches).
    Returns (V float64 (n, 3), F int32 (m, 3)); the same arguments give the same mesh.
    """
    import pyvista

    if not 0.0 < resolution < _FINGER_GAP:
        raise MeshError(
            f"resolution {resolution} m is out of range: the grid must be finer than the "
            f"{_FINGER_GAP * 1000:.0f} mm gap between fingers or the fingers fuse; "
            f"pass a resolution between 0 and {_FINGER_GAP} m (default 0.004)"
        )
    lower = np.full(3, np.inf)
    upper = np.full(3, -np.inf)
    for a, b, radius, _ in _finger_segments(thumb):
        lower = np.minimum(lower, np.minimum(a, b) - radius)
        upper = np.maximum(upper, np.maximum(a, b) + radius)
    lower = np.minimum(lower, _PALM_CENTRE - _PALM_HALF_EXTENTS)
    upper = np.maximum(upper, _PALM_CENTRE + _PALM_HALF_EXTENTS)
    # Two empty cells of margin so the contour closes inside the grid.
    lower -= 2 * resolution
    dims = np.ceil((upper + 2 * resolution - lower) / resolution).astype(int) + 1

    grid = pyvista.ImageData(dimensions=dims, spacing=(resolution,) * 3, origin=lower)
    distance = _hand_distance(np.asarray(grid.points, dtype=np.float64), thumb)
    # Keep samples off the zero level so marching cubes makes no zero-length edges.
    tiny = 1e-6 * resolution
    distance[np.abs(distance) < tiny] = tiny
    grid.point_data["distance"] = distance
    contour = grid.contour([0.0], scalars="distance", method="marching_cubes")
    contour = contour.triangulate()

    V = np.asarray(contour.points, dtype=np.float64)
    F = np.asarray(contour.faces, dtype=np.int64).reshape(-1, 4)[:, 1:]
    V, F = clean_surface(V, F)
    if surface_volume(V, F) < 0.0:
        F = F[:, ::-1]
    return V, F.astype(np.int32)


def clean_surface(V, F):
    """Merge coincident vertices, drop triangles with repeated vertices, compact indices."""
    V, inverse = np.unique(V, axis=0, return_inverse=True)
    F = inverse.reshape(-1)[F]
    repeated = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    F = F[~repeated]
    used, F = np.unique(F, return_inverse=True)
    return V[used], F.reshape(-1, 3)


def procedural_hand_palm_seed() -> np.ndarray:
    """A point inside the palm of `procedural_hand`, 12 mm from its faces."""
    return _PALM_CENTRE.copy()


# --------------------------------------------------------------------------------------------
# OBJ files
# --------------------------------------------------------------------------------------------


def load_obj(path):
    """Vertices and triangles of an OBJ file; polygons are split into fans, vt/vn ignored.
    A line that cannot be read, or a face index outside the file's vertices, is a MeshError
    naming the line (an index is never wrapped to 32 bits)."""
    vertices = []
    triangles = []
    face_lines = []  # the line of each triangle, for messages
    with open(path, encoding="utf-8", errors="replace") as obj:
        for line_number, line in enumerate(obj, start=1):
            fields = line.split()
            if not fields:
                continue
            try:
                if fields[0] == "v":
                    if len(fields) < 4:
                        raise ValueError(f"a vertex needs 3 coordinates x y z, this one has {len(fields) - 1}")
                    vertices.append([float(x) for x in fields[1:4]])
                elif fields[0] == "f":
                    if len(fields) < 4:
                        raise ValueError(f"a face needs at least 3 corners, this one has {len(fields) - 1}")
                    # "f 1/2/3 ..." keeps only the position index; negative is relative.
                    corners = [int(field.split("/")[0]) for field in fields[1:]]
                    corners = [c - 1 if c > 0 else len(vertices) + c for c in corners]
                    triangles.extend(
                        [corners[0], corners[i], corners[i + 1]] for i in range(1, len(corners) - 1)
                    )
                    face_lines.extend([line_number] * (len(corners) - 2))
            except ValueError as error:
                raise MeshError(
                    f"{path}:{line_number}: cannot read {fields[0]!r} line ({error}); "
                    "re-export the mesh as OBJ with triangulated or polygon faces"
                ) from None
    V = np.array(vertices, dtype=np.float64).reshape(-1, 3)
    return V, _obj_faces(triangles, face_lines, len(V), path)


def _obj_faces(triangles: list, lines: list, n: int, path) -> np.ndarray:
    """The triangles as int32, each index checked against the n vertices while still a Python
    integer (numpy would wrap 2^32 + 3 to 3)."""
    outside = next((k for k, t in enumerate(triangles) if not all(0 <= c < n for c in t)), None)
    if outside is not None:
        shown = [c + 1 for c in triangles[outside]]  # OBJ counts from 1
        raise MeshError(
            f"{path}:{lines[outside]}: face refers to vertex {shown}, outside 1..{n} (the file has {n} vertices; "
            "an index is refused, never wrapped); re-export the mesh"
        )
    return np.array(triangles, dtype=np.int32).reshape(-1, 3)


def save_obj(path, V, F):
    """Write vertices and triangles as an OBJ file (1-based indices, full float precision)."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    with open(pathlib.Path(path), "w", encoding="utf-8") as obj:
        obj.write("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in V.tolist()))
        obj.write("".join(f"f {a} {b} {c}\n" for a, b, c in (F + 1).tolist()))


# --------------------------------------------------------------------------------------------
# Surface checks
# --------------------------------------------------------------------------------------------


def surface_volume(V, F) -> float:
    """Signed volume enclosed by a closed triangle surface (positive when wound outward)."""
    V = np.asarray(V, dtype=np.float64)
    # Cones from a point near the surface rather than the origin, to limit cancellation.
    a, b, c = (V[np.asarray(F)[:, i]] - V[0] for i in range(3))
    return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)


def check_closed_surface(V, F) -> None:
    """Raise MeshError unless (V, F) is a closed, 2-manifold, outward-wound triangle surface
    that bounds a volume without touching itself: no coincident vertices, zero-area triangles
    or spikes, no edge or vertex shared by more than one sheet, not flat, no two triangles
    crossing. Each message names the first offending vertices or triangles and Blender's fix."""
    V, F = surface_arrays(V, F)
    _check_triangle_areas(V, F)
    _check_coincident_vertices(V, F)
    _check_spikes(V, F)
    _check_manifold_edges(V, F)
    _check_manifold_vertices(F)
    _check_volume(V, F)
    _check_self_intersections(V, F)


def surface_arrays(V, F) -> tuple[np.ndarray, np.ndarray]:
    """V as float64 (n, 3), F as int64 (m, 3) with every index in range, or MeshError."""
    try:
        V = np.asarray(V, dtype=np.float64)
    except (TypeError, ValueError):
        raise MeshError("surface vertices must be numbers, as an (n, 3) array of positions in metres") from None
    F = np.asarray(F)
    if V.size == 0 or F.size == 0:
        raise MeshError(
            f"surface is empty ({len(V)} vertices, {len(F)} triangles); "
            "select a mesh object with faces"
        )
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3:
        raise MeshError(
            f"surface arrays have shapes {V.shape} and {F.shape}; pass vertices as (n, 3) "
            "and triangles as (m, 3) (triangulate polygons first)"
        )
    F = index_array(F, len(V), "triangle", "vertex", "fix the face indices (re-export the mesh)")
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        raise MeshError(
            f"surface has {bad.sum()} vertices with NaN or infinite coordinates (first is "
            f"vertex {np.argmax(bad)}); delete or re-place them"
        )
    return V, F


def index_array(a, n: int, row: str, target: str, fix: str) -> np.ndarray:
    """Integer indices (rows of triangles or tets) into n targets, as int64: floats are refused
    rather than truncated and 64-bit values checked before any narrowing."""
    a = np.asarray(a)
    if a.dtype.kind not in "iu":
        kind = "floats" if a.dtype.kind == "f" else f"of type {a.dtype}"
        raise MeshError(f"{row} indices are {kind}: they must be integer {target} indices (numpy: "
                        f".astype(np.int32)); they are refused rather than rounded")
    if a.size and (a.min() < 0 or a.max() >= n):
        bad = ((a < 0) | (a >= n)).any(axis=1)
        first = int(np.argmax(bad))
        raise MeshError(f"{row} {first} refers to {target} {a[first].tolist()}, outside 0..{n - 1}; {fix}")
    return a.astype(np.int64)


def _check_coincident_vertices(V, F) -> None:
    used = np.unique(F)
    _, inverse, counts = np.unique(V[used], axis=0, return_inverse=True, return_counts=True)
    repeated = counts[inverse.reshape(-1)] > 1
    if repeated.any():
        first = used[np.argmax(repeated)]
        twins = used[np.flatnonzero(np.all(V[used] == V[first], axis=1))]
        raise MeshError(
            f"surface has {int(repeated.sum())} vertices at the same position as another (first: vertices "
            f"{', '.join(map(str, twins[:4]))} at {np.round(V[first], 6).tolist()} m, in triangles "
            f"{_triangles_at(F, twins)}): the surface touches itself there; duplicated vertices: merge them "
            "(Blender: Mesh > Clean Up > Merge by Distance); two parts touching along an edge or at a corner: move "
            "them apart, or overlap them and join them into one shell (Face > Intersect (Boolean), Union)"
        )


def _triangles_at(F, vertices, shown: int = 8) -> str:
    """The first triangles that use any of the vertices, for messages."""
    faces = np.flatnonzero(np.isin(F, vertices).any(axis=1))
    return ", ".join(map(str, faces[:shown])) + (", ..." if len(faces) > shown else "")


def _unique_edges(F) -> np.ndarray:
    return np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1), axis=0)


def _check_triangle_areas(V, F) -> None:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    diagonal = np.linalg.norm(V.max(axis=0) - V.min(axis=0))
    degenerate = area <= 1e-14 * diagonal**2
    if degenerate.any():
        first = np.argmax(degenerate)
        raise MeshError(
            f"surface has {degenerate.sum()} zero-area triangles (first is triangle {first}, "
            f"vertices {F[first].tolist()}); merge close vertices and dissolve degenerate "
            "faces (Blender: Mesh > Clean Up > Merge by Distance, Degenerate Dissolve)"
        )


def _check_spikes(V, F) -> None:
    """A vertex whose every edge is far longer than the surface's typical edge: a coordinate
    lost on the way (nan read as 0) makes one."""
    edges = _unique_edges(F)
    lengths = np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1)
    shortest = np.full(len(V), np.inf)
    np.minimum.at(shortest, edges[:, 0], lengths)
    np.minimum.at(shortest, edges[:, 1], lengths)
    median = float(np.median(lengths))
    spikes = np.flatnonzero(np.isfinite(shortest) & (shortest > SPIKE_FACTOR * median))
    if len(spikes):
        first = spikes[np.argmax(shortest[spikes])]
        raise MeshError(
            f"surface has {len(spikes)} spike vertices whose every edge is over {SPIKE_FACTOR:g}x the surface's "
            f"median edge ({median * 1e3:.3g} mm): vertex {first} at {np.round(V[first], 6).tolist()} m, in "
            f"triangles {_triangles_at(F, [first])}, has its shortest edge {shortest[first] * 1e3:.3g} mm (a "
            "coordinate lost on export reads as 0; Blender's OBJ importer turns nan into 0); move it back onto the "
            "surface, or delete it and fill the hole (Blender: select it, Mesh > Delete > Vertices, then Mesh > "
            "Clean Up > Fill Holes)"
        )


def _check_manifold_edges(V, F) -> None:
    n = len(V)
    tails = F.reshape(-1)
    heads = F[:, [1, 2, 0]].reshape(-1)
    undirected = np.minimum(tails, heads) * n + np.maximum(tails, heads)
    _, inverse, uses = np.unique(undirected, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    for mask, problem, fix in (
        (
            uses == 1,
            "surface is open: {count} boundary edges",
            "close the holes (Blender: Select > Select All by Trait > Non Manifold, then "
            "Face > Fill)",
        ),
        (
            uses > 2,
            "surface is non-manifold: {count} edges shared by more than two triangles",
            "make every edge border exactly two faces (Blender: Select > Select All by "
            "Trait > Non Manifold, then delete or separate the extra faces; Mesh > Clean Up > "
            "Merge by Distance if they are duplicates; two solids sharing an edge: move them apart, "
            "or overlap them and join them with Face > Intersect (Boolean), Union)",
        ),
    ):
        if mask.any():
            edge = int(np.argmax(mask))
            faces = np.flatnonzero(inverse == edge) // 3
            at = int(np.flatnonzero(inverse == edge)[0])
            raise MeshError(
                f"{problem.format(count=mask.sum())} (first from vertex {tails[at]} to "
                f"vertex {heads[at]}, triangles {', '.join(map(str, faces[:6]))}); {fix} before tetrahedralizing"
            )
    # On a closed manifold each edge has two triangles; they agree on the winding exactly
    # when they traverse the edge in opposite directions.
    _, first_use, uses = np.unique(tails * n + heads, return_index=True, return_counts=True)
    if (uses > 1).any():
        edge = first_use[np.argmax(uses > 1)]
        raise MeshError(
            f"surface winding is inconsistent: {(uses > 1).sum()} edges are traversed the same "
            f"way by both their triangles (first from vertex {tails[edge]} to vertex "
            f"{heads[edge]}, triangle {edge // 3}); make the normals consistent (Blender: "
            "Mesh > Normals > Recalculate Outside)"
        )


def _check_manifold_vertices(F) -> None:
    """Each vertex's triangles form one fan: two solids that share only a vertex (or a cone of
    two fans) make a vertex with more than one. Needs manifold, consistently wound edges."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = len(F)
    n = int(F.max()) + 1
    tails, heads = F.reshape(-1), F[:, [1, 2, 0]].reshape(-1)
    # corner 3 f + k is triangle f at its vertex F[f, k]; the half-edge k runs from it to the next
    order = np.argsort(tails * n + heads)
    twin = order[np.searchsorted((tails * n + heads)[order], heads * n + tails)]
    # the twin half-edge runs head -> tail: its triangle's corner at our tail is the next corner
    next_corner = 3 * (twin // 3) + (twin % 3 + 1) % 3
    corners = np.arange(3 * m)
    graph = coo_matrix((np.ones(3 * m), (corners, next_corner)), shape=(3 * m, 3 * m))
    _, labels = connected_components(graph, directed=False)
    fans = np.unique(np.stack([tails, labels], axis=1), axis=0)
    per_vertex = np.bincount(fans[:, 0], minlength=n)
    bad = np.flatnonzero(per_vertex > 1)
    if len(bad):
        v = int(bad[0])
        raise MeshError(
            f"surface is non-manifold at {len(bad)} vertices where separate sheets meet at one point (first is "
            f"vertex {v}, in {per_vertex[v]} separate fans of triangles "
            f"{', '.join(map(str, sorted(set((corners[tails == v] // 3).tolist()))[:8]))}); split them apart or join "
            "the parts with faces (Blender: Select > Select All by Trait > Non Manifold, then Mesh > Split or "
            "Vertex > Rip)"
        )


def _check_volume(V, F) -> None:
    volume = surface_volume(V, F)
    extent = V.max(axis=0) - V.min(axis=0)
    diagonal = float(np.linalg.norm(extent))
    if abs(volume) <= FLAT_VOLUME * diagonal**3:
        centred = V - V.mean(axis=0)
        thickness = float(np.ptp(centred @ np.linalg.svd(centred, full_matrices=False)[2][-1]))
        raise MeshError(
            f"surface encloses no volume ({volume:.3g} m^3 in a {diagonal * 100:.3g} cm box): it is flat "
            f"({thickness * 1e3:.3g} mm thick at its thinnest) or two sheets lie on each other; a hand or soft "
            "body must be a solid: give it thickness (Blender: a Solidify modifier, applied)"
        )
    if volume < 0.0:
        raise MeshError(
            f"surface encloses a negative volume ({volume:.3g} m^3): its triangles are wound "
            "inward; flip the normals (Blender: Mesh > Normals > Recalculate Outside, or Flip)"
        )


def self_intersections(V, F, capacity: int = 64) -> tuple[np.ndarray, int]:
    """Pairs of triangles (i < j, the first `capacity`) that cross or touch where a closed
    manifold surface keeps them apart (hh_surface_self_intersections), and how many there are."""
    import ctypes

    from . import native

    V, F = surface_arrays(V, F)
    V, F = np.ascontiguousarray(V), np.ascontiguousarray(F, dtype=np.int32)
    pairs = np.zeros((capacity, 2), dtype=np.int32)
    count = ctypes.c_int()
    fn = native.library().hh_surface_self_intersections
    pd, pi = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int)
    fn.argtypes = [pd, ctypes.c_int, pi, ctypes.c_int, pi, ctypes.c_int, pi]
    fn.restype = ctypes.c_int
    native._check(fn(V.ctypes.data_as(pd), len(V), F.ctypes.data_as(pi), len(F), pairs.ctypes.data_as(pi), capacity,
                     ctypes.byref(count)))
    return pairs[: min(count.value, capacity)], count.value


def _check_self_intersections(V, F) -> None:
    pairs, count = self_intersections(V, F, capacity=5)
    if count:
        named = ", ".join(f"{i} and {j}" for i, j in pairs)
        raise MeshError(
            f"surface intersects itself: {count} pairs of triangles cross (first: triangles {named}), as "
            "where two shells overlap or a part pokes through another; separate the parts or merge them into one "
            "shell (Blender: Mesh > Clean Up > Merge by Distance and Delete Loose; overlapping shells: Face > "
            "Intersect (Boolean), Union; Overlays > Mesh Analysis > Intersect shows where)"
        )


def scale_warning(V, what: str = "hand") -> str | None:
    """A warning when a hand's largest extent is far outside a human hand's (about 5-50 cm),
    naming the unit it looks modelled in; None when it is in range."""
    V = np.asarray(V, dtype=np.float64)
    size = float(np.ptp(V, axis=0).max()) if V.size else 0.0
    low, high = HAND_SIZE_RANGE
    if not math.isfinite(size) or size <= 0 or low <= size <= high:
        return None
    units = {"millimetres": 1e-3, "centimetres": 1e-2, "inches": 0.0254, "metres": 1.0,
             "kilometres": 1e3, "feet": 0.3048}
    fits = {name: f for name, f in units.items() if low <= size * f <= high}
    if fits:
        name = min(fits, key=lambda k: abs(math.log(size * fits[k] / TYPICAL_HAND_SIZE)))
        guess = f"it looks modelled in {name} ({size:.4g} {name} = {size * fits[name] * 100:.3g} cm): scale it by {fits[name]:g}"
    else:
        guess = f"scale it by about {TYPICAL_HAND_SIZE / size:.3g}"
    return (f"the {what} is {size:.4g} m long, far from a human hand's 5-50 cm: {guess} (Blender: set the OBJ "
            "importer's scale, or scale the object and Object > Apply > Scale)")


# --------------------------------------------------------------------------------------------
# Tetrahedra
# --------------------------------------------------------------------------------------------


def tet_signed_volumes(nodes, tets) -> np.ndarray:
    """Signed volume of each tet, det[x1 - x0, x2 - x0, x3 - x0] / 6."""
    x = np.asarray(nodes, dtype=np.float64)[np.asarray(tets)]
    edges = x[:, 1:] - x[:, :1]
    return np.einsum("ij,ij->i", edges[:, 0], np.cross(edges[:, 1], edges[:, 2])) / 6.0


def check_tets(nodes, tets) -> None:
    """Raise MeshError unless every tet indexes a finite node and has positive volume."""
    nodes, tets = tet_arrays(nodes, tets)
    volumes = tet_signed_volumes(nodes, tets)
    bad = volumes <= MIN_TET_VOLUME
    if bad.any():
        first = np.argmax(bad)
        kind = "inverted" if volumes[first] < 0 else "zero-volume"
        raise MeshError(
            f"{bad.sum()} tets are inverted or degenerate; first is tet {first} ({kind}, "
            f"volume {volumes[first]:.3g} m^3, at most {MIN_TET_VOLUME:g}); re-tetrahedralize "
            "the surface, or swap two vertices of inverted tets"
        )


def tet_arrays(nodes, tets, where: str = "") -> tuple[np.ndarray, np.ndarray]:
    """nodes as finite float64 (n, 3), tets as int64 (m >= 1, 4) indices into them, or MeshError
    (its message starts with `where`, e.g. the scene field the arrays came from)."""
    lead = f"{where}: " if where else ""
    try:
        nodes = np.asarray(nodes, dtype=np.float64)
    except (TypeError, ValueError):
        raise MeshError(f"{lead}tet nodes must be numbers, an (n, 3) array of positions in metres") from None
    tets = np.asarray(tets)
    if tets.ndim != 2 or tets.shape[1] != 4 or len(tets) < 1:
        raise MeshError(
            f"{lead}tet array has shape {tets.shape}; a tet mesh needs at least one tet as (m, 4) "
            "indices: tetrahedralize the surface"
        )
    if nodes.ndim != 2 or nodes.shape[1] != 3:
        raise MeshError(f"{lead}node array has shape {nodes.shape}; pass node positions as (n, 3)")
    bad = ~np.isfinite(nodes).all(axis=1)
    if bad.any():
        raise MeshError(
            f"{lead}{bad.sum()} tet nodes have NaN or infinite coordinates (first is node "
            f"{np.argmax(bad)}); re-tetrahedralize the surface"
        )
    try:
        tets = index_array(tets, len(nodes), "tet", "node", "re-tetrahedralize the surface")
    except MeshError as e:
        raise MeshError(f"{lead}{e}") from None
    return nodes, tets


def load_tets(path, where: str) -> tuple[np.ndarray, np.ndarray]:
    """nodes float64 (n, 3) and tets int32 (m, 4) from an .npz with those arrays, checked as
    tet_arrays checks them; every failure is a MeshError naming `where` (the scene field)."""
    import zipfile

    path = pathlib.Path(path)
    if not path.is_file():
        what = "is a directory" if path.is_dir() else "does not exist"
        raise MeshError(f"{where} file {path} {what}: give the .npz path relative to the scene file")
    fix = "save it with numpy.savez(path, nodes=nodes, tets=tets)"
    try:
        stored = np.load(path, allow_pickle=False)
        if not isinstance(stored, np.lib.npyio.NpzFile):
            raise MeshError(f"{where} file {path} is a single array, not an .npz archive: {fix}")
        with stored:
            missing = [k for k in ("nodes", "tets") if k not in stored.files]
            if missing:
                raise MeshError(f"{where} file {path} has no {' or '.join(repr(k) for k in missing)} array (it has "
                                f"{', '.join(stored.files) or 'none'}): {fix}")
            nodes, tets = stored["nodes"], stored["tets"]
    except MeshError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as e:
        raise MeshError(f"{where} file {path} is not a readable .npz ({type(e).__name__}: {e}): {fix}") from None
    if nodes.dtype.kind not in "iuf":
        raise MeshError(f"{where} file {path}: nodes are of type {nodes.dtype}, not numbers: {fix}")
    nodes, tets = tet_arrays(nodes, tets, f"{where} file {path}")
    return nodes, tets.astype(np.int32)


def tetrahedralize(V, F, edge_length_fac=None, coarsen=None, epsilon=None, progress=None, sizing=None):
    """Fill a closed surface with positively oriented tets using pytetwild (fTetWild).

    edge_length_fac: target tet edge length as a fraction of the bounding-box diagonal.
    coarsen: coarsen the tets as far as their quality allows.
    epsilon: how far the tet boundary may stray from the surface, relative to that diagonal.
    An option left None takes the parameter table's default (hand.tetrahedralize.*), the one
    scenes and Blender use.
    progress: optional callable progress(fraction, message), called between stages.
    sizing: optional (nodes (k, 3), tets (j, 4), edge lengths (k,) in m), a background tet mesh
    covering the surface whose interpolated values ask for the edge length there (fTetWild's
    sizing field; it refines where they are below edge_length_fac's length): finer tets where
    joints bend.
    Returns (nodes float64 (n, 3), tets int32 (m, 4)); every node belongs to a tet.
    The output of pytetwild differs from run to run: store the tets you simulate.
    """

    def report(fraction, message):
        if progress is not None:
            progress(fraction, message)

    from . import params

    table = params.defaults()["hand"]["tetrahedralize"]
    edge_length_fac = table["edge_length_fac"] if edge_length_fac is None else edge_length_fac
    coarsen = table["coarsen"] if coarsen is None else coarsen
    epsilon = table["epsilon"] if epsilon is None else epsilon
    report(0.0, "checking the surface")
    check_closed_surface(V, F)
    report(0.05, "tetrahedralizing (fTetWild)")
    import pytetwild

    # fTetWild writes this debug file into the working directory; remove it unless it
    # was there already.
    stray = pathlib.Path(_FTETWILD_STRAY_FILE)
    stray_existed = stray.exists()
    try:
        field = {} if sizing is None else dict(zip(("bg_vertices", "bg_tets", "bg_values"), sizing))
        nodes, tets = pytetwild.tetrahedralize(
            np.ascontiguousarray(V, dtype=np.float64),
            np.ascontiguousarray(F, dtype=np.int32),
            edge_length_fac=edge_length_fac,
            coarsen=coarsen,
            epsilon=epsilon,
            quiet=True,
            **field,
        )
    finally:
        if not stray_existed:
            stray.unlink(missing_ok=True)
    nodes = np.asarray(nodes, dtype=np.float64).reshape(-1, 3)
    tets = np.asarray(tets, dtype=np.int64).reshape(-1, 4)
    if len(tets) == 0:
        raise MeshError(
            "pytetwild returned no tets; check that the surface encloses a volume larger than "
            "the target edge length, or lower edge_length_fac"
        )

    report(0.9, "orienting tets")
    inverted = tet_signed_volumes(nodes, tets) < 0.0
    tets[inverted] = tets[inverted][:, [0, 2, 1, 3]]
    used, compact = np.unique(tets, return_inverse=True)
    nodes = nodes[used]
    tets = compact.reshape(-1, 4).astype(np.int32)
    volumes = tet_signed_volumes(nodes, tets)
    if (volumes <= MIN_TET_VOLUME).any():
        first = np.argmax(volumes <= MIN_TET_VOLUME)
        raise MeshError(
            f"pytetwild made {(volumes <= MIN_TET_VOLUME).sum()} flat tets (first is tet "
            f"{first}, volume {volumes[first]:.3g} m^3); tetrahedralize again with a larger "
            "edge_length_fac or epsilon, or check that the surface is in metres"
        )
    report(1.0, f"done: {len(tets)} tets, {len(nodes)} nodes")
    return nodes, tets


def tet_boundary_faces(tets) -> np.ndarray:
    """Triangles used by exactly one tet, wound outward (for positively oriented tets)."""
    faces, on_boundary = _boundary_face_mask(tets)
    return faces[on_boundary].astype(np.int32)


def structured_box(size, cells, origin=(0.0, 0.0, 0.0)):
    """A box of cells[0] x cells[1] x cells[2] cubes, each split into six positively oriented
    tets around its main diagonal (a conforming Kuhn subdivision): a deterministic soft body
    for tests and sample scenes. Returns (nodes, tets); its surface is tet_boundary_faces."""
    size = np.asarray(size, dtype=np.float64)
    cells = np.asarray(cells, dtype=np.int64)
    axes = [np.linspace(0.0, size[k], cells[k] + 1) + origin[k] for k in range(3)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    nodes = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)

    def node_id(i, j, k):
        return (k * (cells[1] + 1) + j) * (cells[0] + 1) + i

    i, j, k = np.meshgrid(np.arange(cells[0]), np.arange(cells[1]), np.arange(cells[2]), indexing="ij")
    i, j, k = i.ravel(), j.ravel(), k.ravel()
    corner = [node_id(i + (b & 1), j + ((b >> 1) & 1), k + ((b >> 2) & 1)) for b in range(8)]
    paths = [(1, 3), (1, 5), (2, 3), (2, 6), (4, 5), (4, 6)]
    tets = np.concatenate([np.stack([corner[0], corner[a], corner[b], corner[7]], axis=1) for a, b in paths])
    flip = tet_signed_volumes(nodes, tets) < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    return nodes, tets.astype(np.int32)


# --------------------------------------------------------------------------------------------
# Barycentric embedding
# --------------------------------------------------------------------------------------------


class _BoundingSpheres:
    """Spheres about the centroids of simplices (tets or triangles) that hold them, kept in
    k-d trees, one per octave of radius, so that a search near small simplices is not
    flooded by the reach of the largest ones."""

    def __init__(self, corners):
        self.centres = corners.mean(axis=1)
        self.radii = np.linalg.norm(corners - self.centres[:, None], axis=2).max(axis=1)
        self.tree = cKDTree(self.centres)
        octave = np.floor(np.log2(self.radii / self.radii.min())).astype(int)
        self.buckets = []
        for level in np.unique(octave):
            ids = np.flatnonzero(octave == level)
            self.buckets.append((ids, cKDTree(self.centres[ids]), self.radii[ids].max()))

    def nearest(self, points, k):
        """(owner, simplex) pairs: the k simplices with centroids nearest each point."""
        k = min(k, len(self.centres))
        _, ids = self.tree.query(points, k=k)
        return np.repeat(np.arange(len(points)), k), ids.reshape(-1)

    def within(self, points, distance):
        """(owner, simplex) pairs for every simplex whose sphere comes within distance[i] of
        points[i]: all those that could contain the point or be that close to it."""
        owners, candidates = [], []
        for ids, tree, radius in self.buckets:
            bucket_owners, bucket_ids = _pairs(tree.query_ball_point(points, r=distance + radius))
            owners.append(bucket_owners)
            candidates.append(ids[bucket_ids])
        owners, candidates = np.concatenate(owners), np.concatenate(candidates)
        gap = np.linalg.norm(points[owners] - self.centres[candidates], axis=1)
        keep = gap - self.radii[candidates] <= distance[owners]
        return owners[keep], candidates[keep]


def _pairs(candidate_lists):
    """Flatten ragged candidate lists into (owner row, candidate) index arrays."""
    counts = np.fromiter(map(len, candidate_lists), dtype=np.int64, count=len(candidate_lists))
    owners = np.repeat(np.arange(len(candidate_lists)), counts)
    candidates = np.fromiter(
        (t for c in candidate_lists for t in c), dtype=np.int64, count=int(counts.sum())
    )
    return owners, candidates


def _first_per_owner(owners, order_key, count):
    """For each of `count` owners, the index of its pair with the smallest key, or -1."""
    chosen = np.full(count, -1, dtype=np.int64)
    if len(owners) == 0:
        return chosen
    order = np.lexsort((order_key, owners))
    first = order[np.r_[True, owners[order][1:] != owners[order][:-1]]]
    chosen[owners[first]] = first
    return chosen


def closest_point_on_triangles(p, a, b, c):
    """Closest point to p[i] on triangle (a[i], b[i], c[i]), after Ericson, Real-Time
    Collision Detection, 5.1.5: find the Voronoi region of p (vertex, edge or face)."""

    def dot(u, v):
        return np.einsum("ij,ij->i", u, v)

    def ratio(num, den):
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(den != 0.0, num / den, 0.0)[:, None]

    ab, ac, bc = b - a, c - a, c - b
    d1, d2 = dot(ab, p - a), dot(ac, p - a)
    d3, d4 = dot(ab, p - b), dot(ac, p - b)
    d5, d6 = dot(ab, p - c), dot(ac, p - c)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    total = va + vb + vc
    regions = [
        ((d1 <= 0) & (d2 <= 0), a),
        ((d3 >= 0) & (d4 <= d3), b),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ratio(d1, d1 - d3) * ab),
        ((d6 >= 0) & (d5 <= d6), c),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ratio(d2, d2 - d6) * ac),
        ((va <= 0) & (d4 >= d3) & (d5 >= d6), b + ratio(d4 - d3, (d4 - d3) + (d5 - d6)) * bc),
    ]
    closest = a + ratio(vb, total) * ab + ratio(vc, total) * ac  # inside the face
    for region, point in reversed(regions):  # so that earlier regions take precedence
        closest = np.where(region[:, None], point, closest)
    return closest


def _barycentric_weights(corners, points):
    """Unclamped barycentric weights (m, 4) of points[i] in the tet with corners[i]."""
    edges = np.transpose(corners[:, 1:] - corners[:, :1], (0, 2, 1))  # columns x1-x0, ...
    local = np.linalg.solve(edges, (points - corners[:, 0])[..., None])[..., 0]
    return np.concatenate([1.0 - local.sum(axis=1, keepdims=True), local], axis=1)


def _boundary_face_mask(tets):
    """Outward faces of every tet (4 per tet, in tet order) and which are used only once."""
    faces = np.asarray(tets)[:, _TET_FACES].reshape(-1, 3)
    _, inverse, uses = np.unique(
        np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True
    )
    return faces, uses[inverse.reshape(-1)] == 1


def embed_points(nodes, tets, points, return_gap: bool = False):
    """Barycentric coordinates of each point in a tet of the mesh.

    A point inside the mesh gets a tet containing it (all weights >= 0 up to rounding).
    A point outside every tet (pytetwild's envelope lets the surface stray from the tet
    boundary) gets the nearest tet and unclamped weights, which extrapolate exactly.
    Either way sum_j weights[i, j] * nodes[tets[tet_index[i], j]] == points[i].
    Returns (tet_index int32 (p,), weights float64 (p, 4)), and with return_gap each point's
    distance outside the tets (m, 0 inside) as a third array.
    """
    check_tets(nodes, tets)
    nodes, tets = tet_arrays(nodes, tets)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    corners = nodes[tets]
    spheres = _BoundingSpheres(corners)
    tet_index = np.full(len(points), -1, dtype=np.int64)
    weights = np.zeros((len(points), 4))
    gap = np.zeros(len(points))

    def take_containing(rows, owners, candidates):
        """Give each of points[rows] the lowest-numbered candidate tet containing it."""
        pair_weights = _barycentric_weights(corners[candidates], points[rows][owners])
        hits = np.flatnonzero(pair_weights.min(axis=1) >= -_INSIDE_TOLERANCE)
        chosen = _first_per_owner(owners[hits], candidates[hits], len(rows))
        found = chosen >= 0
        tet_index[rows[found]] = candidates[hits[chosen[found]]]
        weights[rows[found]] = pair_weights[hits[chosen[found]]]
        return rows[~found]

    # Most points lie in one of the few tets whose centroids are nearest; for the rest,
    # try every tet whose bounding sphere holds the point (the containment test accepts
    # points a hair outside, hence the slack).
    rest = take_containing(np.arange(len(points)), *spheres.nearest(points, _NEAREST_CANDIDATES))
    if len(rest):
        slack = np.full(len(rest), 1e-9 * spheres.radii.max())
        rest = take_containing(rest, *spheres.within(points[rest], slack))

    # Points outside the mesh get the nearest tet, the owner of the nearest boundary face:
    # the distance to a few faces with nearby centroids bounds the search for it.
    if len(rest):
        faces, on_boundary = _boundary_face_mask(tets)
        face_tets = np.flatnonzero(on_boundary) // 4
        triangles = nodes[faces[on_boundary]]
        face_spheres = _BoundingSpheres(triangles)
        outside = points[rest]

        def distances(owners, face_ids):
            a, b, c = (triangles[face_ids, i] for i in range(3))
            closest = closest_point_on_triangles(outside[owners], a, b, c)
            return np.linalg.norm(outside[owners] - closest, axis=1)

        owners, face_ids = face_spheres.nearest(outside, _NEAREST_CANDIDATES)
        bound = np.full(len(rest), np.inf)
        np.minimum.at(bound, owners, distances(owners, face_ids))
        owners, face_ids = face_spheres.within(outside, bound * (1 + 1e-9))
        pair_distances = distances(owners, face_ids)
        chosen = _first_per_owner(owners, pair_distances, len(rest))
        tet_index[rest] = face_tets[face_ids[chosen]]
        weights[rest] = _barycentric_weights(corners[tet_index[rest]], outside)
        gap[rest] = pair_distances[chosen]

    if return_gap:
        return tet_index.astype(np.int32), weights, gap
    return tet_index.astype(np.int32), weights


def interpolate_embedded(nodes_positions, tets, tet_index, weights) -> np.ndarray:
    """Positions of embedded points given (possibly deformed) tet node positions."""
    corners = np.asarray(nodes_positions, dtype=np.float64)[np.asarray(tets)[tet_index]]
    return np.einsum("pj,pjk->pk", weights, corners)


# --------------------------------------------------------------------------------------------
# Inside test
# --------------------------------------------------------------------------------------------


def winding_numbers(V, F, points, chunk=256) -> np.ndarray:
    """Generalized winding number of the closed surface (V, F) at each point: the solid angle
    the surface subtends there over 4 pi (1 inside, 0 outside)."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F)
    points = np.atleast_2d(np.asarray(points, dtype=np.float64))
    total = np.zeros(len(points))
    for start in range(0, len(F), chunk):
        a, b, c = (V[F[start : start + chunk, i]][None] - points[:, None] for i in range(3))
        la, lb, lc = (np.linalg.norm(u, axis=2) for u in (a, b, c))
        # Van Oosterom and Strackee: tan(omega / 2) of each triangle's solid angle.
        numerator = np.einsum("pij,pij->pi", a, np.cross(b, c))
        denominator = (
            la * lb * lc
            + np.einsum("pij,pij->pi", a, b) * lc
            + np.einsum("pij,pij->pi", b, c) * la
            + np.einsum("pij,pij->pi", c, a) * lb
        )
        total += 2.0 * np.arctan2(numerator, denominator).sum(axis=1)
    return total / (4.0 * math.pi)


def point_inside_surface(V, F, p) -> bool:
    """True when p is inside the closed surface (winding number above one half)."""
    return bool(winding_numbers(V, F, p)[0] > 0.5)
