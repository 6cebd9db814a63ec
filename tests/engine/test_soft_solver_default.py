"""A soft body's default solver, `auto`: the per-step factor below 1000 tets, the reused factor
from there on (the rule bench/bench_soft_solver.py supports). A body left at the default steps
exactly as one given that solver explicitly."""

import numpy as np
import pytest

from haptic_hand.engine import mesh, params
from haptic_hand.engine import native_world as W


def drop(cells: int, solver: str | None, then: str | None = None) -> np.ndarray:
    """A soft block of cells^3 * 5 tets dropped 2 mm onto the ground for 10 steps (with `then`:
    switched to that solver after five)."""
    world = W.World(dt=1 / 60, contact_thickness=1e-3)
    world.add_plane([0, 0, 0], [0, 0, 1])
    nodes, tets = mesh.structured_box([0.06] * 3, [cells] * 3, [-0.03, -0.03, 0.003])
    sn, sw = W.vertex_surface(len(nodes))
    body = world.add_soft_body(nodes, tets, sn, sw, mesh.tet_boundary_faces(tets))
    if solver is not None:
        world.set_body_solver(body, solver)
    for k in range(10):
        if k == 5 and then is not None:
            world.set_body_solver(body, then)
        world.step()
    return world.nodes(body)[0]


def test_the_default_is_auto():
    assert params.by_json("bodies[].solver.name").default == "auto"


@pytest.mark.parametrize("cells, same_as, other", [(3, "cholesky", "reused_cholesky"),
                                                    (6, "reused_cholesky", "cholesky")])
def test_auto_picks_the_solver_by_tet_count(cells, same_as, other):
    assert (5 * cells**3 >= 1000) == (same_as == "reused_cholesky")
    default = drop(cells, None)
    assert np.array_equal(default, drop(cells, "auto"))
    assert np.array_equal(default, drop(cells, same_as))      # bit for bit: the same solver
    assert not np.array_equal(default, drop(cells, other))    # the other one differs at CG's tolerance
    assert np.abs(default - drop(cells, other)).max() < 1e-5  # but agrees physically


@pytest.mark.parametrize("first, then", [("cholesky", "reused_cholesky"), ("reused_cholesky", "cholesky")])
def test_a_solver_switched_between_steps_analyses_in_its_own_forms(first, then):
    # The run goes on across the switch and agrees with the per-step factor's run within the
    # reused factor's CG tolerance. (The factor is analysed when the body is added, before its
    # first step; a switch drops that analysis, and the new solver makes its own.)
    switched = drop(4, first, then)
    assert np.isfinite(switched).all()
    assert np.abs(switched - drop(4, "cholesky")).max() < 1e-5
