"""Handle-space linearization of the coupling force (Section 3, Garre & Otaduy 2009): the
linear model built from the Schur-complement solves against the coupling force re-solved for
a prescribed handle motion (issue 4, first part: no contact yet)."""

import numpy as np
import pytest

from haptic_hand.engine import native


@pytest.fixture(scope="module")
def moving_hand(procedural_rig):
    model = native.HandModel(procedural_rig.nodes, procedural_rig.tets, palm_seed=procedural_rig.seed,
                             handle_radius=procedural_rig.radius, spring_stiffness=2e4, spring_damping=20.0)
    sim = native.HandSimulation(model)
    com = np.array(model.info()["handle_com"])
    sim.set_device(com + [0.01, 0.0, -0.005], [0, 0.1, 0, np.sqrt(1 - 0.01)], [0.1, 0, 0], [0, 0.5, 0])
    for _ in range(5):  # a deformed, moving, turned hand: every term active
        sim.step()
    return model, sim


def test_model_is_exact_when_the_handle_is_still(moving_hand):
    _, sim = moving_hand
    w0, _ = sim.coupling_linear_model()
    true = sim.coupling_response(np.zeros(6))
    assert np.abs(true - w0).max() < 1e-9 * np.abs(w0).max()


def test_model_is_exact_for_handle_translation(moving_hand):
    """The springs are linear in the positions of their ends; only rotation is not."""
    _, sim = moving_hand
    w0, response = sim.coupling_linear_model()
    v = np.array([0.05, -0.02, 0.03, 0, 0, 0])
    true = sim.coupling_response(v)
    assert np.abs(true - (w0 + response @ v)).max() < 1e-8 * np.abs(true - w0).max()


def test_model_error_is_second_order_in_handle_rotation(moving_hand):
    _, sim = moving_hand
    w0, response = sim.coupling_linear_model()
    direction = np.array([0.01, 0.0, 0.0, 0.8, -0.5, 0.3])
    errors = []
    for eps in (0.02, 0.01, 0.005):
        v = eps * direction
        errors.append(np.linalg.norm(sim.coupling_response(v) - (w0 + response @ v)))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all(np.abs(ratios - 4.0) < 0.4), ratios  # halving the motion quarters the error
    # and at small motions the linear part dominates: the model is useful, not just consistent
    # (its share of the error shrinks in proportion to the motion; 1e-3 here is 1.9 mrad per step)
    v = 1e-3 * direction
    assert np.linalg.norm(sim.coupling_response(v) - (w0 + response @ v)) < 0.05 * np.linalg.norm(response @ v)


def test_response_opposes_handle_motion(moving_hand):
    """Moving the handle, the flesh pulls back against the motion: the symmetric part of the
    linear response is negative definite (a passive, stable model for the haptic loop)."""
    _, sim = moving_hand
    _, response = sim.coupling_linear_model()
    linear = 0.5 * (response[:3, :3] + response[:3, :3].T)
    assert np.linalg.eigvalsh(linear).max() < 0
