"""A surface riding on tets (the hand's and each soft body's): how far outside them it may lie,
and the check that refuses tets made for another surface or placement."""

from __future__ import annotations

import numpy as np

from . import mesh as meshing

#: The least slack a surface has outside its stored tets, as a fraction of their diagonal
#: (the paper's 271-tet bunny cage lies within 0.33% of its bunny).
EMBEDDING_SLACK = 0.01


def embedding_tolerance(nodes: np.ndarray, epsilon: float) -> float:
    """How far (m) a surface may lie outside its tets: twice the envelope pytetwild keeps at this
    epsilon, or 1% of the tets' diagonal (a coarse cage like the paper's bunny), the larger."""
    return max(2.0 * epsilon, EMBEDDING_SLACK) * float(np.linalg.norm(np.ptp(nodes, axis=0)))


def check_embedding(nodes, tets, surface, epsilon: float, who: str, field_name: str) -> tuple:
    """The surface embedded in the tets, refused when a vertex lies outside them by more than
    embedding_tolerance: the surface would ride on extrapolated weights, far from its flesh."""
    tet_index, weights, gap = meshing.embed_points(nodes, tets, surface, return_gap=True)
    tolerance = embedding_tolerance(nodes, epsilon)
    if gap.max() > tolerance:
        worst = int(np.argmax(gap))
        raise meshing.MeshError(
            f"{who}'s surface lies outside its tets ({field_name}): {int((gap > tolerance).sum())} vertices by more "
            f"than {tolerance * 1e3:.3g} mm, vertex {worst} by {gap[worst] * 1e3:.3g} mm; the tets were made for "
            "another surface or placement: tetrahedralize this surface again (or store tets made from it)")
    return tet_index, weights
