"""Procedural soft objects for sample scenes: a bunny-like soft toy and extruded block letters,
made by the project so that no scene depends on third-party meshes (the Stanford bunny's
licence is research-only).

Each surface is a signed distance field (negative inside) built from spheres, ellipsoids,
capsules and boxes, sampled on a regular grid and contoured by marching cubes, as the
procedural hand in mesh.py. Surfaces are closed, 2-manifold and wound outward (they pass
mesh.check_closed_surface); the same arguments give the same surface.

Each shape also has a coarse tet mesh that holds its surface, for embedding the surface in
the tets (mesh.embed_points) as in the paper: a 4000-triangle bunny on 271 tets, letters of
about 175 triangles on about 65 tets. The bunny's tets come from pytetwild, which is not
deterministic (store the tets you simulate); the letters' tets are prisms over a
triangulation of the letter's outline, and deterministic.

Conventions: SI units (metres); z is up and every shape rests on the ground plane z = 0,
centred on the z axis (x = y = 0); positions float64 (n, 3), triangles int32 (m, 3), tets
int32 (m, 4), positively oriented. Never imports bpy.
"""

from __future__ import annotations

import numpy as np

from .mesh import (
    MeshError,
    capsule_distance,
    clean_surface,
    closest_point_on_triangles,
    smooth_union,
    surface_volume,
    tet_signed_volumes,
    tetrahedralize,
    winding_numbers,
)

# --------------------------------------------------------------------------------------------
# Contouring
# --------------------------------------------------------------------------------------------


def _contour_distance(distance, lower, upper, spacing, project=0):
    """Closed, outward-wound surface of {p : distance(p) < 0} inside the box [lower, upper].

    distance maps points (n, 3) to signed distances (n,); spacing is the grid step, a scalar
    or one per axis. The grid is widened by two cells on every side so the contour closes.
    project: Newton steps moving the vertices onto the zero level (marching cubes cuts
    corners and edges of the shape, which a coarse grid makes large).
    Returns (V float64 (n, 3), F int32 (m, 3)).
    """
    import pyvista

    spacing = np.broadcast_to(np.asarray(spacing, dtype=np.float64), (3,)).copy()
    lower = np.asarray(lower, dtype=np.float64) - 2 * spacing
    upper = np.asarray(upper, dtype=np.float64) + 2 * spacing
    dims = np.ceil((upper - lower) / spacing).astype(int) + 1
    grid = pyvista.ImageData(dimensions=dims, spacing=tuple(spacing), origin=tuple(lower))
    values = np.asarray(distance(np.asarray(grid.points, dtype=np.float64)), dtype=np.float64)
    # Keep samples off the zero level so marching cubes makes no tiny or zero-length
    # edges (moving the level by a thousandth of a step).
    tiny = 1e-3 * spacing.min()
    values = np.where(np.abs(values) < tiny, tiny, values)
    grid.point_data["distance"] = values
    contour = grid.contour([0.0], scalars="distance", method="marching_cubes").triangulate()
    V = np.asarray(contour.points, dtype=np.float64)
    F = np.asarray(contour.faces, dtype=np.int64).reshape(-1, 4)[:, 1:]
    V, F = clean_surface(V, F)
    for _ in range(project):
        V = _project_to_zero_level(distance, V, spacing.min())
    if surface_volume(V, F) < 0.0:
        F = F[:, ::-1]
    return V, np.ascontiguousarray(F, dtype=np.int32)


def _project_to_zero_level(distance, V, step):
    """One Newton step of each vertex towards distance == 0 along the gradient (central
    differences), moving no vertex further than half a grid step."""
    h = 1e-4 * step
    gradient = np.stack(
        [(distance(V + h * e) - distance(V - h * e)) / (2 * h) for e in np.eye(3)], axis=1
    )
    squared = np.maximum((gradient**2).sum(axis=1), 1e-12)
    move = -(distance(V) / squared)[:, None] * gradient
    length = np.linalg.norm(move, axis=1, keepdims=True)
    return V + move * np.minimum(1.0, 0.5 * step / np.maximum(length, 1e-300))


def _ellipsoid_distance(p, centre, radii):
    # A close bound of the distance to an ellipsoid (Quilez): exact on the surface and on
    # the axes, with the right sign everywhere.
    q = (p - centre) / radii
    k0 = np.linalg.norm(q, axis=-1)
    k1 = np.linalg.norm(q / radii, axis=-1)
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-300)


def _sphere_distance(p, centre, radius):
    return np.linalg.norm(p - centre, axis=-1) - radius


def _smooth_intersection(d1, d2, k):
    return -smooth_union(-d1, -d2, k)


# --------------------------------------------------------------------------------------------
# Bunny
# --------------------------------------------------------------------------------------------
# A sitting rabbit facing +X: an egg-shaped body with haunches, a head at the front, two long
# ears standing up from the head, a round tail at the back; the bottom is cut flat (a smooth
# intersection with a half-space) so it rests on z = 0. Before the final translation the
# ground plane is at z = _BUNNY_GROUND.

_BUNNY_GROUND = 0.010
_BUNNY_BODY = (np.array([-0.012, 0.0, 0.040]), np.array([0.050, 0.044, 0.042]))
_BUNNY_HAUNCHES = tuple(
    (np.array([-0.025, side * 0.028, 0.026]), np.array([0.030, 0.017, 0.024])) for side in (-1, 1)
)
_BUNNY_FEET = tuple(
    (np.array([0.014, side * 0.026, 0.010]), np.array([0.022, 0.012, 0.010])) for side in (-1, 1)
)
_BUNNY_HEAD = (np.array([0.040, 0.0, 0.078]), np.array([0.032, 0.026, 0.026]))
_BUNNY_SNOUT = (np.array([0.066, 0.0, 0.072]), 0.012)
# Ear capsules (root, tip, radius): rooted in the top of the head, leaning back and outward.
_BUNNY_EARS = tuple(
    (
        np.array([0.036, side * 0.011, 0.094]),
        np.array([0.012, side * 0.025, 0.142]),
        0.0075,
    )
    for side in (-1, 1)
)
_BUNNY_TAIL = (np.array([-0.062, 0.0, 0.046]), 0.013)
_BUNNY_BLEND = 0.012
_BUNNY_EAR_BLEND = 0.008


def _bunny_distance(p):
    body = _ellipsoid_distance(p, *_BUNNY_BODY)
    for centre, radii in _BUNNY_HAUNCHES + _BUNNY_FEET:
        body = smooth_union(body, _ellipsoid_distance(p, centre, radii), _BUNNY_BLEND)
    head = smooth_union(
        _ellipsoid_distance(p, *_BUNNY_HEAD), _sphere_distance(p, *_BUNNY_SNOUT), _BUNNY_BLEND
    )
    # Each ear blends with the head only, so the two ears stay apart.
    head = np.min(
        [
            smooth_union(head, capsule_distance(p, a, b, r), _BUNNY_EAR_BLEND)
            for a, b, r in _BUNNY_EARS
        ],
        axis=0,
    )
    shape = smooth_union(body, head, _BUNNY_BLEND)
    shape = smooth_union(shape, _sphere_distance(p, *_BUNNY_TAIL), _BUNNY_BLEND)
    return _smooth_intersection(shape, _BUNNY_GROUND - p[..., 2], 0.004)


def _bunny_bounds():
    lower = np.array([-0.080, -0.050, _BUNNY_GROUND - 0.001])
    upper = np.array([0.080, 0.050, 0.150])
    return lower, upper


def _place_on_ground(V):
    """Translate V so that its minimum z is 0 and its bounding box is centred on x = y = 0."""
    V = V + _ground_shift(V)
    V[:, 2] = np.maximum(V[:, 2], 0.0)
    return V


def procedural_bunny(resolution: float = 0.0053):
    """Closed, outward-wound, genus-0 surface of a bunny-like soft toy, about 15 cm long.

    A sitting rabbit facing +X with two long ears pointing up, a round tail at -X and a flat
    bottom resting on z = 0; its bounding box is centred on x = y = 0. The default grid step
    `resolution` (m) gives about 4000 triangles.
    Returns (V float64 (n, 3), F int32 (m, 3)); the same arguments give the same mesh.
    """
    _check_resolution(resolution, 0.006, "procedural_bunny", "the 15 mm thick ears")
    V, F = _contour_distance(_bunny_distance, *_bunny_bounds(), resolution)
    return _place_on_ground(V), F


def _check_resolution(resolution, largest, function, feature):
    if not 0.0 < resolution <= largest:
        raise MeshError(
            f"{function}: resolution {resolution} m is out of range: the grid must be fine "
            f"enough to resolve {feature}; pass a resolution between 0 and {largest} m"
        )


# --------------------------------------------------------------------------------------------
# Block letters
# --------------------------------------------------------------------------------------------
# Each letter is a 2D shape in the letter plane, in units of the letter height: u across
# (becomes x), v up (becomes z, from 0 to 1), made of strokes _STROKE wide. Its surface is
# the extrusion of the shape's distance field along y, contoured; its tets are prisms over
# a triangulation of the shape's exact outline (arcs replaced by polygons around them).

_STROKE = 0.18
_HALF = _STROKE / 2

_H_HALF_WIDTH = 0.35  # H, T and P stems and bars
_A_FOOT = np.array([0.4, -0.2])  # the A's right leg runs from this point to the apex
_A_APEX = np.array([0.0, 1.2])  # (both outside 0 <= v <= 1, which cuts the letter flat)
_A_BAR = 0.26  # bottom of the A's crossbar
_A_BAR_HALF_WIDTH = 0.3
_P_BOWL_BOTTOM = 0.42
_P_RADIUS = (1.0 - _P_BOWL_BOTTOM) / 2  # outer radius of the P's half ring
_P_CENTRE = np.array([0.0, _P_BOWL_BOTTOM + _P_RADIUS])
_I_SERIF = 0.2  # half width of the I's serifs
_C_CENTRE = np.array([0.0, 0.5])
_C_CUT = 0.2  # the C's ring is cut open at u > _C_CUT


def _box_distance_2d(local, half):
    d = np.abs(local) - half
    return np.linalg.norm(np.maximum(d, 0.0), axis=-1) + np.minimum(d.max(axis=-1), 0.0)


def _bar(q, u0, v0, u1, v1):
    """Distance to the axis-aligned rectangle [u0, u1] x [v0, v1]."""
    centre = np.array([u0 + u1, v0 + v1]) / 2
    return _box_distance_2d(q - centre, np.array([u1 - u0, v1 - v0]) / 2)


def _slanted_stroke(q, a, b):
    """Distance to the stroke along the segment a-b, square-ended at a and b."""
    along = (b - a) / np.linalg.norm(b - a)
    across = np.array([-along[1], along[0]])
    offset = q - (a + b) / 2
    local = np.stack([offset @ along, offset @ across], axis=-1)
    return _box_distance_2d(local, np.array([np.linalg.norm(b - a) / 2, _HALF]))


def _ring(q, centre, outer_radius):
    """Distance to the ring of width _STROKE inside the circle of outer_radius."""
    return np.abs(np.linalg.norm(q - centre, axis=-1) - (outer_radius - _HALF)) - _HALF


def _distance_H(q):
    w = _H_HALF_WIDTH
    return np.min(
        [
            _bar(q, -w, 0.0, -w + _STROKE, 1.0),
            _bar(q, w - _STROKE, 0.0, w, 1.0),
            _bar(q, -w, 0.5 - _HALF, w, 0.5 + _HALF),
        ],
        axis=0,
    )


def _distance_A(q):
    # Two legs meeting at the apex, cut flat at the top and bottom, and a crossbar; the
    # counter (hole) between the crossbar and the apex is about 0.4 letter heights tall.
    mirror = np.array([-1.0, 1.0])
    legs = np.minimum(
        _slanted_stroke(q, _A_FOOT, _A_APEX), _slanted_stroke(q, _A_FOOT * mirror, _A_APEX)
    )
    w = _A_BAR_HALF_WIDTH
    shape = np.minimum(legs, _bar(q, -w, _A_BAR, w, _A_BAR + _STROKE))
    return np.maximum(shape, _bar(q, -1.0, 0.0, 1.0, 1.0))


def _distance_P(q):
    # Stem, and a bowl of two bars closed by a half ring on the right. The bars reach into
    # the half ring so that the two overlap: shapes that only touch leave a zero-distance
    # seam that splits the contour.
    w = _H_HALF_WIDTH
    half_ring = np.maximum(_ring(q, _P_CENTRE, _P_RADIUS), -q[..., 0])
    return np.min(
        [
            _bar(q, -w, 0.0, -w + _STROKE, 1.0),
            _bar(q, -w, 1.0 - _STROKE, _HALF, 1.0),
            _bar(q, -w, _P_BOWL_BOTTOM, _HALF, _P_BOWL_BOTTOM + _STROKE),
            half_ring,
        ],
        axis=0,
    )


def _distance_T(q):
    w = _H_HALF_WIDTH
    return np.minimum(_bar(q, -w, 1.0 - _STROKE, w, 1.0), _bar(q, -_HALF, 0.0, _HALF, 1.0))


def _distance_I(q):
    # A stem with serifs at the top and bottom, so the I is more than a plain bar.
    w = _I_SERIF
    return np.min(
        [
            _bar(q, -_HALF, 0.0, _HALF, 1.0),
            _bar(q, -w, 0.0, w, _STROKE),
            _bar(q, -w, 1.0 - _STROKE, w, 1.0),
        ],
        axis=0,
    )


def _distance_C(q):
    # A ring cut open on the right by a vertical line.
    return np.maximum(_ring(q, _C_CENTRE, 0.5), q[..., 0] - _C_CUT)


# Outlines: closed loops of (u, v) corners, the outer loop first, then holes. Arcs become
# polygons that enclose them (outer arcs: polygons tangent to the arc; inner arcs, which
# border holes: chords), so the tets hold the contoured surface.


def _arc_outside(centre, radius, start, stop, max_edge):
    """Corners of a polygon tangent to the arc from angle start to stop (start < stop), its
    ends on the arc. The arc's extreme points in u and v are points of tangency, so the
    polygon has the arc's bounding box."""
    quarter = np.pi / 2
    tangents = [start]
    tangents += list(quarter * np.arange(np.floor(start / quarter) + 1, np.ceil(stop / quarter)))
    tangents += [stop]
    corners = [centre + radius * np.array([np.cos(start), np.sin(start)])]
    for a, b in zip(tangents[:-1], tangents[1:]):
        steps = max(1, int(np.ceil((b - a) * radius / max_edge)))
        step = (b - a) / steps
        # The tangents at a + k step meet at a + (k + 1/2) step, radius / cos(step / 2) out.
        angles = a + step * (np.arange(steps) + 0.5)
        reach = radius / np.cos(step / 2)
        corners.extend(centre + reach * np.stack([np.cos(angles), np.sin(angles)], axis=1))
        corners.append(centre + radius * np.array([np.cos(b), np.sin(b)]))
    return np.array(corners)


def _arc_chords(centre, radius, start, stop, max_edge):
    """Corners of the polygon of chords of the arc from angle start to stop."""
    steps = max(2, int(np.ceil(abs(stop - start) * radius / max_edge)))
    angles = np.linspace(start, stop, steps + 1)
    return centre + radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)


def _outline_H(max_edge):
    w, s, b0, b1 = _H_HALF_WIDTH, _STROKE, 0.5 - _HALF, 0.5 + _HALF
    return [
        np.array(
            [
                (-w, 0), (-w + s, 0), (-w + s, b0), (w - s, b0), (w - s, 0), (w, 0),
                (w, 1), (w - s, 1), (w - s, b1), (-w + s, b1), (-w + s, 1), (-w, 1),
            ]
        )
    ]


def _outline_T(max_edge):
    w, h, t = _H_HALF_WIDTH, _HALF, 1 - _STROKE
    return [np.array([(-h, 0), (h, 0), (h, t), (w, t), (w, 1), (-w, 1), (-w, t), (-h, t)])]


def _outline_I(max_edge):
    w, h, s = _I_SERIF, _HALF, _STROKE
    t = 1 - s
    return [
        np.array(
            [
                (-w, 0), (w, 0), (w, s), (h, s), (h, t), (w, t),
                (w, 1), (-w, 1), (-w, t), (-h, t), (-h, s), (-w, s),
            ]
        )
    ]


def _A_leg_edge(v, offset):
    """u of the right leg's centre line at height v, moved offset across the stroke (+out)."""
    direction = (_A_APEX - _A_FOOT) / np.linalg.norm(_A_APEX - _A_FOOT)
    normal = np.array([direction[1], -direction[0]])  # points out of the letter (+u side)
    # The point of the line foot + t direction + offset normal at height v.
    t = (v - _A_FOOT[1] - offset * normal[1]) / direction[1]
    return _A_FOOT[0] + t * direction[0] + offset * normal[0]


def _outline_A(max_edge):
    bar0, bar1 = _A_BAR, _A_BAR + _STROKE
    outer = lambda v: _A_leg_edge(v, _HALF)  # noqa: E731
    inner = lambda v: _A_leg_edge(v, -_HALF)  # noqa: E731
    # v where the inner edges of the two legs meet on the axis: the top of the counter.
    apex = inner(0.0) / (inner(0.0) - inner(1.0))
    loop = np.array(
        [
            (-outer(0), 0), (-inner(0), 0), (-inner(bar0), bar0), (inner(bar0), bar0),
            (inner(0), 0), (outer(0), 0), (outer(1), 1), (-outer(1), 1),
        ]
    )
    hole = np.array([(-inner(bar1), bar1), (0.0, apex), (inner(bar1), bar1)])
    return [loop, hole]


def _outline_P(max_edge):
    w, s, b = _H_HALF_WIDTH, _STROKE, _P_BOWL_BOTTOM
    outer = _arc_outside(_P_CENTRE, _P_RADIUS, -np.pi / 2, np.pi / 2, max_edge)
    inner = _arc_chords(_P_CENTRE, _P_RADIUS - s, -np.pi / 2, np.pi / 2, max_edge)
    loop = np.concatenate([[(-w, 0), (-w + s, 0), (-w + s, b)], outer, [(-w, 1)]])
    hole = np.concatenate([[(-w + s, b + s)], inner, [(-w + s, 1 - s)]])
    return [loop, hole[::-1]]


def _outline_C(max_edge):
    outer_start = np.arccos(_C_CUT / 0.5)
    inner_start = np.arccos(_C_CUT / (0.5 - _STROKE))
    outer = _arc_outside(_C_CENTRE, 0.5, outer_start, 2 * np.pi - outer_start, max_edge)
    inner = _arc_chords(_C_CENTRE, 0.5 - _STROKE, 2 * np.pi - inner_start, inner_start, max_edge)
    return [np.concatenate([outer, inner])]


_LETTERS = {
    "H": (_distance_H, _outline_H),
    "A": (_distance_A, _outline_A),
    "P": (_distance_P, _outline_P),
    "T": (_distance_T, _outline_T),
    "I": (_distance_I, _outline_I),
    "C": (_distance_C, _outline_C),
}

#: Letters procedural_letter and letter_tets can make.
SUPPORTED_LETTERS = "".join(_LETTERS)

#: Letters with a hole through them (genus 1); the others are genus 0.
LETTERS_WITH_HOLES = "AP"


def _letter(ch):
    if not isinstance(ch, str) or ch.upper() not in _LETTERS:
        raise ValueError(
            f"no procedural letter {ch!r}; supported letters are "
            f"{', '.join(SUPPORTED_LETTERS)} (upper or lower case)"
        )
    return _LETTERS[ch.upper()]


def _letter_surface(ch, height, depth, resolution):
    """The contoured letter before placement on the ground: (V, F)."""
    distance_2d, _ = _letter(ch)
    if not (height > 0.0 and depth > 0.0):
        raise ValueError(f"letter height {height} m and depth {depth} m must be positive")
    if resolution is None:
        resolution = height / 10
    largest = 0.7 * _STROKE * height
    if not 0.0 < resolution <= largest:
        raise MeshError(
            f"procedural_letter: resolution {resolution} m is out of range: the grid must be "
            f"finer than the strokes ({_STROKE * height * 1000:.1f} mm); pass a resolution "
            f"between 0 and {largest:.4g} m"
        )
    # Grid steps chosen so that no sample falls on the flat faces: z samples at half steps
    # (faces at z = 0 and z = height), y samples at whole steps with an odd number of steps
    # through the depth (faces at +-depth / 2 fall half-way between samples).
    step = height / max(1, round(height / resolution))
    steps_y = max(1, round(depth / resolution))
    steps_y += 1 - steps_y % 2
    step_y = depth / steps_y
    half_depth = depth / 2

    def distance(p):
        flat = distance_2d(p[:, [0, 2]] / height) * height
        w = np.stack([flat, np.abs(p[:, 1]) - half_depth], axis=-1)
        return np.minimum(w.max(axis=-1), 0.0) + np.linalg.norm(np.maximum(w, 0.0), axis=-1)

    reach = np.ceil(0.6 * height / step) * step
    lower = np.array([-reach, -(steps_y + 1) / 2 * step_y, -step / 2])
    upper = np.array([reach, half_depth, height])
    spacing = np.array([step, step_y, step])
    return _contour_distance(distance, lower, upper, spacing, project=1)


def _ground_shift(V):
    """The translation _place_on_ground applies to V."""
    lower, upper = V.min(axis=0), V.max(axis=0)
    return np.array([-(lower[0] + upper[0]) / 2, -(lower[1] + upper[1]) / 2, -lower[2]])


def procedural_letter(ch: str, height: float = 0.04, depth: float = 0.012, resolution=None):
    """Closed, outward-wound surface of an extruded block letter standing upright.

    The letter is drawn in the x-z plane, `height` (m) tall from z = 0 up, extruded `depth`
    (m) along y; its bounding box is centred on x = y = 0. The grid step `resolution` (m;
    default a tenth of the height) gives 250-500 triangles.
    A and P have a hole through them (genus 1); the other letters are genus 0.
    Raises ValueError for a letter not in SUPPORTED_LETTERS.
    Returns (V float64 (n, 3), F int32 (m, 3)); the same arguments give the same mesh.
    """
    V, F = _letter_surface(ch, height, depth, resolution)
    return _place_on_ground(V), F


def _inside_loops(points, loops):
    """Even-odd test of 2D points against closed polygon loops."""
    inside = np.zeros(len(points), dtype=bool)
    for loop in loops:
        a, b = loop, np.roll(loop, -1, axis=0)
        u, v = points[:, :1], points[:, 1:]
        crosses = (a[:, 1] > v) != (b[:, 1] > v)
        with np.errstate(divide="ignore", invalid="ignore"):
            at = a[:, 0] + (v - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
        inside ^= (crosses & (u < at)).sum(axis=1) % 2 == 1
    return inside


def _subdivide_loop(loop, max_edge):
    """Loop corners with extra points on every edge longer than max_edge."""
    points = []
    for a, b in zip(loop, np.roll(loop, -1, axis=0)):
        pieces = max(1, int(np.ceil(np.linalg.norm(b - a) / max_edge)))
        points.extend(a + (b - a) * t for t in np.arange(pieces) / pieces)
    return np.array(points)


def _loop_area(loop):
    u, v = loop[:, 0], loop[:, 1]
    return 0.5 * abs(np.dot(u, np.roll(v, -1)) - np.dot(v, np.roll(u, -1)))


def _letter_triangles(ch, max_edge):
    """A triangulation of the letter's outline in (u, v) units: (points (n, 2), triangles)."""
    from scipy.spatial import Delaunay

    _, outline = _letter(ch)
    loops = outline(max_edge)
    points = np.concatenate([_subdivide_loop(loop, max_edge) for loop in loops])
    triangles = Delaunay(points).simplices
    a, b, c = (points[triangles[:, i]] for i in range(3))
    area = 0.5 * ((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    keep = _inside_loops((a + b + c) / 3, loops) & (np.abs(area) > 1e-12)
    triangles, area = triangles[keep], area[keep]
    # The Delaunay triangles inside the outline cover it exactly when every outline edge is
    # a Delaunay edge; the outlines are subdivided finely enough for that.
    expected = _loop_area(loops[0]) - sum(_loop_area(hole) for hole in loops[1:])
    if abs(np.abs(area).sum() - expected) > 1e-9:
        raise MeshError(
            f"letter {ch!r}: the triangulation covers {np.abs(area).sum():.6f} of the outline's "
            f"{expected:.6f} square heights; pass a smaller max_edge"
        )
    flip = area < 0
    triangles[flip] = triangles[flip][:, [0, 2, 1]]
    return points, triangles


def letter_tets(
    ch: str, height: float = 0.04, depth: float = 0.012, resolution=None, max_edge=None
):
    """Tet mesh of the letter of procedural_letter(ch, height, depth, resolution), placed as
    that surface is: the letter's outline (with arcs replaced by polygons around them),
    triangulated with edges of at most max_edge (m; default a quarter of the height) and
    extruded through the depth as one layer of prisms, three tets each; 40-100 tets at the
    default size. Deterministic. Returns (nodes float64 (n, 3), tets int32 (m, 4)),
    positively oriented.
    """
    V, _ = _letter_surface(ch, height, depth, resolution)
    if max_edge is None:
        max_edge = height / 4
    if not max_edge > 0.0:
        raise ValueError(f"letter_tets: max_edge {max_edge} m must be positive")
    points, triangles = _letter_triangles(ch, max_edge / height)
    n = len(points)
    nodes = np.concatenate(
        [
            np.column_stack([points[:, 0], np.full(n, side * depth / 2), points[:, 1]])
            for side in (-1, 1)
        ]
    )
    nodes[:, [0, 2]] *= height
    nodes += _ground_shift(V)
    # Split each prism so that neighbours agree on the diagonals of shared quads: the diagonal
    # of the quad over edge (p, q), p < q, runs from p's bottom to q's top.
    a, b, c = np.sort(triangles, axis=1).T
    tets = np.concatenate(
        [
            np.stack([a, b, c, c + n], axis=1),
            np.stack([a, b, b + n, c + n], axis=1),
            np.stack([a, a + n, b + n, c + n], axis=1),
        ]
    ).astype(np.int64)
    flip = tet_signed_volumes(nodes, tets) < 0.0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    return nodes, tets.astype(np.int32)


# --------------------------------------------------------------------------------------------
# Coarse tet meshes
# --------------------------------------------------------------------------------------------


def _nearest_triangles(V, F, points, chunk=32):
    """Distance from each point to the surface (V, F) and the index of the nearest triangle."""
    best = np.full(len(points), np.inf)
    nearest = np.zeros(len(points), dtype=np.int64)
    for start in range(0, len(F), chunk):
        ids = np.arange(start, min(start + chunk, len(F)))
        owners = np.repeat(np.arange(len(points)), len(ids))
        tris = np.tile(ids, len(points))
        a, b, c = (V[F[tris, i]] for i in range(3))
        closest = closest_point_on_triangles(points[owners], a, b, c)
        gap = np.linalg.norm(points[owners] - closest, axis=1).reshape(len(points), len(ids))
        column = gap.argmin(axis=1)
        gap = gap[np.arange(len(points)), column]
        better = gap < best
        best[better] = gap[better]
        nearest[better] = ids[column[better]]
    return best, nearest


def _vertex_normals(V, F):
    normals = np.zeros_like(V)
    face_normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])  # area weighted
    for corner in range(3):
        np.add.at(normals, F[:, corner], face_normals)
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


# Vertices of a coarse surface this close to the ground plane are snapped onto it and only
# pushed sideways, so the coarse shape rests on z = 0 as the fine one does.
_GROUND_SNAP = 1e-4


def enclosing_surface(V, F, triangles: int, tolerance: float = 0.00075, max_iterations: int = 40):
    """A coarse closed surface of about `triangles` triangles around the closed surface (V, F).

    The fine surface is decimated (quadric error, VTK), then the coarse vertices near fine
    vertices that stick out are pushed outward along their normals, a little at a time, until
    no fine vertex is more than `tolerance` (m) outside. Vertices on the ground plane z = 0
    stay on it. Deterministic. Returns (V float64 (n, 3), F int32 (m, 3)).
    """
    import pyvista

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if not 4 <= triangles < len(F):
        raise ValueError(
            f"enclosing_surface: asked for {triangles} triangles from a surface of {len(F)}; "
            "ask for at least 4 and fewer than the surface has"
        )
    surface = pyvista.PolyData(V, np.column_stack([np.full(len(F), 3), F]).ravel())
    coarse = surface.decimate(1.0 - triangles / len(F))
    coarse_V = np.asarray(coarse.points, dtype=np.float64).copy()
    coarse_F = np.asarray(coarse.faces, dtype=np.int64).reshape(-1, 4)[:, 1:]
    ground = np.abs(coarse_V[:, 2]) < _GROUND_SNAP
    coarse_V[ground, 2] = 0.0

    # Pushing outward keeps inside points inside, so after a full check only the points
    # found outside are checked again, until a full check finds none.
    candidates = np.arange(len(V))
    for _ in range(max_iterations):
        points = V[candidates]
        gap, nearest = _nearest_triangles(coarse_V, coarse_F, points)
        outside = (gap > tolerance) & (winding_numbers(coarse_V, coarse_F, points) < 0.5)
        if not outside.any():
            if len(candidates) == len(V):
                break
            candidates = np.arange(len(V))
            continue
        candidates = candidates[outside]
        # Push each corner of a triangle nearest to a protruding point by part of the gap:
        # whole gaps overshoot, since neighbouring corners move too.
        push = np.zeros(len(coarse_V))
        for corner in range(3):
            np.maximum.at(push, coarse_F[nearest[outside], corner], 0.6 * gap[outside])
        direction = _vertex_normals(coarse_V, coarse_F)
        direction[ground, 2] = 0.0
        coarse_V += push[:, None] * direction
        coarse_V[:, 2] = np.maximum(coarse_V[:, 2], 0.0)
    else:
        raise MeshError(
            f"enclosing_surface: {len(candidates)} fine vertices are still more than "
            f"{tolerance * 1000:.2f} mm outside the coarse surface after {max_iterations} "
            "steps; ask for more triangles or a larger tolerance"
        )
    return coarse_V, coarse_F.astype(np.int32)


def procedural_bunny_coarse_tets(
    resolution: float = 0.0053,
    triangles: int = 160,
    tolerance: float = 0.00075,
    edge_length_fac: float = 0.2,
    epsilon: float = 1e-3,
):
    """Coarse tet mesh (about 270 tets) that encloses procedural_bunny(resolution).

    The bunny's surface is coarsened to about `triangles` triangles and pushed out until every
    fine vertex is inside or within `tolerance` (m) of it, then filled with tets by pytetwild
    (mesh.tetrahedralize with coarsen=True), whose boundary strays from that surface by at
    most `epsilon` times the bounding-box diagonal (0.23 mm at the default). The fine surface
    is meant to be embedded in these tets (mesh.embed_points) as in the paper, where a
    4000-triangle bunny rides on 271 tets. Not deterministic (pytetwild).
    Returns (nodes float64 (n, 3), tets int32 (m, 4)), positively oriented.
    """
    V, F = procedural_bunny(resolution)
    coarse_V, coarse_F = enclosing_surface(V, F, triangles, tolerance)
    return tetrahedralize(
        coarse_V, coarse_F, edge_length_fac=edge_length_fac, coarsen=True, epsilon=epsilon
    )
