"""Tests of haptic_hand.engine.mesh: surfaces, checks, tetrahedralization, embedding.

pytetwild is slow and not deterministic, so each tet mesh is made once per module (coarse
settings) and only its geometric properties are asserted.
"""

import math
import pathlib

import numpy as np
import pytest

from haptic_hand.engine import mesh
from haptic_hand.engine.mesh import MeshError

DATA_DIR = pathlib.Path(__file__).resolve().parents[2].parent / "shared" / "data"
HAND_OBJ = DATA_DIR / "hand.obj"

# Corners of the unit cube indexed by bits (x, y, z); each quad runs counter-clockwise
# seen from outside.
CUBE_CORNERS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=float)
CUBE_QUADS = np.array(
    [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
)


def cube_surface(size=0.1, origin=(0.0, 0.0, 0.0)):
    V = CUBE_CORNERS * size + np.asarray(origin)
    F = np.concatenate([CUBE_QUADS[:, [0, 1, 2]], CUBE_QUADS[:, [0, 2, 3]]]).astype(np.int32)
    return V, F


def edge_count(F):
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    return len(np.unique(edges, axis=0))


@pytest.fixture(scope="module")
def hand_surface():
    return mesh.procedural_hand()


@pytest.fixture(scope="module")
def hand_tets(hand_surface):
    V, F = hand_surface
    return mesh.tetrahedralize(V, F, coarsen=True, edge_length_fac=0.2, epsilon=0.004)


@pytest.fixture(scope="module")
def cube_tets(tmp_path_factory):
    V, F = cube_surface()
    progress = []
    workdir = tmp_path_factory.mktemp("cwd")
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(workdir)
        nodes, tets = mesh.tetrahedralize(
            V, F, edge_length_fac=0.2, progress=lambda f, m: progress.append((f, m))
        )
    return nodes, tets, progress, list(workdir.iterdir())


# --- procedural hand -------------------------------------------------------------------------


def test_procedural_hand_is_a_closed_sphere_like_surface(hand_surface):
    V, F = hand_surface
    mesh.check_closed_surface(V, F)
    # Euler characteristic 2: one closed component of genus 0 (no tunnels between fingers).
    assert len(V) - edge_count(F) + len(F) == 2
    assert 1000 < len(F) < 20000


def test_procedural_hand_has_hand_proportions_with_fingers_towards_minus_z(hand_surface):
    V, _ = hand_surface
    extent = V.max(axis=0) - V.min(axis=0)
    assert 0.15 <= extent.max() <= 0.25
    assert np.argmax(extent) == 2
    seed = mesh.procedural_hand_palm_seed()
    # Fingers hang below the palm: far more hand lies below the palm centre than above.
    assert seed[2] - V[:, 2].min() > 2 * (V[:, 2].max() - seed[2])
    assert abs(seed[0]) < 0.01 and abs(seed[1]) < 0.01


def test_procedural_hand_fingers_are_separated_by_gaps(hand_surface):
    V, F = hand_surface
    # A line across the hand below the knuckles crosses the four fingers, with outside
    # samples between them.
    ys = np.arange(-0.06, 0.06, 0.0005)
    inside = np.array([mesh.point_inside_surface(V, F, (0.0, y, -0.12)) for y in ys])
    starts = np.flatnonzero(inside[1:] & ~inside[:-1])
    ends = np.flatnonzero(~inside[1:] & inside[:-1])
    assert len(starts) == 4 and len(ends) == 4
    gaps = ys[starts[1:] + 1] - ys[ends[:-1] + 1]
    assert gaps.min() >= 0.003


def test_procedural_hand_palm_seed_is_deep_inside(hand_surface):
    V, F = hand_surface
    seed = mesh.procedural_hand_palm_seed()
    assert seed.shape == (3,)
    assert mesh.point_inside_surface(V, F, seed)
    assert np.linalg.norm(V - seed, axis=1).min() >= 0.005


def test_procedural_hand_is_deterministic(hand_surface):
    V, F = hand_surface
    V2, F2 = mesh.procedural_hand()
    assert np.array_equal(V, V2) and np.array_equal(F, F2)


def test_procedural_hand_rejects_a_grid_coarser_than_the_finger_gaps():
    with pytest.raises(MeshError, match="resolution"):
        mesh.procedural_hand(resolution=0.01)


def test_procedural_hand_volume_matches_its_tet_mesh(hand_surface, hand_tets):
    V, F = hand_surface
    nodes, tets = hand_tets
    surface = mesh.surface_volume(V, F)
    assert surface > 0.0
    assert mesh.tet_signed_volumes(nodes, tets).sum() == pytest.approx(surface, rel=0.05)


# --- surface checks ----------------------------------------------------------------------------


def test_surface_volume_of_a_cube_is_its_size_cubed_wherever_it_is():
    for origin in [(0.0, 0.0, 0.0), (5.0, -3.0, 2.0)]:
        V, F = cube_surface(0.1, origin)
        assert mesh.surface_volume(V, F) == pytest.approx(1e-3, rel=1e-9)
    assert mesh.surface_volume(V, F[:, ::-1]) == pytest.approx(-1e-3, rel=1e-9)


def test_check_closed_surface_rejects_an_open_hand(hand_surface):
    V, F = hand_surface
    with pytest.raises(MeshError, match="open") as error:
        mesh.check_closed_surface(V, F[1:])
    assert "3 boundary edges" in str(error.value)  # the hole left by one triangle


def test_check_closed_surface_rejects_a_flipped_hand(hand_surface):
    V, F = hand_surface
    with pytest.raises(MeshError, match="flip"):
        mesh.check_closed_surface(V, F[:, ::-1])


def test_check_closed_surface_rejects_nan(hand_surface):
    V, F = hand_surface
    V = V.copy()
    V[F[7, 1]] = np.nan
    with pytest.raises(MeshError, match="NaN"):
        mesh.check_closed_surface(V, F)


def test_check_closed_surface_rejects_a_non_manifold_edge():
    # Two closed tet surfaces glued along one edge (vertices 0 and 1): four triangles meet
    # there, yet no edge is open.
    V = np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, -1, 0], [0, 0, -1]], dtype=float
    )
    tet_surface = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    second = np.array([0, 1, 4, 5])[tet_surface]  # (0, 1, 4, 5) is positively oriented too
    F = np.concatenate([tet_surface, second])
    assert mesh.surface_volume(V, second) > 0
    with pytest.raises(MeshError, match="non-manifold"):
        mesh.check_closed_surface(V, F)


def test_check_closed_surface_rejects_one_flipped_triangle():
    V, F = cube_surface()
    F = F.copy()
    F[3] = F[3, ::-1]
    with pytest.raises(MeshError, match="inconsistent"):
        mesh.check_closed_surface(V, F)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda V, F: (V[:0], F[:0]), "empty"),
        (lambda V, F: (V, np.where(F == 7, 8, F)), "outside"),
        (lambda V, F: (np.where(np.arange(8)[:, None] == 7, V[6], V), F), "zero-area"),
    ],
)
def test_check_closed_surface_rejects_broken_input(change, message):
    V, F = change(*cube_surface())
    with pytest.raises(MeshError, match=message):
        mesh.check_closed_surface(V, F)


def test_messages_say_how_to_fix(hand_surface):
    V, F = hand_surface
    with pytest.raises(MeshError) as error:
        mesh.check_closed_surface(V, F[1:])
    assert "close the holes" in str(error.value)


# --- OBJ files ---------------------------------------------------------------------------------


def test_load_obj_splits_polygons_and_ignores_texture_and_normal_indices(tmp_path):
    path = tmp_path / "cube.obj"
    lines = ["o cube"] + [f"v {x * 0.1} {y * 0.1} {z * 0.1}" for x, y, z in CUBE_CORNERS]
    lines += ["vt 0 0", "vn 0 0 1"]
    forms = ["{}", "{}/1", "{}/1/1", "{}//1"]
    for quad in CUBE_QUADS:
        # Negative indices count back from the last vertex (8 so far).
        corners = [quad[0] + 1, quad[1] - 8, quad[2] + 1, quad[3] + 1]
        lines.append("f " + " ".join(form.format(c) for form, c in zip(forms, corners)))
    path.write_text("\n".join(lines) + "\n")

    V, F = mesh.load_obj(path)
    assert V.shape == (8, 3) and F.shape == (12, 3)
    assert F.dtype == np.int32
    mesh.check_closed_surface(V, F)
    assert mesh.surface_volume(V, F) == pytest.approx(1e-3, rel=1e-12)


def test_save_then_load_obj_gives_the_same_mesh(tmp_path, hand_surface):
    V, F = hand_surface
    mesh.save_obj(tmp_path / "hand.obj", V, F)
    V2, F2 = mesh.load_obj(tmp_path / "hand.obj")
    assert np.array_equal(V, V2) and np.array_equal(F, F2)


def test_load_obj_reports_the_bad_line(tmp_path):
    path = tmp_path / "bad.obj"
    path.write_text("v 0 0 0\nv 1 0 zero\n")
    with pytest.raises(MeshError, match=":2:"):
        mesh.load_obj(path)


# --- tetrahedra --------------------------------------------------------------------------------


def test_tetrahedralize_fills_a_cube(cube_tets):
    nodes, tets, _, _ = cube_tets
    assert tets.dtype == np.int32 and nodes.dtype == np.float64
    volumes = mesh.tet_signed_volumes(nodes, tets)
    assert (volumes > 0).all()
    assert volumes.sum() == pytest.approx(1e-3, rel=0.02)
    # Every node belongs to a tet.
    assert np.array_equal(np.unique(tets), np.arange(len(nodes)))
    mesh.check_closed_surface(nodes, mesh.tet_boundary_faces(tets))


def test_tetrahedralize_reports_progress_from_start_to_end(cube_tets):
    _, _, progress, _ = cube_tets
    fractions = [f for f, _ in progress]
    assert fractions[0] == 0.0 and fractions[-1] == 1.0
    assert fractions == sorted(fractions)
    assert all(isinstance(message, str) and message for _, message in progress)


def test_tetrahedralize_leaves_no_files_in_the_working_directory(cube_tets):
    *_, left_behind = cube_tets
    assert left_behind == []


def test_tetrahedralize_gives_a_positive_hand_with_a_closed_boundary(hand_tets):
    nodes, tets = hand_tets
    mesh.check_tets(nodes, tets)
    assert (mesh.tet_signed_volumes(nodes, tets) > 0).all()
    boundary = mesh.tet_boundary_faces(tets)
    mesh.check_closed_surface(nodes, boundary)
    assert mesh.surface_volume(nodes, boundary) == pytest.approx(
        mesh.tet_signed_volumes(nodes, tets).sum(), rel=1e-9
    )


def test_tetrahedralize_checks_the_surface_first(hand_surface):
    V, F = hand_surface
    with pytest.raises(MeshError, match="open"):
        mesh.tetrahedralize(V, F[1:])


def test_tet_signed_volume_of_the_corner_tet_is_one_sixth():
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    assert mesh.tet_signed_volumes(nodes, [[0, 1, 2, 3]]) == pytest.approx([1 / 6])
    assert mesh.tet_signed_volumes(nodes, [[0, 2, 1, 3]]) == pytest.approx([-1 / 6])


def test_boundary_of_one_tet_is_its_four_faces_wound_outward():
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    faces = mesh.tet_boundary_faces(np.array([[0, 1, 2, 3]]))
    assert len(faces) == 4
    mesh.check_closed_surface(nodes, faces)
    assert mesh.surface_volume(nodes, faces) == pytest.approx(1 / 6)


def test_boundary_of_two_tets_omits_their_shared_face():
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
    tets = np.array([[0, 1, 2, 3], [0, 2, 1, 4]])
    faces = mesh.tet_boundary_faces(tets)
    assert len(faces) == 6
    assert not any(set(face) == {0, 1, 2} for face in faces.tolist())
    mesh.check_closed_surface(nodes, faces)


def test_check_tets_names_the_inverted_tet():
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
    mesh.check_tets(nodes, [[0, 1, 2, 3], [0, 2, 1, 4]])
    with pytest.raises(MeshError, match=r"tet 1 \(inverted"):
        mesh.check_tets(nodes, [[0, 1, 2, 3], [0, 1, 2, 4]])


@pytest.mark.parametrize(
    "nodes, tets, message",
    [
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 1, 2, 2]], "zero-volume"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 1, 2, 4]], "outside"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, np.nan]], [[0, 1, 2, 3]], "NaN"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.zeros((0, 4), int), "at least one"),
    ],
)
def test_check_tets_rejects_broken_meshes(nodes, tets, message):
    with pytest.raises(MeshError, match=message):
        mesh.check_tets(np.array(nodes, dtype=float), np.array(tets))


# --- embedding ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def hand_embedding(hand_surface, hand_tets):
    """Surface vertices (some lie outside the tets) and random points inside known tets."""
    V, _ = hand_surface
    nodes, tets = hand_tets
    rng = np.random.default_rng(7)
    source_tets = rng.integers(len(tets), size=500)
    inner_weights = rng.dirichlet(np.ones(4), size=500)
    inner = np.einsum("pj,pjk->pk", inner_weights, nodes[tets[source_tets]])
    points = np.concatenate([V, inner])
    tet_index, weights = mesh.embed_points(nodes, tets, points)
    return points, len(V), tet_index, weights


def test_embedding_weights_sum_to_one_and_reproduce_the_points(hand_tets, hand_embedding):
    nodes, tets = hand_tets
    points, _, tet_index, weights = hand_embedding
    assert tet_index.dtype == np.int32 and weights.shape == (len(points), 4)
    assert np.abs(weights.sum(axis=1) - 1.0).max() < 1e-12
    reproduced = mesh.interpolate_embedded(nodes, tets, tet_index, weights)
    assert np.abs(reproduced - points).max() < 1e-12


def test_embedding_follows_an_affine_map_exactly(hand_tets, hand_embedding):
    nodes, tets = hand_tets
    points, _, tet_index, weights = hand_embedding
    angle = 0.7
    rotation = np.array(
        [[math.cos(angle), -math.sin(angle), 0], [math.sin(angle), math.cos(angle), 0], [0, 0, 1]]
    )
    A = rotation @ np.array([[1.3, 0.2, 0.0], [0.0, 0.8, 0.1], [0.0, 0.0, 1.1]])
    b = np.array([0.05, -0.02, 0.3])
    moved = mesh.interpolate_embedded(nodes @ A.T + b, tets, tet_index, weights)
    assert np.abs(moved - (points @ A.T + b)).max() < 1e-12


def test_points_inside_tets_get_a_tet_that_contains_them(hand_embedding):
    _, surface_count, _, weights = hand_embedding
    assert weights[surface_count:].min() >= -1e-9


def test_surface_points_outside_the_tets_get_a_tet_holding_their_nearest_point(
    hand_tets, hand_embedding
):
    import pyvista

    nodes, tets = hand_tets
    points, surface_count, tet_index, weights = hand_embedding
    outside = np.flatnonzero(weights[:surface_count].min(axis=1) < -1e-9)
    assert len(outside) > 0  # pytetwild's envelope leaves some surface vertices outside
    # The point of the tet mesh nearest to p lies on its boundary; VTK finds it
    # independently. The nearest tet is one that contains that point.
    boundary = pyvista.PolyData.from_regular_faces(nodes, mesh.tet_boundary_faces(tets))
    _, nearest = boundary.find_closest_cell(points[outside], return_closest_point=True)
    corners = nodes[tets[tet_index[outside]]]
    local = np.linalg.solve(
        np.transpose(corners[:, 1:] - corners[:, :1], (0, 2, 1)),
        (nearest - corners[:, 0])[..., None],
    )[..., 0]
    nearest_weights = np.concatenate([1 - local.sum(axis=1, keepdims=True), local], axis=1)
    assert nearest_weights.min() >= -1e-9


def test_point_outside_every_tet_gets_the_nearest_tet_and_extrapolates():
    # Two tets stacked along z; a point just below the bottom tet and one off the side of
    # the top tet.
    nodes = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
    tets = np.array([[0, 1, 2, 3], [0, 2, 1, 4]])
    points = np.array([[0.1, 0.1, -1.2], [0.6, 0.6, 0.3], [0.1, 0.1, 0.1], [0.1, 0.1, -0.1]])
    tet_index, weights = mesh.embed_points(nodes, tets, points)
    assert tet_index.tolist() == [1, 0, 0, 1]
    assert weights[0].min() < 0 and weights[1].min() < 0  # extrapolated
    assert weights[2].min() >= 0 and weights[3].min() >= 0
    reproduced = mesh.interpolate_embedded(nodes, tets, tet_index, weights)
    assert np.abs(reproduced - points).max() < 1e-15


# --- inside test -------------------------------------------------------------------------------


def test_point_inside_a_cube():
    V, F = cube_surface(0.1)
    for p in [(0.05, 0.05, 0.05), (0.001, 0.099, 0.002), (0.09, 0.01, 0.05)]:
        assert mesh.point_inside_surface(V, F, p)
    for p in [(0.05, 0.05, 0.101), (-0.001, 0.05, 0.05), (0.2, 0.2, 0.2), (5.0, -3.0, 1.0)]:
        assert not mesh.point_inside_surface(V, F, p)


# --- the shared hand.obj -----------------------------------------------------------------------


@pytest.mark.skipif(not HAND_OBJ.exists(), reason=f"{HAND_OBJ} is absent")
def test_shared_hand_obj_is_closed_and_tetrahedralizes_positively():
    V, F = mesh.load_obj(HAND_OBJ)
    mesh.check_closed_surface(V, F)
    nodes, tets = mesh.tetrahedralize(V, F, coarsen=True, epsilon=0.004, edge_length_fac=0.2)
    mesh.check_tets(nodes, tets)
    volumes = mesh.tet_signed_volumes(nodes, tets)
    assert (volumes > 0).all()
    assert volumes.sum() == pytest.approx(mesh.surface_volume(V, F), rel=0.05)


# --- surfaces that bound no proper solid -------------------------------------------------------


def tet_surface(corners):
    """The outward surface of one positively oriented tet on the given 4 vertex indices."""
    c = np.asarray(corners)
    return c[np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])]


def test_two_overlapping_shells_are_named_with_their_faces(hand_surface):
    V, F = hand_surface
    W, G = np.concatenate([V, V + [0.01, 0.0, 0.0]]), np.concatenate([F, F + len(V)])
    with pytest.raises(MeshError, match=r"intersects itself: \d+ pairs .*triangles \d+ and \d+.*Mesh > Clean Up"):
        mesh.check_closed_surface(W, G)
    pairs, count = mesh.self_intersections(W, G)
    assert count > 100 and np.all(pairs[:, 0] < len(F)) and np.all(pairs[:, 1] >= len(F))  # one from each shell


def test_a_shell_inside_another_does_not_cross_it(hand_surface):
    """Nested shells cross nowhere: the test must not invent crossings (the volume check and the
    inside tests see a nested shell; here only the crossing test is asked)."""
    V, F = hand_surface
    centre = V.mean(axis=0)
    inner = centre + 0.05 * (V - centre)
    assert mesh.self_intersections(np.concatenate([V, inner]), np.concatenate([F, F + len(V)]))[1] == 0


def test_clean_surfaces_have_no_self_intersections(hand_surface):
    from haptic_hand.engine import shapes

    for V, F in [hand_surface, cube_surface(), shapes.procedural_bunny()] + [shapes.procedural_letter(c) for c in "HAPTIC"]:
        assert mesh.self_intersections(V, F)[1] == 0


def crossing_reference(t, u) -> bool:
    """Generic triangles (no shared vertex, no degeneracy): some edge of one passes through the
    other, by plain floating-point line-plane intersection and barycentric coordinates."""
    for a, b in ((t, u), (u, t)):
        n = np.cross(b[1] - b[0], b[2] - b[0])
        for k in range(3):
            p, q = a[k], a[(k + 1) % 3]
            dp, dq = (p - b[0]) @ n, (q - b[0]) @ n
            if dp * dq >= 0:
                continue
            x = p + (q - p) * (dp / (dp - dq))
            m = np.array([b[1] - b[0], b[2] - b[0]]).T
            s, r = np.linalg.lstsq(m, x - b[0], rcond=None)[0]
            if s >= 0 and r >= 0 and s + r <= 1:
                return True
    return False


def test_self_intersections_of_a_triangle_soup_match_a_brute_force_reference():
    rng = np.random.default_rng(3)
    centres = rng.uniform(0, 0.1, (80, 3))
    V = (centres[:, None] + rng.normal(0, 0.012, (80, 3, 3))).reshape(-1, 3)
    F = np.arange(len(V)).reshape(-1, 3)
    expected = {(i, j) for i in range(len(F)) for j in range(i + 1, len(F)) if crossing_reference(V[F[i]], V[F[j]])}
    pairs, count = mesh.self_intersections(V, F, capacity=10000)
    assert len(expected) > 20 and count == len(pairs) == len(expected)
    assert {tuple(p) for p in pairs.tolist()} == expected


def test_a_fold_across_an_edge_and_a_crossing_beside_a_shared_vertex_are_found():
    # fold: two triangles on edge (0, 1), both on the same side of it in one plane
    V = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, 0.5, 0]], float)
    assert mesh.self_intersections(V, np.array([[0, 1, 2], [1, 0, 3]]))[1] == 1
    V[3] = [0.5, -0.5, 0]  # the other side: a flat pair of neighbours, no fold
    assert mesh.self_intersections(V, np.array([[0, 1, 2], [1, 0, 3]]))[1] == 0
    # one shared vertex (0): the second triangle's far edge passes through the first
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, -1], [0.3, 0.3, 1]], float)
    assert mesh.self_intersections(V, np.array([[0, 1, 2], [0, 3, 4]]))[1] == 1


def test_two_solids_sharing_one_vertex_are_non_manifold():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], float)
    second = [0, 4, 6, 5]
    assert mesh.tet_signed_volumes(V, [second])[0] > 0
    F = np.concatenate([tet_surface([0, 1, 2, 3]), tet_surface(second)])
    with pytest.raises(MeshError, match=r"non-manifold at 1 vertices .*vertex 0, in 2 separate fans"):
        mesh.check_closed_surface(V, F)


def test_two_cubes_touching_along_an_edge_are_refused():
    V, F = cube_surface(0.1)
    W, G = cube_surface(0.1, (0.1, 0.1, 0.0))
    with pytest.raises(MeshError, match=r"same position as another.*Merge by Distance"):
        mesh.check_closed_surface(np.concatenate([V, W]), np.concatenate([F, G + len(V)]))


def test_a_flat_closed_surface_is_told_it_is_flat_not_to_flip():
    # a square sheet, both sides, with different diagonals: closed, manifold, consistently wound
    V = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0], [0, 0.1, 0]], float)
    F = np.array([[0, 1, 2], [0, 2, 3], [1, 0, 3], [1, 3, 2]])
    with pytest.raises(MeshError, match=r"encloses no volume .*flat \(0 mm thick.*Solidify") as error:
        mesh.check_closed_surface(V, F)
    assert "flip" not in str(error.value)


def test_a_spike_is_named(hand_surface):
    V, F = hand_surface
    V = V.copy()
    V[100] = 0.0  # what Blender's OBJ importer makes of a vertex with a nan coordinate
    with pytest.raises(MeshError, match=r"1 spike vertices .*vertex 100 at \[0.0, 0.0, 0.0\]"):
        mesh.check_closed_surface(V, F)


def test_float_and_wide_indices_are_refused_not_rounded_or_wrapped():
    V, F = cube_surface()
    with pytest.raises(MeshError, match="refused rather than rounded"):
        mesh.check_closed_surface(V, F + 0.0)
    with pytest.raises(MeshError, match="outside 0..7"):
        mesh.check_closed_surface(V, F.astype(np.int64) + (2**32) * (F == 0))
    nodes, tets = mesh.structured_box([0.1] * 3, [1] * 3)
    with pytest.raises(MeshError, match="refused rather than rounded"):
        mesh.embed_points(nodes, tets.astype(float), nodes)


@pytest.mark.parametrize("content, words", [(b"PK\x03\x04junk", "not a readable"), (None, "does not exist"),
                                            ("npy", "single array"), ("nokey", "no 'tets' array")])
def test_load_tets_names_its_field(tmp_path, content, words):
    path = tmp_path / "t.npz"
    if content == "npy":
        with open(path, "wb") as f:
            np.save(f, np.zeros(3))
    elif content == "nokey":
        np.savez(path, nodes=np.zeros((4, 3)))
    elif content is not None:
        path.write_bytes(content)
    with pytest.raises(MeshError, match=f"hand.tets file .*{words}"):
        mesh.load_tets(path, "hand.tets")


def test_embedding_gap_is_the_distance_outside_the_tets():
    nodes, tets = mesh.structured_box([0.1] * 3, [2] * 3)
    points = np.array([[0.05, 0.05, 0.05], [0.05, 0.05, 0.13], [-0.03, -0.04, 0.05]])
    _, _, gap = mesh.embed_points(nodes, tets, points, return_gap=True)
    assert gap == pytest.approx([0.0, 0.03, 0.05], abs=1e-12)


def test_a_sizing_field_makes_the_tets_finer_where_it_asks():
    """fTetWild's sizing field through mesh.tetrahedralize: edges of 4 mm asked on the cube's
    x < 5 cm half, 40 mm (above edge_length_fac's 8.7 mm, which then rules) on the other, give
    that half more nodes (at an edge ratio of 2.2, ~10 times as many tets in the same volume)."""
    V, F = cube_surface()
    background, background_tets = mesh.structured_box(np.full(3, 0.12), np.array([6, 6, 6]), np.full(3, -0.01))
    edge = np.where(background[:, 0] < 0.05, 0.004, 0.04)
    nodes, tets = mesh.tetrahedralize(V, F, edge_length_fac=0.05, coarsen=False, epsilon=1e-3,
                                      sizing=(background, background_tets, edge))
    assert (mesh.tet_signed_volumes(nodes, tets) > 0).all()
    inside = (nodes[:, 0] > 1e-6) & (nodes[:, 0] < 0.1 - 1e-6)  # off the two x faces, which both halves lack
    fine, coarse = (inside & (nodes[:, 0] < 0.045)).sum(), (inside & (nodes[:, 0] > 0.055)).sum()
    assert fine > 2 * coarse, (fine, coarse)
