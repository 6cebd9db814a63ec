"""Bad input gets a clear error that names the problem (and the fix), never a crash."""

import math

import numpy as np
import pytest

from haptic_hand.engine import mesh, native


def make(rig, **params):
    base = dict(palm_seed=rig.seed, handle_radius=rig.radius)
    base.update(params)
    return native.HandModel(rig.nodes, rig.tets, **base)


def test_open_mesh_is_refused_before_tetrahedralizing():
    v, f = mesh.procedural_hand()
    with pytest.raises(mesh.MeshError, match="open"):
        mesh.tetrahedralize(v, f[1:])


def test_inverted_tet_is_named(procedural_rig):
    tets = procedural_rig.tets.copy()
    tets[17] = tets[17][[0, 2, 1, 3]]
    with pytest.raises(native.InvalidInput, match=r"tetrahedron 17 .*inverted"):
        native.HandModel(procedural_rig.nodes, tets, palm_seed=procedural_rig.seed, handle_radius=0.03)


def test_zero_volume_tet_is_named(procedural_rig):
    nodes = procedural_rig.nodes.copy()
    tets = procedural_rig.tets.copy()
    # move vertex 3 of tet 5 onto the plane of the other three
    a, b, c, d = tets[5]
    nodes[d] = (nodes[a] + nodes[b] + nodes[c]) / 3
    with pytest.raises(native.InvalidInput, match="zero volume|inverted"):
        native.HandModel(nodes, tets, palm_seed=procedural_rig.seed, handle_radius=0.03)


def test_seed_outside_the_hand(procedural_rig):
    outside = procedural_rig.nodes.max(axis=0) + 0.05
    with pytest.raises(native.InvalidInput, match="outside the hand"):
        make(procedural_rig, palm_seed=outside)


@pytest.mark.parametrize("radius, words", [(1e-4, "at least 4"), (10.0, "all")])
def test_radius_catching_too_few_or_all_nodes(procedural_rig, radius, words):
    with pytest.raises(native.InvalidInput, match=words):
        make(procedural_rig, handle_radius=radius)


@pytest.mark.parametrize("name", ["young_modulus", "density", "spring_stiffness", "handle_radius", "dt"])
@pytest.mark.parametrize("value", [math.nan, 0.0, -1.0])
def test_nan_or_non_positive_parameters(procedural_rig, name, value):
    with pytest.raises(native.InvalidInput, match=name):
        make(procedural_rig, **{name: value})


@pytest.mark.parametrize("name", ["poisson_ratio", "spring_damping", "rayleigh_beta"])
def test_out_of_range_parameters(procedural_rig, name):
    with pytest.raises(native.InvalidInput, match=name):
        make(procedural_rig, **{name: -0.1 if name != "poisson_ratio" else 0.5})


def test_too_large_time_step(procedural_rig):
    with pytest.raises(native.InvalidInput, match="dt"):
        make(procedural_rig, dt=0.5)


def test_array_shapes_are_checked(procedural_rig):
    model = make(procedural_rig)
    sim = native.HandSimulation(model)
    with pytest.raises(native.InvalidInput, match="shape"):
        sim.set_state(positions=np.zeros((3, 3)))
    with pytest.raises(native.InvalidInput, match="NaN"):
        sim.set_device([np.nan, 0, 0])


def test_rejected_state_leaves_the_simulation_as_it_was(procedural_rig):
    model = make(procedural_rig)
    sim = native.HandSimulation(model)
    sim.step()
    before = sim.positions()
    with pytest.raises(native.InvalidInput):
        sim.set_state(velocities=np.full(model.nodes.shape, np.inf))
    assert np.array_equal(sim.positions(), before)
