"""Co-rotational elastic forces after a state jump (issue 37, point 2): the hand set to a
rotated state deformed by 1 mm of random noise (every rotation, tets inverted among them),
its elastic forces against co-rotational FEM written again in numpy with numpy's SVD.

The engine's forces are read through one implicit step from rest at dt = 1e-9 s with no damping,
no gravity, no device and springs of 1e-9 N/m: (M + dt^2 K) v' = dt f, so M v'/dt is f to a
relative 1e-12 (dt^2 K/M), through the very element pass the step runs (SIMD lanes included)."""

from pathlib import Path

import numpy as np

from haptic_hand.engine import native, scene as scenes

SAMPLES = Path(native.__file__).parent / "sample_scenes"
E, NU, RHO, DT = 5e4, 0.3, 1000.0, 1e-9


def reference_forces(rest: np.ndarray, tets: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """f_a = -V R sigma g_a per element (Mueller & Gross 2004 in stress form), R the proper
    rotation maximizing trace(R^T F): U V^T with the smallest singular direction flipped when
    det F < 0 (McAdams et al. 2011). Returns the nodal forces and det F per element."""
    lam, mu = E * NU / ((1 + NU) * (1 - 2 * NU)), E / (2 * (1 + NU))
    dm = np.stack([rest[tets[:, k]] - rest[tets[:, 0]] for k in (1, 2, 3)], axis=2)
    ds = np.stack([x[tets[:, k]] - x[tets[:, 0]] for k in (1, 2, 3)], axis=2)
    bm, vol = np.linalg.inv(dm), np.linalg.det(dm) / 6
    f = ds @ bm
    u, _, vt = np.linalg.svd(f)
    u[:, :, 2] *= np.sign(np.linalg.det(u @ vt))[:, None]  # numpy sorts: column 2 is the smallest
    r = u @ vt
    g = np.einsum("eki,ekj->eij", r, f)
    eps = 0.5 * (g + g.transpose(0, 2, 1)) - np.eye(3)
    sigma = 2 * mu * eps + lam * np.trace(eps, axis1=1, axis2=2)[:, None, None] * np.eye(3)
    p = vol[:, None, None] * (r @ sigma)
    grads = np.concatenate([-bm.sum(axis=1, keepdims=True), bm], axis=1)  # rows g_a
    out = np.zeros_like(x)
    for a in range(4):
        np.add.at(out, tets[:, a], -np.einsum("eij,ej->ei", p, grads[:, a]))
    return out, np.linalg.det(f)


def random_rotation(rng) -> np.ndarray:
    q = rng.standard_normal(4)
    x, y, z, s = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - s * z), 2 * (x * z + s * y)],
                     [2 * (x * y + s * z), 1 - 2 * (x * x + z * z), 2 * (y * z - s * x)],
                     [2 * (x * z - s * y), 2 * (y * z + s * x), 1 - 2 * (x * x + y * y)]]), np.array([x, y, z, s])


def force_probe():
    """The sample scenes' hand set up so that one step reads its elastic forces (module docstring):
    rest nodes, tets, the simulation, the lumped masses and the handle's centre."""
    sc = scenes.load(SAMPLES / "hand_wave.json")
    scenes.load_hand_geometry(sc)
    model = native.HandModel(sc.nodes, sc.tets, palm_seed=sc.palm_seed(), handle_radius=0.03, young_modulus=E,
                             poisson_ratio=NU, density=RHO, rayleigh_alpha=0.0, rayleigh_beta=0.0,
                             gravity=[0.0, 0.0, 0.0], dt=DT, spring_stiffness=1e-9, spring_damping=0.0)
    return sc.nodes, sc.tets, native.HandSimulation(model), model.lumped_masses(), np.array(model.info()["handle_com"])


def forces_at(probe, x, q):
    """The engine's elastic forces at x (handle turned to q) and the reference's, with det F."""
    rest, tets, sim, masses, com = probe
    # no reset: the element rotations of the previous state are the warm starts, as after a teleport
    sim.set_state(x, np.zeros_like(x), handle_position=com, handle_quaternion=q,
                  handle_velocity=np.zeros(3), handle_angular_velocity=np.zeros(3))
    sim.set_device(enabled=False)
    sim.step()
    return masses[:, None] * sim.velocities() / DT, *reference_forces(rest, tets, x)


def test_elastic_forces_after_a_jump_to_a_rotated_noisy_state_match_numpy():
    probe = force_probe()
    rest, com = probe[0], probe[4]
    rng = np.random.default_rng(37)
    inverted = 0
    for trial in range(16):
        rot, q = random_rotation(rng)
        x = com + (rest - com) @ rot.T + 1e-3 * rng.standard_normal(rest.shape)
        engine, expected, det = forces_at(probe, x, q)
        inverted += int((det <= 0).sum())
        scale = np.abs(expected).max()
        assert np.abs(engine - expected).max() < 1e-7 * scale, f"trial {trial}"
    assert inverted > 100  # inverted elements were among them


def random_large_deformation(rng) -> np.ndarray:
    """U diag(s) V^T with stretches s log-uniform in [0.2, 3] and U, V random rotations; in a
    third of the draws one stretch is negated, so every element is inverted."""
    s = np.exp(rng.uniform(np.log(0.2), np.log(3.0), 3))
    if rng.uniform() < 1 / 3:
        s[rng.integers(3)] *= -1
    return random_rotation(rng)[0] @ np.diag(s) @ random_rotation(rng)[0].T


def test_elastic_forces_under_large_deformations_match_numpy():
    """Thousands of elements in large deformations, stretched and squashed up to 3x and 5x in
    random directions, turned anywhere, a third of them inverted: 48 states of the 2468-tet hand,
    each a random deformation of the whole hand with 1 mm of noise, warm-started from the last."""
    probe = force_probe()
    rest, com = probe[0], probe[4]
    rng = np.random.default_rng(2)
    inverted = elements = 0
    for trial in range(48):
        x = com + (rest - com) @ random_large_deformation(rng).T + 1e-3 * rng.standard_normal(rest.shape)
        engine, expected, det = forces_at(probe, x, [0, 0, 0, 1])
        inverted += int((det <= 0).sum())
        elements += len(det)
        assert np.abs(engine - expected).max() < 1e-7 * np.abs(expected).max(), f"trial {trial}"
    assert elements > 100000 and inverted > 20000
