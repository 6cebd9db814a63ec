"""A hand of sixteen bones in a world (issue 40; docs/skeleton.md, Section 3, "Contacts"): with no
contact its world step is its own step bit for bit; pressed on the ground by its bones, the
contacts hold the thickness and the statics close: the bones' springs carry the flesh's weight
and the ground's push, node by node as the world reports them."""

from pathlib import Path

import numpy as np
import pytest

from haptic_hand.engine import mesh, native
from haptic_hand.engine import native_skeleton as ns
from haptic_hand.engine import native_world as nw
from haptic_hand.engine import skeleton as sk

SAMPLES = Path(sk.__file__).resolve().parent / "sample_scenes"
G = np.array([0.0, 0.0, -9.81])
PARAMS = dict(young_modulus=5e4, poisson_ratio=0.3, density=1000.0, rayleigh_alpha=8.0, rayleigh_beta=0.01,
              spring_stiffness=1e4, spring_damping=10.0, dt=1.0 / 30.0, gravity=list(G))


@pytest.fixture(scope="module")
def rig():
    stored = np.load(SAMPLES / "procedural_hand_tets.npz")
    nodes, tets = stored["nodes"], stored["tets"]
    return nodes, tets, ns.SkeletonModel(nodes, tets, sk.procedural_hand_skeleton(), **PARAMS)


def world_with(rig, floor=None, **world):
    nodes, tets, model = rig
    w = nw.World(dt=PARAMS["dt"], gravity=list(G), **world)
    surface_nodes, surface_weights = nw.vertex_surface(len(nodes))
    hand = w.add_hand(model, surface_nodes, surface_weights, mesh.tet_boundary_faces(tets))
    if floor is not None:
        w.add_plane([0.0, 0.0, floor], [0.0, 0.0, 1.0], friction=0.5)
    return w, hand


def test_world_without_contact_is_the_skeletons_own_step(rig):
    """No body to touch: the world's step of the hand (its free solve, the B-bone Schur
    complement) is step_skeleton's, every bone coupled to its rest pose, bit for bit."""
    _, _, model = rig
    w, hand = world_with(rig)
    sim = ns.SkeletonSimulation(model)
    p, q, _ = w.bone_states(hand)
    w.set_bone_targets(hand, np.full(16, ns.COUPLED), p + [0.0, 0.01, 0.0], q)
    sim.set_bone_targets(np.full(16, ns.COUPLED), p + [0.0, 0.01, 0.0], q)
    for _ in range(8):
        w.step()
        sim.step()
    assert np.array_equal(w.nodes(hand)[0], sim.positions())
    assert np.array_equal(w.bone_states(hand)[1], sim.bone_states()[1])
    assert np.abs(sim.positions() - rig[0]).max() > 1e-3  # it moved


@pytest.mark.parametrize("threads", [1, 2])
def test_pressed_on_the_ground_the_bones_carry_weight_and_push(rig, threads):
    """Every bone prescribed 1 cm down into a floor 2 mm under the fingertips, then held: no
    node ends inside the contact thickness (1 mm; 1 % slack for the solver's tolerance), and once
    settled the springs' forces on the bones are the flesh's weight plus the ground's push,
    sum_b F_b = M g + F_contact (the flesh in equilibrium; gravity acts on it alone), with
    F_contact the sum of the per-node contact forces."""
    nodes, _, model = rig
    floor = nodes[:, 2].min() - 0.002
    w, hand = world_with(rig, floor, threads=threads)
    p0, q0, _ = w.bone_states(hand)
    for k in range(80):
        w.set_bone_targets(hand, np.full(16, ns.PRESCRIBED), p0 + [0.0, 0.0, -0.01 * min(1.0, k / 10)], q0)
        stats = w.step()
        assert w.nodes(hand)[0][:, 2].min() - floor > 0.99e-3, k
    assert stats["contacts"] > 10
    _, _, wrench = w.bone_states(hand)
    per_node = w.node_contact_forces(hand)
    assert np.allclose(per_node.sum(axis=0), w.contact_force(hand), rtol=1e-12, atol=1e-9)
    push = per_node.sum(axis=0)
    assert push[2] > 100.0  # the ground pushes the hand up, hard
    expected = model.lumped_masses().sum() * G + push
    print("sum F_b", wrench[:, :3].sum(axis=0), "M g + F_c", expected)
    assert np.abs(wrench[:, :3].sum(axis=0) - expected).max() < 1e-6 * np.linalg.norm(expected)
    assert np.abs(per_node[nodes[:, 2] > floor + 0.02]).max() == 0.0  # only the fingertips touch


def test_the_palm_handles_model_refuses_a_skeleton_hand_naming_the_bones_model(rig):
    w, hand = world_with(rig)
    w.set_bone_targets(hand, np.full(16, ns.PRESCRIBED))
    w.step()
    with pytest.raises(native.InvalidInput, match="this hand has 16 bones .a skeleton.: take the bones' model, "
                                                  "hh_world_bone_coupling_model"):
        w.coupling_model(hand)
    assert w.bone_coupling_model(hand)[1].shape == (96, 96)


def test_bone_targets_are_checked_naming_the_fix(rig):
    w, hand = world_with(rig)
    with pytest.raises(native.InvalidInput, match=r"bone modes must be 16 integers"):
        w.set_bone_targets(hand, np.ones(3, dtype=int))
    modes = np.full(16, ns.COUPLED)
    modes[4] = 7
    with pytest.raises(native.InvalidInput, match=r"bone 4 has mode 7: give HH_BONE_FREE \(0\), HH_BONE_COUPLED"):
        w.set_bone_targets(hand, modes)
    plane = w.add_plane([0.0, 0.0, -1.0], [0.0, 0.0, 1.0])
    with pytest.raises(native.InvalidInput, match=f"body {plane} is not the hand"):
        w.bone_states(plane)
