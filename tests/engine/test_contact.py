"""Contact in the visual loop, against physics: Coulomb friction on an incline, a resting
body's weight carried by the ground, momentum in a collision, friction drag by a moving
body. (The hand's own contact tests are in test_hand_contact.py.)"""

import math

import numpy as np
import pytest

from haptic_hand.engine import mesh, native, scene as scenes
from haptic_hand.engine import native_world as W

G = 9.81


def cube_surface(half: float):
    v = np.array([[x, y, z] for z in (-half, half) for y in (-half, half) for x in (-half, half)], float)
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])
    return v, f


def rotation_y(theta):
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def add_soft_block(world, size, cells, origin, **material):
    nodes, tets = mesh.structured_box([size] * 3, [cells] * 3, origin)
    faces = mesh.tet_boundary_faces(tets)
    sn, sw = W.vertex_surface(len(nodes))
    return world.add_soft_body(nodes, tets, sn, sw, faces, **material), nodes


def incline(theta_deg: float, mu: float, seconds: float, dt=0.01, kinetic=None, speed=0.0):
    """A 4 cm rigid cube on a plane tilted by theta about y, at rest or sliding downhill at
    `speed`; returns the cube's displacement along the slope (downhill positive) per step."""
    theta = math.radians(theta_deg)
    rot = rotation_y(theta)
    normal = rot @ [0, 0, 1]  # (sin, 0, cos): the plane z = -x tan(theta) descends towards +x
    downhill = rot @ [1, 0, 0]
    world = W.World(dt=dt, contact_thickness=1e-3)
    plane = world.add_plane([0, 0, 0], normal, friction=mu)
    v, f = cube_surface(0.02)
    centre = (0.02 + 0.001) * normal  # resting at the contact thickness: touching, not overlapping
    cube = world.add_mesh_body(W.RIGID, v @ rot.T + centre, f, density=500.0, friction=mu)
    if kinetic is not None:
        for body in (plane, cube):
            world.set_friction(body, mu, kinetic)
    start = world.pose(cube)[0]
    world.set_pose(cube, velocity=speed * downhill)
    travel = []
    for _ in range(int(round(seconds / dt))):
        world.step()
        travel.append((world.pose(cube)[0] - start) @ downhill)
    return np.array(travel), downhill


def test_block_stays_on_an_incline_flatter_than_its_friction_angle():
    travel, _ = incline(20.0, 0.5, 2.0)  # tan 20 deg = 0.36 < 0.5
    assert np.abs(travel).max() < 1e-3


@pytest.mark.parametrize("theta_deg, mu", [(30.0, 0.3), (40.0, 0.5)])
def test_block_slides_with_the_coulomb_acceleration(theta_deg, mu):
    dt = 0.01
    travel, _ = incline(theta_deg, mu, 1.0, dt)
    t = dt * np.arange(1, len(travel) + 1)
    expected = G * (math.sin(math.radians(theta_deg)) - mu * math.cos(math.radians(theta_deg)))
    measured = 2 * np.polyfit(t[10:], travel[10:], 2)[0]
    assert measured == pytest.approx(expected, rel=0.05)


def test_static_friction_holds_and_kinetic_friction_slides():
    """Static 0.5, kinetic 0.3 on a 25 degree slope (tan = 0.47): at rest the block stays; set
    sliding, it keeps sliding and speeds up at g (sin - 0.3 cos)."""
    at_rest, _ = incline(25.0, 0.5, 1.0, kinetic=0.3)
    assert np.abs(at_rest).max() < 1e-3
    dt = 0.01
    sliding, _ = incline(25.0, 0.5, 1.0, dt=dt, kinetic=0.3, speed=0.2)
    t = dt * np.arange(1, len(sliding) + 1)
    expected = G * (math.sin(math.radians(25.0)) - 0.3 * math.cos(math.radians(25.0)))
    assert 2 * np.polyfit(t[10:], sliding[10:], 2)[0] == pytest.approx(expected, rel=0.05)


@pytest.mark.parametrize("solver", ["cholesky", "reused_cholesky"])
def test_soft_block_on_the_ground_carries_its_weight(solver):
    # reused_cholesky: the contact responses come from a lagged factor; the impulses carried
    # into the next free solve keep the resting block's load exact (World::solve_free)
    world = W.World(dt=1 / 60, contact_thickness=1e-3)
    world.add_plane([0, 0, 0], [0, 0, 1], friction=0.5)
    size, density = 0.04, 1000.0
    block, _ = add_soft_block(world, size, 3, (-0.02, -0.02, 0.0009), young_modulus=1e5, density=density)
    if solver != "cholesky":
        world.set_body_solver(block, solver, cg_tolerance=1e-8)
    for _ in range(240):
        stats = world.step()
    _, v = world.nodes(block)
    assert np.abs(v).max() < 1e-3  # at rest
    weight = density * size**3 * G
    force = world.contact_force(block)
    assert force[2] == pytest.approx(weight, rel=0.01)
    assert np.hypot(force[0], force[1]) < 0.01 * weight
    assert stats["max_penetration"] < 1e-3


def test_resting_contacts_keep_their_warm_start():
    """A body at rest on the ground: the last step's impulses solve this step's contact problem
    too, so the sweeps end at once. The block's fine surface (1.7 mm) rides on a coarse tet mesh
    (2 cm), so several bottom vertices of an element share each 4 mm patch cell at nearly the
    same depth: the cell's contact must stay on the same vertex from step to step (an impulse
    moved to another vertex of the element turns it differently, and the solve starts over)."""
    world = W.World(dt=1 / 60, contact_thickness=1e-3)
    world.add_plane([0, 0, 0], [0, 0, 1], friction=0.5)
    size, origin = 0.04, (-0.02, -0.02, 0.0009)
    nodes, tets = mesh.structured_box([size] * 3, [2] * 3, origin)
    fine_nodes, fine_tets = mesh.structured_box([size] * 3, [24] * 3, origin)
    faces = mesh.tet_boundary_faces(fine_tets)
    used, faces = np.unique(faces, return_inverse=True)
    faces = faces.reshape(-1, 3)
    tet_index, weights = mesh.embed_points(nodes, tets, fine_nodes[used])
    sn, sw = W.embedded_surface(tets, tet_index, weights)
    block = world.add_soft_body(nodes, tets, sn, sw, faces, young_modulus=1e5, density=1000.0)
    for _ in range(240):
        world.step()
    _, v = world.nodes(block)
    assert np.abs(v).max() < 1e-3  # at rest
    sweeps = []
    for _ in range(30):
        stats = world.step()
        assert stats["contacts"] > 0 and stats["residual"] <= 1e-5
        sweeps.append(stats["iterations"])
    assert max(sweeps) <= 2, sweeps


def test_colliding_soft_bodies_conserve_momentum():
    world = W.World(dt=1 / 100, gravity=[0, 0, 0], contact_thickness=1e-3)
    a, _ = add_soft_block(world, 0.03, 2, (-0.0305, 0.0, 0.0), young_modulus=5e4, rayleigh_beta=0.0)
    b, _ = add_soft_block(world, 0.03, 2, (0.0005, 0.005, 0.005), young_modulus=5e4, rayleigh_beta=0.0, density=600.0)
    xa, _ = world.nodes(a)
    xb, _ = world.nodes(b)
    world.set_nodes(a, velocities=np.tile([0.3, 0.0, 0.0], (len(xa), 1)))
    world.set_nodes(b, velocities=np.tile([-0.2, 0.05, 0.0], (len(xb), 1)))
    p0 = world.linear_momentum()
    touched = 0
    for _ in range(60):
        stats = world.step()
        touched += stats["contacts"] > 0
        assert np.linalg.norm(world.linear_momentum() - p0) < 1e-6 * np.linalg.norm(p0)
    assert touched > 0
    # they bounced: a no longer moves towards b as fast as it started
    assert world.nodes(a)[1][:, 0].mean() < 0.3 - 0.05


def test_moving_platform_drags_a_resting_block_by_friction():
    dt = 1 / 60
    world = W.World(dt=dt, contact_thickness=1e-3)
    v, f = cube_surface(0.5)
    platform_top = 0.0
    verts = v * [0.4, 0.4, 0.02] / 0.5 + [0, 0, platform_top - 0.02]
    platform = world.add_mesh_body(W.KINEMATIC, verts, f, friction=0.8)
    block, _ = add_soft_block(world, 0.04, 2, (-0.02, -0.02, platform_top + 0.0009), young_modulus=1e5, friction=0.8)
    speed = np.array([0.1, 0.0, 0.0])
    p0 = world.pose(platform)[0]
    for k in range(1, 181):
        world.set_pose(platform, p0 + speed * k * dt, [0, 0, 0, 1], speed, [0, 0, 0])
        world.step()
    _, vel = world.nodes(block)
    mean = vel.mean(axis=0)
    assert mean[0] == pytest.approx(speed[0], rel=0.01)
    assert abs(mean[2]) < 1e-3


@pytest.mark.parametrize("target", ["ground", "block"])
def test_fast_bodies_do_not_tunnel(target):
    """A soft block dropped from 12 cm hits at ~1.5 m/s, 5 cm per 1/30 s step: fifty contact
    thicknesses. Each body is searched as far as it can move within the step, so the landing
    is met as an open contact one step ahead and the gap is closed exactly: no step may end
    with the surfaces closer than the thickness minus round-off, on the ground plane or on a
    static rigid block (pair detection, the falling body's reach on top of the block's)."""
    dt, thickness, drop = 1 / 30, 1e-3, 0.12
    world = W.World(dt=dt, contact_thickness=thickness)
    if target == "ground":
        world.add_plane([0, 0, 0], [0, 0, 1], friction=0.5)
    else:
        v, f = cube_surface(0.05)
        world.add_mesh_body(W.STATIC, v - [0, 0, 0.05], f, friction=0.5)  # top face at z = 0
    block, nodes = add_soft_block(world, 0.03, 2, (-0.015, -0.015, drop), young_modulus=1e5)
    fastest, deepest = 0.0, 0.0
    for _ in range(12):
        stats = world.step()
        fastest = max(fastest, np.abs(world.nodes(block)[1][:, 2]).max())
        deepest = max(deepest, stats["max_penetration"])
    assert fastest * dt > 20 * thickness  # it did fall fast enough to have tunnelled
    assert world.nodes(block)[0][:, 2].min() > 0  # it did land, on top
    assert deepest < thickness


def sagging_beam_at_rest(solver: str):
    """A 20 cm soft cantilever (fixed at x = 0) sagging under gravity onto a frictionless floor
    5 cm below it, stepped to rest: the floor's force on it, its nodes, their largest speed,
    and its rest nodes."""
    world = W.World(dt=1 / 60, contact_thickness=1e-3)
    world.add_plane([0, 0, -0.05], [0, 0, 1], friction=0.0)
    nodes, tets = mesh.structured_box([0.2, 0.02, 0.02], [10, 1, 1], (0, -0.01, -0.01))
    sn, sw = W.vertex_surface(len(nodes))
    fixed = np.flatnonzero(nodes[:, 0] < 1e-9).astype(np.int32)
    beam = world.add_soft_body(nodes, tets, sn, sw, mesh.tet_boundary_faces(tets), fixed_nodes=fixed, friction=0.0,
                               young_modulus=1e4, density=1000.0, rayleigh_alpha=3.0, rayleigh_beta=0.02)
    if solver != "cholesky":
        world.set_body_solver(beam, solver, cg_tolerance=1e-8)
    for _ in range(600):
        world.step()
    x, v = world.nodes(beam)
    return world.contact_force(beam), x, np.abs(v).max(), nodes


def test_a_soft_body_on_the_reused_factor_rests_where_the_per_step_factor_does():
    # Without friction the resting state is unique: the beam's shape and the floor's force
    # balance its weight and elasticity whatever solver found them. On the reused factor the
    # contact responses come from a lagged, warped operator (its columns kept between
    # factorizations) and the free solve is CG to 1e-8: the rest state must still be the
    # per-step factor's, to far below the 1e-6 allowed here.
    exact_force, exact_x, exact_v, rest = sagging_beam_at_rest("cholesky")
    force, x, v, _ = sagging_beam_at_rest("reused_cholesky")
    assert exact_v < 1e-6 and v < 1e-6  # both at rest
    assert exact_force[2] > 0.1  # the beam lies on the floor...
    tip = rest[:, 0] > 0.2 - 1e-9
    assert exact_x[tip, 2].mean() < -0.03  # ... sagging through large rotations near its tip
    assert force[2] == pytest.approx(exact_force[2], rel=1e-6)
    assert np.abs(x - exact_x).max() < 1e-6


def test_a_soft_body_solver_is_checked():
    world = W.World()
    plane = world.add_plane([0, 0, 0], [0, 0, 1])
    block, _ = add_soft_block(world, 0.04, 2, (0, 0, 0.01))
    with pytest.raises(native.InvalidInput, match="cholesky or reused_cholesky"):
        world.set_body_solver(block, "cg")
    with pytest.raises(native.InvalidInput, match="only soft bodies"):
        world.set_body_solver(plane, "reused_cholesky")
    with pytest.raises(native.InvalidInput, match="cg_tolerance"):
        world.set_body_solver(block, "reused_cholesky", cg_tolerance=float("nan"))
    world.set_body_solver(block, "reused_cholesky")
    world.step()  # (the body steps on the reused factor)


@pytest.mark.parametrize("factor", [-1.0, 0.5, float("nan"), float("inf"), True, "4"])
def test_bad_stall_factors_are_named(factor):
    # 0 (off) or at least 1: a factor below 1 would never let the sweeps stop before the tolerance
    with pytest.raises(scenes.SceneError, match="contact.stall_factor"):
        scenes.from_dict({"format": scenes.FORMAT, "contact": {"stall_factor": factor}})
    if isinstance(factor, float):
        with pytest.raises(native.InvalidInput, match="stall_factor"):
            W.World(stall_factor=factor)


@pytest.mark.parametrize("threads", [0, 3, True, 1.5])
def test_bad_thread_counts_are_named(threads):
    with pytest.raises(scenes.SceneError, match="contact.threads"):
        scenes.from_dict({"format": scenes.FORMAT, "contact": {"threads": threads}})
    if isinstance(threads, int) and not isinstance(threads, bool):
        with pytest.raises(native.InvalidInput, match="threads"):
            W.World(threads=threads)
