"""The handle-space model of a hand of B bones in a world with its contacts held (issue 40;
docs/skeleton.md, Section 6): hh_world_bone_coupling_model against the full world step re-run
from the same state with every bone prescribed to its pose displaced, in each of the 6B
directions and over three decades of the displacement. As for the palm handle
(test_linearization.py): where the step is linear in the displacement (translations, with the
contacts sticking or none) the error is round-off; elsewhere it must fall as delta^2 (fitted
slope 1.9-2.1), and the model must explain the change (error below 1e-3 of it at the smallest
delta).

The hands' flesh here has Poisson's ratio 0.01. Pressed into the ground with 0.3, a fingertip
bulges sideways: its edge contacts slide outward and stop under load, stuck on the rim of their
friction cones, where the step has a kink (pushed one way they stick, the other way they slide).
The model holds them stuck, and there its error does not shrink with delta (measured on the
gripper: up to 5e-4 of the change, the same at every delta). Without the bulge, pressing leaves
every contact strictly inside its cone: sticking in the model's sense."""

from pathlib import Path

import numpy as np
import pytest

from haptic_hand.engine import gripper, mesh, native
from haptic_hand.engine import native_skeleton as ns
from haptic_hand.engine import native_world as nw
from haptic_hand.engine import skeleton as sk
from test_linearization import DT, assert_derivative, quat, quat_mul

SAMPLES = Path(sk.__file__).resolve().parent / "sample_scenes"
# the contact sweeps converge to 1e-12 m/s so that the step is a smooth function of the poses
CONTACT = dict(contact_thickness=1e-3, contact_patch=4e-3, threads=1, tolerance=1e-12, max_iterations=100000,
               stall_factor=0.0)
G = [0.0, 0.0, -9.81]


def rigid_motion(p0, q0, centre, offset, turn):
    """Every bone carried by one rigid motion: a turn (rotation vector) about `centre`, then `offset`."""
    r = quat(turn)
    rot = 2 * np.outer(r[:3], r[:3]) + (r[3] ** 2 - r[:3] @ r[:3]) * np.eye(3) + 2 * r[3] * np.array(
        [[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
    return centre + (p0 - centre) @ rot.T + offset, np.array([quat_mul(r, q) for q in q0])


def displaced(poses, delta):
    """The B poses displaced by delta (dx_1, dtheta_1, ..., dx_B, dtheta_B)."""
    p, q = poses
    d = delta.reshape(-1, 6)
    return p + d[:, :3], np.array([quat_mul(quat(d[b, 3:]), q[b]) for b in range(len(p))])


def pressed_world(kind, model, nodes, tets, steps, press, spread=None):
    """The hand on the ground (friction 0.5, gravity on), every bone prescribed: pressed `press`
    m into it over the first ten steps (sticking); sliding, also dragged along y at 0.05 m/s while
    it turns about the vertical at 0.3 rad/s; free, waved and turned above the ground instead. spread(k) moves the
    bones relative to each other (a finger closing). Returns the world, the hand and the poses
    the step after those steps prescribes, with a function that re-runs that step."""
    world = nw.World(dt=DT, gravity=G, **CONTACT)
    surface_nodes, surface_weights = nw.vertex_surface(len(nodes))
    hand = world.add_hand(model, surface_nodes, surface_weights, mesh.tet_boundary_faces(tets), friction=0.5)
    if kind != "free":
        world.add_plane([0.0, 0.0, nodes[:, 2].min() - 0.0015], [0.0, 0.0, 1.0], friction=0.5)
    p0, q0, _ = world.bone_states(hand)
    centre = p0[0]
    b = len(p0)

    def target(k):
        t = k * DT
        if kind == "free":
            offset = 0.01 * np.array([np.sin(3 * t), 0.5 * np.sin(2 * t), 0.3 * np.sin(4 * t)])
            turn = [0.2 * np.sin(4 * t), 0.1 * (1 - np.cos(3 * t)), 0.3 * t]
        else:  # (sticking: pressed straight down; the turn would make the fingertips slide)
            offset = np.array([0.0, 0.05 * t if kind == "sliding" else 0.0, -press * min(k, 10) / 10])
            turn = [0.0, 0.0, 0.3 * t if kind == "sliding" else 0.0]
        p = p0 + (spread(k) if spread else 0.0)
        return rigid_motion(p, q0, centre, offset, turn)

    for k in range(1, steps + 1):
        world.set_bone_targets(hand, np.full(b, ns.PRESCRIBED), *target(k))
        stats = world.step()
    x, v = world.nodes(hand)
    p, q, _ = world.bone_states(hand)
    vel, omega = world.bone_velocities(hand)
    poses = target(steps + 1)

    def step_wrench(delta):
        world.set_nodes(hand, x, v)
        world.set_bone_states(hand, p, q, vel, omega)
        world.set_bone_targets(hand, np.full(b, ns.PRESCRIBED), *displaced(poses, delta))
        world.step()
        return world.bone_states(hand)[2].reshape(-1)

    return world, hand, stats, step_wrench


def check_model(world, hand, step_wrench, kind):
    w0_step = step_wrench(np.zeros(6 * world.n_bones(hand)))
    w0, stiffness, held = world.bone_coupling_model(hand)
    assert (held > 0) == (kind != "free")
    assert np.abs(w0_step - w0).max() < 1e-12 * np.abs(w0).max()
    assert np.abs(step_wrench(np.zeros_like(w0)) - w0).max() < 1e-9 * np.abs(w0).max()
    # as test_linearization's world case: the sweeps' 1e-12 m/s leave ~1e-11 N of noise; while
    # sliding the friction turns with the sliding velocity, so translations too are second order
    sliding = kind == "sliding"
    assert_derivative(step_wrench, w0, stiffness, translation_exact=not sliding, translation=0.1 if sliding else 0.01,
                      exact=1e-5, linear_or_second_order=sliding)
    return w0, stiffness


FLESH = dict(gripper.HAND, poisson_ratio=0.01)


@pytest.fixture(scope="module")
def three_bones():
    """The two-finger gripper (engine/gripper.py): a palm and two finger bones, fingers down."""
    nodes, tets, skeleton = gripper.gripper(gripper.GAP)
    return nodes, tets, ns.SkeletonModel(nodes, tets, skeleton, dt=DT, gravity=G, **FLESH)


@pytest.mark.parametrize("kind", ["sticking", "sliding", "free"])
def test_three_bone_model_with_contacts_held_is_the_derivative_of_its_step(three_bones, kind):
    """The gripper's fingertips pressed 3 mm into the ground (gravity on, friction 0.5) while the
    fingers close: sticking, dragged and turned along the ground (sliding), or waved in the air
    (free); every one of the 18 directions."""
    nodes, tets, model = three_bones

    def closing(k):
        out = np.zeros((3, 3))
        out[1, 0], out[2, 0] = 0.002 * min(k, 15) / 15, -0.002 * min(k, 15) / 15
        return out

    world, hand, stats, step_wrench = pressed_world(kind, model, nodes, tets, 18, 0.003,
                                                    None if kind == "sticking" else closing)
    if kind != "free":
        assert stats["contacts"] >= 4
    w0, stiffness = check_model(world, hand, step_wrench, kind)
    # the bones feel each other through the flesh and the held contacts: the model is not block diagonal
    assert np.abs(stiffness[:6, 6:12]).max() > 1e-3 * np.abs(stiffness[:6, :6]).max()


def test_sixteen_bone_hand_pressed_on_the_ground_has_a_second_order_model():
    """The rigged procedural hand (16 bones, the stored sample tets) pressed 4 mm into the ground
    with friction 0.5 and sticking, its 96 directions."""
    stored = np.load(SAMPLES / "procedural_hand_tets.npz")
    nodes, tets = stored["nodes"], stored["tets"]
    model = ns.SkeletonModel(nodes, tets, sk.procedural_hand_skeleton(), dt=DT, gravity=G, **FLESH)
    world, hand, stats, step_wrench = pressed_world("sticking", model, nodes, tets, 12, 0.004)
    assert stats["contacts"] > 10
    check_model(world, hand, step_wrench, "sticking")


def test_one_bone_model_is_the_palm_handles_model(procedural_rig):
    """A one-bone hand (the palm handle) pressed on the ground: the bones' model is
    hh_world_coupling_model's, entry for entry."""
    model = native.HandModel(procedural_rig.nodes, procedural_rig.tets, palm_seed=procedural_rig.seed,
                             handle_radius=procedural_rig.radius)
    world, hand, stats, _ = pressed_world("sticking", model, procedural_rig.nodes, procedural_rig.tets, 8, 0.004)
    assert stats["contacts"] > 0
    w0, k, held = world.bone_coupling_model(hand)
    w1, k1, held1 = world.coupling_model(hand)
    assert held > 0 and held == held1
    assert np.array_equal(w0, w1) and np.array_equal(k, k1)


def test_the_bones_model_refuses_a_step_not_prescribed(three_bones):
    nodes, tets, model = three_bones
    world = nw.World(dt=DT, gravity=G)
    surface_nodes, surface_weights = nw.vertex_surface(len(nodes))
    hand = world.add_hand(model, surface_nodes, surface_weights, mesh.tet_boundary_faces(tets))
    modes = np.full(3, ns.PRESCRIBED)
    modes[2] = ns.COUPLED
    world.set_bone_targets(hand, modes)
    world.step()
    with pytest.raises(native.InvalidInput, match=r"needs the world's last step taken with every bone prescribed "
                                                  r"\(hh_world_set_bone_targets with HH_BONE_PRESCRIBED"):
        world.bone_coupling_model(hand)
