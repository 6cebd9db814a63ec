"""Tests of haptic_hand.engine.shapes: the procedural bunny and block letters that stand in
for third-party meshes in sample scenes, and their coarse tet meshes.

The bunny's tets come from pytetwild (slow, not deterministic): they are made once per module
and only their geometric properties are asserted.
"""

import numpy as np
import pytest

from haptic_hand.engine import mesh, shapes
from haptic_hand.engine.mesh import MeshError

LETTER_HEIGHT = 0.04
LETTER_DEPTH = 0.012


def euler_characteristic(V, F):
    """V - E + F: 2 for a closed genus-0 surface, 0 for genus 1."""
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    return len(V) - len(np.unique(edges, axis=0)) + len(F)


def distance_outside_tets(nodes, tets, points):
    """Distance from each point to the tet mesh (0 inside)."""
    _, weights = mesh.embed_points(nodes, tets, points)
    outside = np.flatnonzero(weights.min(axis=1) < -1e-9)
    distance = np.zeros(len(points))
    if len(outside):
        faces = nodes[mesh.tet_boundary_faces(tets)]
        p = np.repeat(points[outside], len(faces), axis=0)
        a, b, c = (np.tile(faces[:, i], (len(outside), 1)) for i in range(3))
        gap = np.linalg.norm(p - mesh.closest_point_on_triangles(p, a, b, c), axis=1)
        distance[outside] = gap.reshape(len(outside), len(faces)).min(axis=1)
    return distance


@pytest.fixture(scope="module")
def bunny():
    return shapes.procedural_bunny()


@pytest.fixture(scope="module")
def bunny_tets():
    return shapes.procedural_bunny_coarse_tets()


@pytest.fixture(scope="module")
def letters():
    return {ch: shapes.procedural_letter(ch) for ch in shapes.SUPPORTED_LETTERS}


@pytest.fixture(scope="module")
def letters_tets():
    return {ch: shapes.letter_tets(ch) for ch in shapes.SUPPORTED_LETTERS}


# --------------------------------------------------------------------------------------------
# Bunny
# --------------------------------------------------------------------------------------------


def test_bunny_is_a_closed_sphere_like_surface_of_about_4000_triangles(bunny):
    V, F = bunny
    mesh.check_closed_surface(V, F)
    assert euler_characteristic(V, F) == 2
    assert 3000 <= len(F) <= 5000
    assert V.dtype == np.float64 and F.dtype == np.int32


def test_bunny_is_15_cm_long_and_rests_centred_on_the_ground(bunny):
    V, _ = bunny
    lower, upper = V.min(axis=0), V.max(axis=0)
    assert 0.12 <= upper[0] - lower[0] <= 0.18
    assert lower[2] == pytest.approx(0.0, abs=1e-9)
    assert (lower + upper)[:2] == pytest.approx([0.0, 0.0], abs=1e-9)
    # A toy, not a sliver: as tall as 3/4 of its length and about half as wide.
    assert upper[2] > 0.75 * (upper[0] - lower[0])
    assert 0.3 < (upper[1] - lower[1]) / (upper[0] - lower[0]) < 0.8


def test_bunny_sits_on_a_flat_bottom(bunny):
    # The bottom is cut flat: its vertices on the ground span a base over 4 cm across.
    V, _ = bunny
    ground = V[V[:, 2] < 1e-9]
    assert np.ptp(ground[:, 0]) > 0.04 and np.ptp(ground[:, 1]) > 0.04


def test_bunny_ears_stick_up_apart(bunny):
    # The top centimetre is the two ear tips, one either side of the x-z plane.
    V, _ = bunny
    top = V[V[:, 2] > V[:, 2].max() - 0.01]
    assert np.abs(top[:, 1]).min() > 0.005
    assert (top[:, 1] > 0).any() and (top[:, 1] < 0).any()


def test_bunny_is_deterministic(bunny):
    V, F = shapes.procedural_bunny()
    assert np.array_equal(V, bunny[0]) and np.array_equal(F, bunny[1])


def test_bunny_rejects_a_grid_too_coarse_for_the_ears():
    with pytest.raises(MeshError, match="resolution"):
        shapes.procedural_bunny(resolution=0.02)


def test_bunny_coarse_tets_are_few_and_positive(bunny_tets):
    nodes, tets = bunny_tets
    assert 150 <= len(tets) <= 500
    mesh.check_tets(nodes, tets)
    assert (mesh.tet_signed_volumes(nodes, tets) > 0).all()
    mesh.check_closed_surface(nodes, mesh.tet_boundary_faces(tets))
    # They rest on the ground with the fine surface (pytetwild may move nodes by its envelope,
    # 1e-3 of the 0.23 m diagonal).
    assert abs(nodes[:, 2].min()) < 0.0005


def test_bunny_coarse_tets_hold_the_fine_surface(bunny, bunny_tets):
    V, _ = bunny
    assert distance_outside_tets(*bunny_tets, V).max() < 0.0015


def test_bunny_coarse_tets_have_the_fine_surface_volume_within_15_percent(bunny, bunny_tets):
    # They enclose the surface, so they hold at least its volume (less the 0.23 mm envelope).
    ratio = mesh.tet_signed_volumes(*bunny_tets).sum() / mesh.surface_volume(*bunny)
    assert 0.98 <= ratio <= 1.15


def test_enclosing_surface_is_coarse_closed_deterministic_and_on_the_ground(bunny):
    V, F = bunny
    coarse = shapes.enclosing_surface(V, F, 120, tolerance=0.001)
    assert 100 <= len(coarse[1]) <= 140
    mesh.check_closed_surface(*coarse)
    assert euler_characteristic(*coarse) == 2
    assert coarse[0][:, 2].min() == 0.0
    # Every fine vertex is inside or within the tolerance of the coarse surface.
    outside = ~np.array([mesh.point_inside_surface(*coarse, p) for p in V[::7]])
    gaps, _ = shapes._nearest_triangles(*coarse, V[::7][outside])
    assert (gaps <= 0.001).all()
    again = shapes.enclosing_surface(V, F, 120, tolerance=0.001)
    assert np.array_equal(again[0], coarse[0]) and np.array_equal(again[1], coarse[1])


def test_enclosing_surface_rejects_more_triangles_than_the_surface_has(bunny):
    with pytest.raises(ValueError, match="fewer than the surface has"):
        shapes.enclosing_surface(*bunny, len(bunny[1]))


# --------------------------------------------------------------------------------------------
# Letters
# --------------------------------------------------------------------------------------------


def test_the_paper_letters_are_supported():
    assert set("HAPTIC") <= set(shapes.SUPPORTED_LETTERS)


@pytest.mark.parametrize("ch", shapes.SUPPORTED_LETTERS)
def test_letter_is_a_closed_surface_with_holes_only_in_A_and_P(letters, ch):
    V, F = letters[ch]
    mesh.check_closed_surface(V, F)
    assert euler_characteristic(V, F) == (0 if ch in "AP" else 2)
    assert (ch in shapes.LETTERS_WITH_HOLES) == (ch in "AP")
    assert 150 <= len(F) <= 600


@pytest.mark.parametrize("ch", shapes.SUPPORTED_LETTERS)
def test_letter_stands_upright_centred_on_the_ground(letters, ch):
    V, _ = letters[ch]
    lower, upper = V.min(axis=0), V.max(axis=0)
    assert lower[2] == pytest.approx(0.0, abs=1e-9)
    assert upper[2] == pytest.approx(LETTER_HEIGHT, abs=1e-9)  # flat top at full height
    assert upper[1] - lower[1] == pytest.approx(LETTER_DEPTH, abs=1e-9)
    assert (lower + upper)[:2] == pytest.approx([0.0, 0.0], abs=1e-9)
    assert 0.3 * LETTER_HEIGHT < upper[0] - lower[0] < LETTER_HEIGHT


# Points (x from the letter's left edge, z up, in letter heights; y = 0) inside and outside
# each letter, with the strokes 0.18 wide: e.g. the H's crossbar spans z 0.41-0.59 and its
# stems x 0-0.18 and 0.52-0.7; the A's counter spans z 0.44-0.87 on its axis.
LETTER_PROBES = {
    "H": {"inside": [(0.09, 0.9), (0.35, 0.5), (0.61, 0.1)], "outside": [(0.35, 0.2), (0.35, 0.7)]},
    "A": {"inside": [(0.44, 0.35), (0.44, 0.95)], "outside": [(0.44, 0.6), (0.44, 0.1)]},
    "P": {"inside": [(0.09, 0.2), (0.3, 0.91), (0.6, 0.71)], "outside": [(0.3, 0.71), (0.4, 0.2)]},
    "T": {"inside": [(0.05, 0.91), (0.35, 0.4)], "outside": [(0.1, 0.4), (0.6, 0.4)]},
    "I": {"inside": [(0.2, 0.5), (0.05, 0.09)], "outside": [(0.05, 0.5), (0.35, 0.5)]},
    "C": {"inside": [(0.09, 0.5), (0.5, 0.09), (0.5, 0.91)], "outside": [(0.5, 0.5), (0.65, 0.5)]},
}


@pytest.mark.parametrize("ch", shapes.SUPPORTED_LETTERS)
def test_letter_has_its_strokes_and_gaps(letters, ch):
    V, F = letters[ch]
    left = V[:, 0].min()
    for where, expected in (("inside", True), ("outside", False)):
        for x, z in LETTER_PROBES[ch][where]:
            point = (left + x * LETTER_HEIGHT, 0.0, z * LETTER_HEIGHT)
            assert mesh.point_inside_surface(V, F, point) == expected, (ch, where, x, z)


def test_letter_is_deterministic_and_accepts_lower_case(letters):
    V, F = shapes.procedural_letter("a")
    assert np.array_equal(V, letters["A"][0]) and np.array_equal(F, letters["A"][1])


def test_letter_scales_with_height_and_depth():
    V, F = shapes.procedural_letter("H", height=0.08, depth=0.02)
    mesh.check_closed_surface(V, F)
    assert np.ptp(V, axis=0)[1:] == pytest.approx([0.02, 0.08], abs=1e-9)


@pytest.mark.parametrize("make", [shapes.procedural_letter, shapes.letter_tets])
@pytest.mark.parametrize("ch", ["Z", "?", "HA", ""])
def test_unknown_letter_raises_naming_the_supported_ones(make, ch):
    with pytest.raises(ValueError, match="supported letters are H, A, P, T, I, C"):
        make(ch)


@pytest.mark.parametrize("ch", shapes.SUPPORTED_LETTERS)
def test_letter_tets_are_few_positive_and_hold_the_surface(letters, letters_tets, ch):
    V, F = letters[ch]
    nodes, tets = letters_tets[ch]
    assert 40 <= len(tets) <= 150
    mesh.check_tets(nodes, tets)
    boundary = mesh.tet_boundary_faces(tets)
    mesh.check_closed_surface(nodes, boundary)
    # The tets have the letter's holes too.
    assert euler_characteristic(nodes, boundary) == euler_characteristic(V, F)
    assert nodes[:, 2].min() == pytest.approx(0.0, abs=1e-12)
    assert distance_outside_tets(nodes, tets, V).max() < 0.0005
    # Marching cubes on the coarse grid bevels the edges, so the tets hold more volume.
    ratio = mesh.tet_signed_volumes(nodes, tets).sum() / mesh.surface_volume(V, F)
    assert 1.0 <= ratio <= 1.35


def test_letter_tets_of_H_and_T_fill_exactly_their_block_outlines(letters_tets):
    # H: two stems 0.18 x 1 and a crossbar 0.34 x 0.18 between them; T: a bar 0.7 x 0.18
    # and a stem 0.18 x 0.82 (letter heights).
    for ch, area in (("H", 2 * 0.18 + 0.34 * 0.18), ("T", 0.7 * 0.18 + 0.18 * 0.82)):
        volume = mesh.tet_signed_volumes(*letters_tets[ch]).sum()
        assert volume == pytest.approx(area * LETTER_HEIGHT**2 * LETTER_DEPTH, rel=1e-9)


def test_letter_tets_are_deterministic(letters_tets):
    nodes, tets = shapes.letter_tets("P")
    assert np.array_equal(nodes, letters_tets["P"][0])
    assert np.array_equal(tets, letters_tets["P"][1])


def test_finer_letter_tets_have_more_tets():
    coarse = shapes.letter_tets("C")[1]
    fine = shapes.letter_tets("C", max_edge=LETTER_HEIGHT / 8)[1]
    assert len(fine) > 1.5 * len(coarse)
