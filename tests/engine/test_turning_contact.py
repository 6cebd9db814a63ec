"""The hand's step advances every node by its handle's turn (docs/maths.md, "Rotation-consistent
integration"); the contact solve must know where the nodes end: a hand whose wrist turns fast
against a wall stays outside the wall's contact layer (issue 37, point 3)."""

from pathlib import Path

import numpy as np
import pytest

from haptic_hand.engine import scene as scenes, simulate

SAMPLES = Path(simulate.__file__).parent / "sample_scenes"
DT = 1.0 / 30.0


def quat(theta):
    angle = float(np.linalg.norm(theta))
    if angle == 0.0:
        return np.array([0.0, 0.0, 0.0, 1.0])
    return np.concatenate([np.sin(angle / 2) * np.asarray(theta) / angle, [np.cos(angle / 2)]])


@pytest.mark.parametrize("axis", [1, 2])
def test_a_wrist_turning_against_a_wall_stays_outside_its_contact_layer(axis):
    """The palm pressed into a frictionless wall while the handle rocks at up to 3 rad/s about
    an axis along the wall: the fingertips swing into it. Leaving the turn's second-order part
    out of the contacts' gaps, they ended up to 0.17 mm inside the 1 mm layer."""
    sc = scenes.load(SAMPLES / "hand_wave.json")
    sc.data["gravity"] = [0.0, 0.0, 0.0]
    sc.data["hand"]["friction"] = 0.0
    world, hand, model, _, _ = simulate.build_world(sc)
    thickness = 1e-3
    wall = world.surface(hand)[:, 0].min() - 0.001
    world.add_plane([wall, 0, 0], [1, 0, 0], friction=0.0)
    com = np.array(model.info()["handle_com"])
    deepest, pushed = 0.0, 0
    for k in range(1, 61):
        turn = np.zeros(3)
        turn[axis] = 0.3 * np.sin(10 * k * DT)
        world.set_device(hand, com + [-0.004 * min(k, 15) / 15, 0, 0], quat(turn), enabled=2)
        stats = world.step()
        if k > 20:
            deepest = max(deepest, thickness - (world.surface(hand)[:, 0].min() - wall))
            pushed += stats["contacts"] > 0
    assert pushed >= 30  # in contact most of the time
    assert deepest < 0.05 * thickness
