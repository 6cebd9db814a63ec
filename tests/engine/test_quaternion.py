"""The Python quaternions (addon/engine/quaternion.py, (x, y, z, s) as in the paper's Appendix A)
against scipy's rotations, one at a time and on arrays of them (the bone drive turns every
bone of a skeleton at once)."""

import numpy as np
from scipy.spatial.transform import Rotation

from haptic_hand.engine import quaternion as quat


def turns(n: int, seed: int) -> np.ndarray:
    q = Rotation.random(n, random_state=seed).as_quat()  # scalar last, as here
    q[: n // 2] *= -1  # both signs of each rotation
    return q


def test_products_on_arrays_equal_scipys_composition_and_each_one_alone():
    a, b = turns(16, 1), turns(16, 2)
    product = quat.multiply(a, b)
    expected = (Rotation.from_quat(a) * Rotation.from_quat(b)).as_matrix()
    assert np.abs(Rotation.from_quat(product).as_matrix() - expected).max() < 1e-14
    for k in range(16):
        assert np.array_equal(quat.multiply(a[k], b[k]), product[k])
    # one quaternion against many broadcasts
    assert np.abs(quat.multiply(a[0], b) - quat.multiply(np.tile(a[0], (16, 1)), b)).max() == 0


def test_the_conjugate_undoes_the_turn():
    a = turns(8, 3)
    assert np.abs(quat.multiply(a, quat.conjugate(a)) - [0, 0, 0, 1]).max() < 1e-15


def test_rotation_vectors_on_arrays_equal_scipys_the_shorter_way_round():
    a = np.vstack([turns(16, 4), [[0, 0, 0, 1], [0, 0, 0, -1], [1e-14, 0, 0, 1]]])
    vectors = quat.rotation_vector(a)
    expected = Rotation.from_quat(a / np.linalg.norm(a, axis=1, keepdims=True)).as_rotvec()
    assert np.abs(vectors - expected).max() < 1e-12
    assert np.linalg.norm(vectors, axis=1).max() <= np.pi + 1e-12
    for k in range(len(a)):
        assert np.abs(quat.rotation_vector(a[k]) - vectors[k]).max() == 0
