"""Speculative contacts whose points separate at the start of a step wait outside its contact
solve (`contact.defer_separating`, sim/world_speculative.cpp), and the step solves again with
them when one would close. Checked here against what does not depend on the engine's contacts:
free flight where nothing may touch, and a depth measured against the ground where something
must; and against the same step with every contact in the solve."""

import numpy as np
import pytest

from haptic_hand.engine import native_world as W
from test_fast_motion import DT, THICKNESS, Plane, Rigid, ThinBox, icosphere

RADIUS = 0.01  # the sphere of test_fast_motion's Rigid


def skimming_sphere(defer: bool, target, gravity: float):
    """A rigid sphere 2.5 mm above a target (its bottom past the base reach of 1.5 mm), sliding
    along it at 5 m/s: every contact the search finds starts square to the motion."""
    world = W.World(dt=DT, gravity=[0, 0, -gravity], contact_thickness=THICKNESS, defer_separating=defer)
    goal = target(world)
    body = Rigid(world, "sphere", 0.0, 0.0025)
    world.set_pose(body.body, world.pose(body.body)[0], [0, 0, 0, 1], [5.0, 0, 0], [0, 0, 0])
    return world, goal, body


@pytest.mark.parametrize("target", [Plane, ThinBox])
def test_a_waiting_contact_that_would_close_is_solved_and_the_sphere_lands_on_the_target(target):
    """Under 300 m/s^2 the first step would carry the sphere 0.33 m down through the target:
    its contacts, square to the motion at the start, must come back into the solve."""
    world, goal, body = skimming_sphere(True, target, 300.0)
    for _ in range(3):
        stats = world.step()
        assert not goal.passed(body), "it went through"
        assert goal.depth(body) <= THICKNESS
        assert stats["contacts"] > 0
    assert body.vertices()[:, 2].min() < 2 * THICKNESS  # it did come down onto the target


def test_the_solve_again_holds_the_contacts_the_full_solve_holds():
    """In the first step every contact waits (the sphere slides level), so solving again takes
    them all in their order: that step equals the one with every contact solved from the start.
    Later steps, the sphere on the ground, leave a few separating contacts out, which the full
    solve's sweeps also visit: they agree within the sweeps' tolerance (1e-5 m/s, against a
    hundredth of the thickness here)."""
    runs = []
    for defer in (True, False):
        world, _, body = skimming_sphere(defer, Plane, 300.0)
        poses = []
        for _ in range(3):
            world.step()
            poses.append(np.concatenate(world.pose(body.body)[:2]))
        runs.append(np.array(poses))
    np.testing.assert_allclose(runs[0][0], runs[1][0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(runs[0][1:, :3], runs[1][1:, :3], rtol=0, atol=0.01 * THICKNESS)


def falling_past_a_wall(defer: bool):
    """A rigid sphere falling at 3 m/s beside a wall (the plane x = 0), 2 mm from it, nothing
    pulling it sideways: the search reaches 0.1 m (its fall in a step) and finds the wall."""
    world = W.World(dt=DT, gravity=[0, 0, 0], contact_thickness=THICKNESS, defer_separating=defer)
    world.add_plane([0, 0, 0], [1, 0, 0], friction=0.5)
    sv, sf = icosphere(RADIUS)
    start = np.array([RADIUS + 0.002, 0.0, 0.05])
    body = world.add_mesh_body(W.RIGID, sv + start, sf, friction=0.5)
    world.set_pose(body, start, [0, 0, 0, 1], [0, 0, -3.0], [0, 0, 0])
    return world, body, start


@pytest.mark.parametrize("defer", [True, False])
def test_a_sphere_falling_past_a_wall_flies_free(defer):
    """Free flight, x(t) = x0 + v t, either way; deferred, the wall's speculative contacts stay
    out of the solve (none is solved), and without deferring they are solved to zero impulse."""
    world, body, start = falling_past_a_wall(defer)
    solved = 0
    for k in range(1, 5):
        solved += world.step()["contacts"]
        p, q, v, w = world.pose(body)
        np.testing.assert_allclose(p, start + [0, 0, -3.0 * k * DT], rtol=0, atol=1e-9)
        np.testing.assert_allclose(v, [0, 0, -3.0], rtol=0, atol=1e-7)
    assert (solved == 0) if defer else (solved > 0)

