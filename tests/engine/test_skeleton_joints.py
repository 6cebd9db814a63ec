"""The skeleton's ball joints (docs/skeleton.md Section 5; skeleton.joints.stiffness, .damping):
off, the step without them; on, the native step against the numpy reference's joint terms
(reference_skeleton.joint, written apart from the native code), Schur against monolithic, the
statics of a free bone hanging from its parent by its joint, and the energy of a free spinning
hand with undamped joints; the angular limits (skeleton.joints.limit_stiffness, .limit_damping;
hand.skeleton[].limits): a bone hanging past its range held back by the limit's torque, Schur
against monolithic with a limit active, off bit for bit, bad limits refused."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import reference_skeleton as ref
from haptic_hand.engine import mesh, native
from haptic_hand.engine import native_skeleton as ns
from haptic_hand.engine import quaternion as quat
from haptic_hand.engine import skeleton as sk

from test_skeleton_native import moving_hand, sixteen_bone_rig

SAMPLES = Path(sk.__file__).resolve().parent / "sample_scenes"


@pytest.fixture(scope="module")
def sample_hand():
    stored = np.load(SAMPLES / "procedural_hand_tets.npz")
    return stored["nodes"], stored["tets"]


def joint_heads(skeleton: sk.Skeleton) -> list:
    """(parent, child, the child's rest head) per bone with a parent."""
    return [(p, c, np.asarray(skeleton.bones[c].head, float)) for c, p in enumerate(skeleton.parents) if p >= 0]


def joint_gaps(model, sim) -> np.ndarray:
    """e = p_child - p_parent per joint at the current bone poses, the joint points placed from
    the bones' rest heads and rest centres of mass (bone_info)."""
    x, q, _, _ = sim.bone_states()
    coms = [model.bone_info(b)["com"] for b in range(model.n_bones)]
    out = []
    for p, c, head in joint_heads(model.skeleton):
        on_child = x[c] + quat.to_matrix(q[c]) @ (head - coms[c])
        on_parent = x[p] + quat.to_matrix(q[p]) @ (head - coms[p])
        out.append(on_child - on_parent)
    return np.array(out)


# --------------------------------------------------------------------------------------------
# Off: the step without joints
# --------------------------------------------------------------------------------------------


def test_a_root_has_no_joint_so_one_bone_with_joint_settings_steps_as_the_palm_handle():
    """One bone is a root: joint settings leave today's single-handle step bit for bit (==)."""
    nodes, tets = mesh.structured_box((0.06, 0.03, 0.03), (6, 3, 3), (-0.03, -0.015, -0.015))
    seed, radius = np.zeros(3), 0.012
    today = native.HandModel(nodes, tets, palm_seed=seed, handle_radius=radius, rayleigh_alpha=0.5)
    one = ns.SkeletonModel(nodes, tets, sk.palm_handle_skeleton(seed, radius), rayleigh_alpha=0.5,
                           joint_stiffness=1e4, joint_damping=5.0)
    sims = [native.HandSimulation(today), ns.SkeletonSimulation(one)]
    rng = np.random.default_rng(4)
    x = nodes + 1e-3 * rng.standard_normal(nodes.shape)
    v = 0.05 * rng.standard_normal(nodes.shape)
    for sim in sims:
        sim.set_state(x, v, today.info()["handle_com"], quat.from_rotation_vector([0.2, 0.1, -0.3]),
                      [0.02, 0.0, -0.01], [0.5, 1.0, -1.0])
        sim.set_device([0.002, 0.0, 0.0], [0, 0, 0, 1], [0.03, 0, 0], [0.3, 0, 0], enabled=1)
    for _ in range(6):
        for sim in sims:
            sim.step()
        assert np.array_equal(sims[0].positions(), sims[1].positions())
        assert np.array_equal(sims[0].velocities(), sims[1].velocities())


def test_the_palm_handle_model_refuses_joint_settings():
    """The palm handle is one bone, with no parent to tie: joint settings given to it are refused
    with the fix, not ignored."""
    nodes, tets = mesh.structured_box((0.06, 0.03, 0.03), (6, 3, 3), (-0.03, -0.015, -0.015))
    for field in ("joint_stiffness", "joint_damping"):
        with pytest.raises(native.InvalidInput, match="hh_model_create_skeleton"):
            native.HandModel(nodes, tets, palm_seed=np.zeros(3), handle_radius=0.012, **{field: 1.0})


def test_joints_off_sixteen_bones_is_the_reference_step_without_joint_terms(sample_hand):
    """Stiffness and damping 0 (the defaults): the 16-bone step is the reference's step with no
    joint terms, and the energies count no joint (a check that 0 means off, not a weak joint)."""
    model, rig = sixteen_bone_rig(sample_hand, joint_stiffness=0.0, joint_damping=0.0)
    state, drive = moving_hand(rig, model, np.random.default_rng(12), stretch=1e-3)
    after = ref.step(rig, state, drive, still_jacobians=True)
    sim = stepped(model, state, drive)
    assert np.abs(sim.velocities() - after.v).max() < 1e-10 * np.abs(after.v).max()
    assert np.abs(sim.bone_states()[3] - after.bw).max() < 1e-10 * np.abs(after.bw).max()


# --------------------------------------------------------------------------------------------
# On: the native step against the reference's joint terms
# --------------------------------------------------------------------------------------------


def stepped(model, state, drive, monolithic=False):
    sim = ns.SkeletonSimulation(model)
    sim.set_state(state.x, state.v)
    sim.set_bone_states(state.bx, state.bq, state.bv, state.bw)
    sim.set_bone_targets(drive.mode, drive.position, drive.quaternion, drive.velocity, drive.angular_velocity)
    sim.step(monolithic=monolithic)
    return sim


def test_reference_joint_jacobians_match_finite_differences():
    """The reference's own joint blocks against central differences of its wrenches (so the
    native comparison below compares two checked derivations)."""
    rng = np.random.default_rng(8)
    ends = [[0.02 * rng.standard_normal(3), quat.from_rotation_vector(0.5 * rng.standard_normal(3)),
             0.1 * rng.standard_normal(3), 2.0 * rng.standard_normal(3), 0.02 * rng.standard_normal(3)]
            for _ in range(2)]
    k, d = 3e3, 7.0
    _, dx, dv = ref.joint(k, d, *ends)
    worst = 0.0
    for t in range(2):
        for c in range(12):
            h = 1e-7 if c < 6 else 1e-6

            def moved(sign):
                e = [list(end) for end in ends]
                u = np.zeros(3)
                u[c % 3] = sign * h
                if c < 3:
                    e[t][0] = e[t][0] + u
                elif c < 6:
                    e[t][1] = quat.multiply(quat.from_rotation_vector(u), e[t][1])
                elif c < 9:
                    e[t][2] = e[t][2] + u
                else:
                    e[t][3] = e[t][3] + u
                return ref.joint(k, d, *e)[0]

            num = (moved(1) - moved(-1)) / (2 * h)
            for s in range(2):
                analytic = dx[s, t][:, c] if c < 6 else dv[s, t][:, c - 6]
                scale = np.linalg.norm(dx[s, t] if c < 6 else dv[s, t])
                worst = max(worst, np.linalg.norm(num[s] - analytic) / scale)
    print("reference joint blocks against central differences:", worst)
    assert worst < 1e-7


def test_native_sixteen_bones_with_joints_match_reference(sample_hand):
    """Joints on (k 2e3 N/m, d 3 N s/m), the moving 16-bone hand with stretched joints, one
    bone prescribed and one free: the native Schur step and its monolithic solve against the
    reference's monolithic solve of Eq. 7 with its own joint terms; Schur against monolithic."""
    model, rig = sixteen_bone_rig(sample_hand, joint_stiffness=2e3, joint_damping=3.0)
    rig.joint_k, rig.joint_d = 2e3, 3.0
    rig.joint_heads = joint_heads(model.skeleton)
    rig.__post_init__()
    assert len(rig.joints) == 15
    state, drive = moving_hand(rig, model, np.random.default_rng(11), stretch=1e-3)
    after = ref.step(rig, state, drive, still_jacobians=True)

    def rel(a, b):
        return np.abs(a - b).max() / np.abs(b).max()

    expected = (after.v, after.x - state.x, after.bx - state.bx, after.bq, after.bv, after.bw)
    results = []
    for monolithic in (False, True):
        sim = stepped(model, state, drive, monolithic)
        x, q, v, w = sim.bone_states()
        results.append((sim.velocities(), sim.positions() - state.x, x - state.bx, q, v, w))
        diffs = [rel(g, e) for g, e in zip(results[-1], expected)]
        print("with joints, relative differences from the reference:", diffs)
        assert max(diffs) < 1e-10, diffs
    schur, mono = results
    print("with joints, Schur against monolithic:", max(rel(s, m) for s, m in zip(schur, mono)))
    assert max(rel(s, m) for s, m in zip(schur, mono)) < 1e-9
    # the joints changed the step: the same step without them differs well beyond the agreement
    plain, _ = sixteen_bone_rig(sample_hand)
    free_bw = stepped(plain, state, drive).bone_states()[3]
    assert rel(free_bw, after.bw) > 1e-4


def test_compare_solvers_with_joints_sixteen_bones(sample_hand):
    """hh_compare_solvers on the 16-bone hand with joints: Schur (6B x 6B with the joints' blocks
    between parents and children) against the monolithic sparse LU, to 1e-8."""
    model, rig = sixteen_bone_rig(sample_hand, joint_stiffness=1e4, joint_damping=10.0)
    state, drive = moving_hand(rig, model, np.random.default_rng(3), stretch=1e-3)
    sim = stepped(model, state, drive)
    sim.set_bone_targets(drive.mode, drive.position, drive.quaternion, drive.velocity, drive.angular_velocity)
    assert sim.compare_solvers() < 1e-8


# --------------------------------------------------------------------------------------------
# Physics: a free bone hanging from its parent by its joint
# --------------------------------------------------------------------------------------------


def two_bone_bar(root_limits=None, child_limits=None, child_axes=None, **params):
    """An 8 x 2 x 2 cm bar along x: a root bone holding its left end, a child bone holding its
    right end (head at x = 0.01 m), flesh between them; each bone's angular limits as given."""
    nodes, tets = mesh.structured_box((0.08, 0.02, 0.02), (8, 2, 2), (-0.04, -0.01, -0.01))
    bones = sk.Skeleton([sk.Bone("root", None, np.array([-0.04, 0, 0]), np.array([-0.025, 0, 0]), 0.012,
                                 limits=root_limits),
                         sk.Bone("child", "root", np.array([0.01, 0, 0]), np.array([0.035, 0, 0]), 0.011,
                                 limits=child_limits, axes=child_axes)])
    base = dict(rayleigh_alpha=8.0, young_modulus=2e4)
    base.update(params)
    return ns.SkeletonModel(nodes, tets, bones, drive_scales=[1.0, 0.0], **base)


def hang(model, steps=200):
    """The root prescribed at its rest pose, the child free (drive_scale 0), gravity: settle."""
    sim = ns.SkeletonSimulation(model)
    p, q, _, _ = sim.bone_states()
    sim.set_bone_targets([ns.PRESCRIBED, ns.FREE], p, q)
    for _ in range(steps):
        sim.step()
    return sim


@pytest.mark.parametrize("stiffness", [3e3, 1e6])
def test_a_free_bone_hangs_from_its_parent_by_its_joint_and_its_flesh(stiffness):
    """At rest the free child bone (no weight: gravity acts on the flesh) is held by two wrenches
    only, its flesh springs' and its joint's: they cancel, force and torque, and the joint's
    force is k_joint times its gap (the gap from the bone poses, the joint points from the rest
    heads). The flesh hangs on the two bones' springs alone, so together they carry its weight
    M g; the joint carries the child's share, M g less the root's, so with the root's share along
    gravity the gap is at most M g / k_joint. And the child droops less than without the joint."""
    model = two_bone_bar(joint_stiffness=stiffness)
    sim = hang(model)
    assert np.abs(sim.velocities()).max() < 1e-6  # at rest
    gap = joint_gaps(model, sim)[0]
    x, q, _, _ = sim.bone_states()
    com = model.bone_info(1)["com"]
    lever = quat.to_matrix(q[1]) @ (np.array([0.01, 0.0, 0.0]) - com)
    joint_force = -stiffness * gap  # on the child, at rest
    joint_wrench = np.concatenate([joint_force, np.cross(lever, joint_force)])
    springs = sim.bone_wrenches()[1]
    print("child: springs' wrench", springs, "joint's", joint_wrench)
    assert np.abs(springs + joint_wrench).max() < 1e-6 * np.abs(springs).max()
    weight = model.lumped_masses().sum() * 9.81 * np.array([0.0, 0.0, -1.0])
    root = sim.bone_wrenches()[0][:3]
    assert np.linalg.norm(root + springs[:3] - weight) < 1e-6 * np.linalg.norm(weight)
    assert root @ weight > 0  # the root carries its share
    assert np.linalg.norm(gap) <= np.linalg.norm(weight) / stiffness
    assert np.linalg.norm(joint_force) > 0.05 * np.linalg.norm(weight)  # the joint does carry the child
    plain = hang(two_bone_bar())
    drop, plain_drop = com[2] - x[1][2], com[2] - plain.bone_states()[0][1][2]
    print(f"child's drop: {drop:.3g} m with the joint, {plain_drop:.3g} m without")
    assert 0 < drop < plain_drop


# --------------------------------------------------------------------------------------------
# Angular limits (skeleton.joints.limit_stiffness, .limit_damping; hand.skeleton[].limits)
# --------------------------------------------------------------------------------------------

LIMIT_Y = 0.01  # rad: the child's range about y, the axis it droops about (0.031 rad without it)


def limited_bar(**params):
    """two_bone_bar pinned at the knuckle (joints 1e6 N/m), the child's rotation about y within
    +-LIMIT_Y, x and z free, its rest axes the world's (turned axes: test_skeleton.cpp's
    joint_limit test)."""
    limits = np.array([[-np.inf, -LIMIT_Y, -np.inf], [np.inf, LIMIT_Y, np.inf]])
    return two_bone_bar(child_limits=limits, child_axes=np.eye(3), **{"joint_stiffness": 1e6, **params})


def limit_energy(k: float, qp, qc, limits: np.ndarray) -> float:
    """k/2 |overshoot|^2 of the child's rotation vector relative to its parent (world axes at
    rest), written with scipy's rotations, apart from the native code."""
    psi = Rotation.from_matrix(quat.to_matrix(qp).T @ quat.to_matrix(qc)).as_rotvec()
    over = psi - np.clip(psi, limits[0], limits[1])
    return 0.5 * k * float(over @ over)


def limit_torque(k: float, qp, qc, limits: np.ndarray) -> np.ndarray:
    """The torque on the child: minus the energy's gradient in a world-frame turn of the child
    (central differences)."""
    h, out = 1e-7, np.zeros(3)
    for i in range(3):
        turn = [quat.multiply(quat.from_rotation_vector(sgn * h * np.eye(3)[i]), qc) for sgn in (1, -1)]
        out[i] = -(limit_energy(k, qp, turn[0], limits) - limit_energy(k, qp, turn[1], limits)) / (2 * h)
    return out


def settled_droop(k_limit: float) -> float:
    """The pinned bar's free child droops about y, 0.031 rad without limits. With its range
    +-0.01 rad it settles beyond the limit by what the limit's torque needs: at rest its flesh
    springs' wrench, its joint's and the limit's torque (minus the gradient of k/2 |overshoot|^2,
    reckoned apart with scipy's rotations) cancel, and it droops less than without the limit.
    Returns the droop (rad)."""
    limits = np.array([[-np.inf, -LIMIT_Y, -np.inf], [np.inf, LIMIT_Y, np.inf]])
    model = limited_bar(joint_limit_stiffness=k_limit, joint_limit_damping=0.01)
    sim = hang(model, steps=300)
    assert np.abs(sim.velocities()).max() < 1e-6  # at rest
    x, q, _, _ = sim.bone_states()
    psi = Rotation.from_matrix(quat.to_matrix(q[0]).T @ quat.to_matrix(q[1])).as_rotvec()
    plain = hang(two_bone_bar(joint_stiffness=1e6))
    psi_plain = Rotation.from_matrix(quat.to_matrix(plain.bone_states()[1][0]).T
                                     @ quat.to_matrix(plain.bone_states()[1][1])).as_rotvec()
    print(f"k {k_limit}: droop about y {psi[1]:.4g} rad with the limit, {psi_plain[1]:.4g} without")
    assert LIMIT_Y < psi[1] < psi_plain[1]
    com = model.bone_info(1)["com"]
    lever = quat.to_matrix(q[1]) @ (np.array([0.01, 0.0, 0.0]) - com)
    joint_force = -1e6 * joint_gaps(model, sim)[0]
    torque = limit_torque(k_limit, q[0], q[1], limits)
    total = sim.bone_wrenches()[1] + np.concatenate([joint_force, np.cross(lever, joint_force) + torque])
    scale = np.abs(sim.bone_wrenches()[1][3:]).max()
    print("child: springs", sim.bone_wrenches()[1], "joint force", joint_force, "limit torque", torque)
    assert np.abs(total[3:]).max() < 1e-4 * scale
    assert np.abs(torque[1]) > 0.3 * scale  # the limit does hold the child back
    return float(psi[1])


def test_a_free_bone_hanging_past_its_limit_is_held_back_the_nearer_the_stiffer_the_limit():
    """settled_droop at two limit stiffnesses: each balance holds, and the stiffer limit holds
    the bone nearer its range."""
    soft, stiff = settled_droop(0.3), settled_droop(3.0)
    assert LIMIT_Y < stiff < soft


def test_a_limit_enters_the_step_as_the_monolithic_system_has_it():
    """The bar drooping past its limit (the limit active from the first steps): each step's
    Schur solve against the monolithic one (the limit's blocks in A_h and between the bones),
    to 1e-9 of the velocities."""
    model = limited_bar(joint_limit_stiffness=3.0, joint_limit_damping=0.01)
    sims = [ns.SkeletonSimulation(model) for _ in range(2)]
    for sim in sims:
        p, q, _, _ = sim.bone_states()
        sim.set_bone_targets([ns.PRESCRIBED, ns.FREE], p, q)
    active = 0
    for _ in range(40):
        for sim, monolithic in zip(sims, (False, True)):
            sim.step(monolithic=monolithic)
        x, q, _, _ = sims[0].bone_states()
        active += Rotation.from_matrix(quat.to_matrix(q[0]).T @ quat.to_matrix(q[1])).as_rotvec()[1] > LIMIT_Y
        scale = np.abs(sims[1].velocities()).max()
        assert np.abs(sims[0].velocities() - sims[1].velocities()).max() < 1e-9 * scale
        assert np.abs(sims[0].bone_states()[3] - sims[1].bone_states()[3]).max() < 1e-9 * max(
            np.abs(sims[1].bone_states()[3]).max(), 1e-12)
        # (the states stay together: each step starts from the same state)
        sims[1].set_state(sims[0].positions(), sims[0].velocities())
        sims[1].set_bone_states(*sims[0].bone_states())
    assert active > 20  # the limit acted through most of the run


def test_limits_off_step_as_without_limits_and_the_palm_model_refuses_them():
    """limit_stiffness and limit_damping 0 (the defaults): ranges given, the step is the one
    without them, bit for bit; the palm handle model refuses the settings (it has no parent)."""
    plain, given = hang(two_bone_bar(joint_stiffness=1e6), 20), hang(limited_bar(), 20)
    assert np.array_equal(plain.velocities(), given.velocities())
    nodes, tets = mesh.structured_box((0.06, 0.03, 0.03), (6, 3, 3), (-0.03, -0.015, -0.015))
    for field in ("joint_limit_stiffness", "joint_limit_damping"):
        with pytest.raises(native.InvalidInput, match="hh_model_create_skeleton"):
            native.HandModel(nodes, tets, palm_seed=np.zeros(3), handle_radius=0.012, **{field: 1.0})


@pytest.mark.parametrize("limits, axes, message", [
    ([[-0.1, 0.02, -0.1], [0.1, 0.1, 0.1]], None, "does not hold its rest pose"),
    ([[-0.1, np.nan, -0.1], [0.1, 0.1, 0.1]], None, "NaN angular limit"),
    ([[-4.0, -0.1, -0.1], [0.1, 0.1, 0.1]], None, "reaches a half turn"),
    ([[-0.1, -0.1, -0.1], [0.1, 0.1, 0.1]], 2 * np.eye(3), "rest axes are not a rotation"),
])
def test_bad_limits_are_refused_naming_the_bone_and_the_fix(limits, axes, message):
    with pytest.raises(native.InvalidInput, match=f"bone 'child'.*{message}"):
        two_bone_bar(child_limits=np.array(limits), child_axes=axes)
    with pytest.raises(native.InvalidInput, match="bone 'root' is a root with angular limits"):
        two_bone_bar(root_limits=np.array([[-0.1] * 3, [0.1] * 3]))


# --------------------------------------------------------------------------------------------
# Energy: a free spinning hand with undamped joints
# --------------------------------------------------------------------------------------------


def turn_trade(omega: float, dt: float, elastic: float) -> float:
    """test_dynamics.turn_trade: what a step of a turning, stretched hand may hand back from its
    stretch to its motion, (omega dt)^2 of the elastic energy."""
    return (omega * dt) ** 2 * elastic


def spin(sample_hand, stiffness: float, limit: float):
    """The free 16-bone hand spinning as the test below says, 30 steps: (model, simulation, each
    step's total energy from the start, each step's stored energy)."""
    nodes, tets = sample_hand
    rig = sk.procedural_hand_skeleton()
    if limit:
        ranges = np.array([[-1e-5] * 3, [1e-5] * 3])
        rig = sk.Skeleton([b if b.parent is None else sk.Bone(b.name, b.parent, b.head, b.tail, b.radius, b.nodes,
                                                                limits=ranges) for b in rig.bones])
    model = ns.SkeletonModel(nodes, tets, rig, gravity=[0.0, 0.0, 0.0],
                             rayleigh_alpha=0.0, rayleigh_beta=0.0, spring_damping=0.0, joint_stiffness=stiffness,
                             joint_damping=0.0, joint_limit_stiffness=limit, dt=1.0 / 30.0)
    sim = ns.SkeletonSimulation(model)
    masses = model.lumped_masses()
    w = np.array([0.0, 0.0, 3.0])
    c = masses @ nodes / masses.sum()
    sim.set_state(nodes, np.cross(w, nodes - c))
    p, q, _, _ = sim.bone_states()
    spins = np.tile(w, (16, 1))
    rng = np.random.default_rng(6)
    spins[1:] += rng.standard_normal((15, 3))
    sim.set_bone_states(p, q, np.cross(w, p - c), spins)

    def energy():
        e = sim.energies()
        return e["kinetic"] + e["elastic"] + e["spring"], e["elastic"] + e["spring"]

    energies, stored = [energy()[0]], []
    for _ in range(30):
        sim.step()
        total, potential = energy()
        energies.append(total)
        stored.append(potential)
    return model, sim, np.array(energies), np.array(stored)


@pytest.mark.parametrize("stiffness, limit", [(0.0, 0.0), (1e4, 0.0), (1e4, 0.5)])
def test_a_free_spinning_hand_with_undamped_joints_keeps_its_energy(sample_hand, stiffness, limit):
    """The 16-bone hand spinning freely at 3 rad/s about z through its centre of mass, no
    damping (flesh springs, joints, Rayleigh), no gravity, dt 1/30, the finger bones also
    spinning about their own axes at 1 rad/s so the joints stretch: as test_dynamics' free
    spinning hand, no step gains beyond the co-rotational trade of the elastic energy (the
    flesh's plus the springs' and joints'), and after 1 s at least 0.99 of the energy is left
    (the rigid spin) and the joints hold the fingers on: no joint gap beyond 1 mm. With angular
    limits of +-1e-5 rad on every finger bone (undamped, 0.5 N m/rad), which the fingers' own
    spins run past before their flesh stops them, the limits' energy counted in the springs':
    the same, and the run differs from the one without limits."""
    model, sim, energies, stored = spin(sample_hand, stiffness, limit)
    e0, gains = energies[0], np.diff(energies)
    bound = turn_trade(3.0, 1 / 30, stored.max())
    print(f"joints {stiffness:g}, limits {limit:g}: largest gain {gains.max():.3g} J against {bound:.3g} J; "
          f"E/E0 {energies[-1] / e0:.4f}")
    assert gains.max() <= bound
    assert energies[-1] / e0 >= 0.99
    if stiffness:
        assert np.linalg.norm(joint_gaps(model, sim), axis=1).max() < 1e-3
    if limit:  # the limits acted
        assert np.abs(energies - spin(sample_hand, stiffness, 0.0)[2]).max() > 1e-6 * e0
