"""The native skeleton of many handles (issue 40; docs/skeleton.md): hh_model_create_skeleton,
its capture and bones, and the coupled step for B bones, against today's single-handle step
(one bone), the independent numpy reference (reference_skeleton.py, sixteen bones) and statics
(a hanging rigged hand)."""

from pathlib import Path

import numpy as np
import pytest

import reference_skeleton as ref
from haptic_hand.engine import mesh, native
from haptic_hand.engine import native_skeleton as ns
from haptic_hand.engine import quaternion as quat
from haptic_hand.engine import skeleton as sk

SAMPLES = Path(sk.__file__).resolve().parent / "sample_scenes"


@pytest.fixture(scope="module")
def sample_hand():
    stored = np.load(SAMPLES / "procedural_hand_tets.npz")
    return stored["nodes"], stored["tets"]


def bar():
    """A 6 x 3 x 3 cm bar of 324 tets."""
    return mesh.structured_box((0.06, 0.03, 0.03), (6, 3, 3), (-0.03, -0.015, -0.015))


# --------------------------------------------------------------------------------------------
# Capture and bones (docs/skeleton.md, Section 1)
# --------------------------------------------------------------------------------------------


def test_native_capture_is_the_documented_rule(sample_hand):
    """The native capture equals skeleton.py's (nearest segment among capsules, ties to the
    bone listed first, explicit sets first) on the procedural rig and with a vertex group."""
    nodes, _ = sample_hand
    skel = sk.procedural_hand_skeleton()
    owner, counts = ns.capture(nodes, skel)
    assert np.array_equal(owner, skel.capture(nodes))
    assert np.array_equal(counts, np.bincount(owner[owner >= 0], minlength=16))
    group = np.flatnonzero(nodes[:, 2] < -0.17)[:30]  # fingertips' nodes as an explicit set of the last bone
    bones = list(skel.bones)
    bones[-1] = sk.Bone(bones[-1].name, bones[-1].parent, bones[-1].head, bones[-1].tail, 0.0, nodes=group)
    explicit = sk.Skeleton(bones)
    owner, _ = ns.capture(nodes, explicit)
    assert np.array_equal(owner, explicit.capture(nodes))


@pytest.mark.parametrize("case, message", [
    ("few", "bone 'tip': its capsule of radius 0.001 m captures 0 node(s) of its own; a rigid bone needs at least 4"),
    ("twice", "node 0 is in the vertex groups of both 'a' and 'b'; a node belongs to at most one bone"),
    ("all", "the bones capture all 81 nodes, so nothing of the hand is soft"),
    ("range", "bone 'b': node 999 of its vertex group is not a tet node (0..80)"),
    ("group", "bone 'b': its vertex group holds 2 node(s) of its own"),
    ("radius", "bone 'b' has capsule radius 0"),
])
def test_native_capture_refuses_bad_skeletons_naming_the_bone(case, message):
    nodes, _ = mesh.structured_box((0.08, 0.02, 0.02), (8, 2, 2), (0.0, -0.01, -0.01))
    o, e = np.zeros(3), np.array([0.08, 0, 0])
    a = sk.Bone("a", None, o, e, 0.012)
    bones = {
        "few": [a, sk.Bone("tip", "a", np.array([0.2, 0, 0]), np.array([0.3, 0, 0]), 0.001)],
        "twice": [sk.Bone("a", None, o, o, 0, nodes=np.arange(6)), sk.Bone("b", "a", o, o, 0, nodes=np.arange(4) * 2)],
        "all": [sk.Bone("a", None, o, e, 1.0)],
        "range": [a, sk.Bone("b", "a", o, o, 0, nodes=np.array([1, 999]))],
        "group": [a, sk.Bone("b", "a", o, o, 0, nodes=np.array([1, 2]))],
        "radius": [a, sk.Bone("b", "a", o, e, 1e-3)],
    }[case]
    desc = ns._Desc(sk.Skeleton(bones))
    if case == "radius":  # (skeleton.py refuses a zero radius before the library sees it)
        desc.radii[1] = 0.0
    with pytest.raises(native.InvalidInput, match=message.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")):
        ns._capture(nodes, desc)


def test_one_bone_model_is_the_palm_handle_model(sample_hand):
    """head = tail = seed, radius = handle_radius: the same nodes in the same order, and Eq. 3
    bit for bit."""
    nodes, tets = sample_hand
    seed, radius = mesh.procedural_hand_palm_seed(), 0.03
    today = native.HandModel(nodes, tets, palm_seed=seed, handle_radius=radius)
    one = ns.SkeletonModel(nodes, tets, sk.palm_handle_skeleton(seed, radius))
    info, bone = today.info(), one.bone_info(0)
    assert one.n_bones == 1 and bone["parent"] == -1
    assert np.array_equal(one.bone_nodes(0), today.handle_nodes())
    assert np.array_equal(one.handle_nodes(), today.handle_nodes())
    assert bone["mass"] == info["handle_mass"] and np.array_equal(bone["com"], info["handle_com"])
    assert np.array_equal(bone["inertia"], np.array(info["handle_inertia"]))
    p = today.params()
    assert np.array_equal(bone["drive"], [p["coupling_stiffness"], p["coupling_damping"],
                                          p["coupling_angular_stiffness"], p["coupling_angular_damping"]])
    owner = one.node_bones()
    assert np.array_equal(np.flatnonzero(owner == 0), today.handle_nodes()) and (owner >= -1).all()


def test_bones_have_eq3_mass_and_the_drive_scales_with_them(sample_hand):
    """Eq. 3 per bone from the native lumped masses (skeleton.py's bodies), and Section 4's
    gains: k = m (2 pi f)^2, d = 2 zeta m (2 pi f), the angular ones with tr(M_q) / 3."""
    nodes, tets = sample_hand
    skel = sk.procedural_hand_skeleton()
    f, zeta = 15.0, 0.7
    scales = np.ones(16)
    scales[4] = 0.5
    model = ns.SkeletonModel(nodes, tets, skel, drive_scales=scales, drive_frequency=f, drive_damping_ratio=zeta)
    bodies = skel.bodies(nodes, model.lumped_masses())
    w = 2 * np.pi * f
    for b, body in enumerate(bodies):
        info = model.bone_info(b)
        assert np.array_equal(model.bone_nodes(b), body.nodes)
        assert info["mass"] == pytest.approx(body.mass, rel=1e-14)
        assert np.allclose(info["com"], body.com, rtol=0, atol=1e-15)
        assert np.allclose(info["inertia"], body.inertia, rtol=1e-12, atol=1e-20)
        if b == 0:
            continue
        ibar = np.trace(body.inertia) / 3
        expected = scales[b] * np.array([body.mass * w * w, 2 * zeta * body.mass * w, ibar * w * w, 2 * zeta * ibar * w])
        assert np.allclose(info["drive"], expected, rtol=1e-12, atol=0)


# --------------------------------------------------------------------------------------------
# The coupled step (docs/skeleton.md, Sections 3-4)
# --------------------------------------------------------------------------------------------


def moving_state(n, rng):
    x0 = 1e-3 * rng.standard_normal((n, 3))
    v = 0.05 * rng.standard_normal((n, 3))
    return x0, v


@pytest.mark.parametrize("solver", ["cholesky", "cg"])
@pytest.mark.parametrize("mode", [0, 1, 2])
def test_one_bone_step_is_the_palm_handle_step(mode, solver):
    """The one-bone skeleton model steps exactly as today's model (==, bit for bit) over 12
    steps from a deformed, moving, rotated, spinning state, free, coupled and prescribed."""
    nodes, tets = bar()
    seed, radius = np.zeros(3), 0.012
    params = dict(rayleigh_alpha=0.5, solver=solver, cg_tolerance=1e-10)
    today = native.HandModel(nodes, tets, palm_seed=seed, handle_radius=radius, **params)
    one = ns.SkeletonModel(nodes, tets, sk.palm_handle_skeleton(seed, radius), **params)
    sims = [native.HandSimulation(today), ns.SkeletonSimulation(one)]
    rng = np.random.default_rng(5)
    q0 = quat.from_rotation_vector([0.3, -0.2, 0.5])
    x = nodes @ quat.to_matrix(q0).T + 1e-3 * rng.standard_normal(nodes.shape)
    w = np.array([0.5, 2.0, -1.0])
    v = np.cross(w, x) + 0.05 * rng.standard_normal(nodes.shape)
    com = today.info()["handle_com"]
    for sim in sims:
        sim.set_state(x, v, com, q0, [0.02, 0.0, -0.01], w)
    for k in range(12):
        target = quat.from_rotation_vector([0.3 + 0.01 * k, -0.2, 0.5])
        for sim in sims:
            sim.set_device([0.001 * k, 0.0, 0.0], target, [0.03, 0, 0], [0.3, 0, 0], enabled=mode)
            sim.step()
        a, b = sims
        assert np.array_equal(a.positions(), b.positions()) and np.array_equal(a.velocities(), b.velocities())
        ha, hb = a.handle(), b.handle()
        for f in ("position", "quaternion", "velocity", "angular_velocity"):
            assert np.array_equal(getattr(ha, f), getattr(hb, f)), (k, f)
    assert np.abs(a.velocities()).max() > 0.01  # it moved


def sixteen_bone_rig(sample_hand, **params):
    nodes, tets = sample_hand
    skel = sk.procedural_hand_skeleton()
    base = dict(young_modulus=5e4, poisson_ratio=0.3, density=1000.0, rayleigh_alpha=0.5, rayleigh_beta=0.01,
                spring_stiffness=1e4, spring_damping=10.0, dt=1.0 / 30.0, gravity=[0.0, 0.0, -9.81])
    base.update(params)
    model = ns.SkeletonModel(nodes, tets, skel, **base)
    owner = model.node_bones()
    rig = ref.Rig(nodes, tets, young=base["young_modulus"], poisson=base["poisson_ratio"], density=base["density"],
                  alpha=base["rayleigh_alpha"], beta=base["rayleigh_beta"], k=base["spring_stiffness"],
                  d=base["spring_damping"], dt=base["dt"], gravity=np.array(base["gravity"]),
                  bone_nodes=[np.flatnonzero(owner == b) for b in range(16)])
    return model, rig


def point_inertias(m, r):
    return m[:, None, None] * ((r * r).sum(1)[:, None, None] * np.eye(3) - r[:, :, None] * r[:, None, :])


def moving_hand(rig, model, rng, stretch: float = 0.0):
    """The 16-bone hand deformed and moving, every finger bone turned and spinning, coupled to
    moving targets (bone 3 prescribed, bone 5 free), not turning as a whole (the native step's
    frame is then the identity: reference_skeleton.assemble's still_jacobians); `stretch` (m)
    moves the bones off their rest centres at random (their joints stretched)."""
    b = 16
    state = ref.rest_state(rig)
    state.x = rig.rest + 5e-4 * rng.standard_normal(rig.rest.shape)
    state.v = 0.05 * rng.standard_normal(rig.rest.shape)
    if stretch:
        state.bx = state.bx + stretch * rng.standard_normal((b, 3))
    state.bq = np.array([quat.from_rotation_vector(0.05 * rng.standard_normal(3)) for _ in range(b)])
    state.bv = 0.05 * rng.standard_normal((b, 3))
    state.bw = 0.5 * rng.standard_normal((b, 3))
    state.bw[0] = 0.0
    state.v -= np.cross(hand_turn(rig, state), state.x - state.bx[0])
    assert np.linalg.norm(hand_turn(rig, state)) < 1e-12
    gains = np.array([model.bone_info(i)["drive"] for i in range(b)])
    drive = ref.Drive(np.full(b, ref.COUPLED), state.bx + 0.005 * rng.standard_normal((b, 3)),
                      np.array([quat.from_rotation_vector(0.1 * rng.standard_normal(3)) for _ in range(b)]),
                      0.1 * rng.standard_normal((b, 3)), rng.standard_normal((b, 3)), gains)
    drive.mode[3], drive.mode[5] = ref.PRESCRIBED, ref.FREE
    return state, drive


def hand_turn(rig, state):
    """The angular velocity that the hand's flesh would need, added to its velocities, to give the
    whole hand (flesh and bones) no angular momentum about the root's centre relative to the
    root's motion: zero when the hand does not turn as a whole (the native step's frame)."""
    c, vc = state.bx[0], state.bv[0]
    momentum = (rig.masses[:, None] * np.cross(state.x - c, state.v - vc)).sum(0)
    for bone, x, q, v, w in zip(rig.bones, state.bx, state.bq, state.bv, state.bw):
        turned = quat.to_matrix(q)
        momentum += bone.mass * np.cross(x - c, v - vc) + turned @ bone.inertia @ turned.T @ w
    return np.linalg.solve(point_inertias(rig.masses, state.x - c).sum(0), momentum)


def test_native_sixteen_bones_match_reference(sample_hand):
    """Sixteen bones of the procedural rig, the native Schur step (and its monolithic solve)
    against the reference's monolithic solve of Eq. 7: flesh deformed and moving, bones turned
    and moving (every finger bone spinning), coupled to moving targets, one prescribed, one free.
    The hand as a whole does not turn (its flesh carries the spinning bones' angular momentum
    back), so the native step's rigid frame is the identity and the two steps are the same step
    (reference_skeleton.assemble, still_jacobians)."""
    model, rig = sixteen_bone_rig(sample_hand)
    assert np.allclose(rig.masses, model.lumped_masses(), rtol=1e-13, atol=0)
    rng = np.random.default_rng(11)
    state, drive = moving_hand(rig, model, rng)
    after = ref.step(rig, state, drive, still_jacobians=True)

    results = []
    for monolithic in (False, True):
        sim = ns.SkeletonSimulation(model)
        sim.set_state(state.x, state.v)
        sim.set_bone_states(state.bx, state.bq, state.bv, state.bw)
        sim.set_bone_targets(drive.mode, drive.position, drive.quaternion, drive.velocity, drive.angular_velocity)
        sim.step(monolithic=monolithic)
        results.append((sim.velocities(), sim.positions(), *sim.bone_states()))

    def rel(a, b):
        return np.abs(a - b).max() / np.abs(b).max()

    expected = (after.v, after.x - state.x, after.bx - state.bx, after.bq, after.bv, after.bw)
    for v, x, bx, bq, bv, bw in results:
        got = (v, x - state.x, bx - state.bx, bq, bv, bw)
        diffs = [rel(g, e) for g, e in zip(got, expected)]
        print("relative differences from the reference:", diffs)
        assert max(diffs) < 1e-10, diffs
    schur, mono = results
    print("Schur against monolithic:", max(rel(s, m) for s, m in zip(schur, mono)))
    assert max(rel(s, m) for s, m in zip(schur, mono)) < 1e-9
    assert np.allclose(results[0][2][3], drive.position[3], rtol=0, atol=1e-15)  # the prescribed bone got there


def test_hanging_hand_bones_carry_its_weight(sample_hand):
    """The rigged hand hanging from its sixteen bones, each coupled to its rest pose: once it
    has settled, the springs' forces on the bones add up to the flesh's weight M g (gravity acts
    on the flesh only, so at rest the flesh's springs carry all of it; docs/skeleton.md, Section 1)."""
    model, _ = sixteen_bone_rig(sample_hand, rayleigh_alpha=8.0)
    sim = ns.SkeletonSimulation(model)
    p, q, _, _ = sim.bone_states()
    sim.set_bone_targets(np.full(16, ns.COUPLED), p, q)
    for _ in range(150):
        sim.step()
    weight = model.lumped_masses().sum() * np.array([0.0, 0.0, -9.81])
    force = sim.bone_wrenches()[:, :3].sum(axis=0)
    print("|sum F_b - M g| / |M g| =", np.abs(force - weight).max() / np.linalg.norm(weight))
    assert np.abs(force - weight).max() < 1e-9 * np.linalg.norm(weight), (force, weight)
    assert np.abs(sim.positions() - model.nodes).max() > 1e-5  # it sagged onto its springs
    assert np.abs(sim.bone_states()[0] - p).max() > 1e-7  # and the bones onto their couplings


def test_free_spinning_skeleton_keeps_its_linear_momentum(sample_hand):
    """No gravity, no mass damping, every bone free: the springs, the flesh's stress and the
    frame's centrifugal terms are internal, so 20 steps of a hand spinning about a free root
    (the free frame's turn about the whole hand's centre of mass) keep its linear momentum, bones
    counted (hh_linear_momentum)."""
    nodes, tets = sample_hand
    model = ns.SkeletonModel(nodes, tets, sk.procedural_hand_skeleton(), gravity=[0.0, 0.0, 0.0], rayleigh_alpha=0.0)
    sim = ns.SkeletonSimulation(model)
    w, c = np.array([1.0, -2.0, 3.0]), nodes.mean(axis=0)
    rng = np.random.default_rng(1)
    sim.set_state(nodes, np.cross(w, nodes - c) + 0.02 * rng.standard_normal(nodes.shape))
    p, q, _, _ = sim.bone_states()
    sim.set_bone_states(p, q, np.cross(w, p - c) + 0.02 * rng.standard_normal(p.shape), np.tile(w, (16, 1)))
    masses = model.lumped_masses()
    bone_masses = np.array([model.bone_info(b)["mass"] for b in range(16)])
    p0 = sim.linear_momentum()
    assert np.allclose(p0, masses @ sim.velocities() + bone_masses @ sim.bone_states()[2], rtol=1e-13, atol=0)
    for _ in range(20):
        sim.step()
    assert np.abs(sim.linear_momentum() - p0).max() < 1e-9 * np.abs(p0).max()
    assert np.abs(sim.bone_states()[3][0] - w).max() > 1e-3  # the bones moved apart from the rigid spin


# --------------------------------------------------------------------------------------------
# The 6B x 6B model of the hand alone (docs/skeleton.md, Section 6)
# --------------------------------------------------------------------------------------------


def driven_hand(sample_hand):
    """The 16-bone hand after three steps from moving bones coupled to displaced targets."""
    nodes, tets = sample_hand
    model = ns.SkeletonModel(nodes, tets, sk.procedural_hand_skeleton())
    sim = ns.SkeletonSimulation(model)
    rng = np.random.default_rng(2)
    p, q, _, _ = sim.bone_states()
    sim.set_bone_states(p, q, 0.05 * rng.standard_normal((16, 3)), 0.5 * rng.standard_normal((16, 3)))
    sim.set_bone_targets(np.full(16, ns.COUPLED), p + 0.003 * rng.standard_normal((16, 3)), q)
    for _ in range(3):
        sim.step()
    return model, sim, rng


def test_bone_model_has_second_order_error_in_every_direction(sample_hand):
    """W(h d) - (wrench0 + response h d) falls as h^2 over three decades of h, in every bone's
    six directions and in random directions of all 96 at once (the full re-solved step,
    hh_bone_response); in the directions where the step is linear (a bone's translation: its
    springs are linear in positions, and the step is one linear solve) it is round-off."""
    model, sim, rng = driven_hand(sample_hand)
    w0, r = sim.bone_linear_model()
    assert np.array_equal(w0, sim.bone_response(np.zeros(96)))
    directions = list(np.eye(96) * np.tile([0.05] * 3 + [0.5] * 3, 16))
    directions += [np.tile([0.05] * 3 + [0.5] * 3, 16) * rng.standard_normal(96) for _ in range(3)]
    scale = np.abs(w0).max()
    curved = 0
    for d in directions:
        errors = np.array([np.abs(sim.bone_response(h * d) - w0 - r @ (h * d)).max() for h in (1.0, 0.1, 0.01, 0.001)])
        if errors[0] < 1e-10 * scale:  # linear in this direction: round-off at every h
            assert errors.max() < 1e-10 * scale
            continue
        curved += 1
        slopes = np.log10(errors[:-1] / errors[1:])
        assert (np.abs(slopes - 2) < 0.05).all(), (d.nonzero(), errors, slopes)
    assert curved >= 16 * 3 + 3  # every rotation direction and the random ones are curved


def test_one_bone_model_is_the_palm_handles_model():
    nodes, tets = bar()
    seed, radius = np.zeros(3), 0.012
    today = native.HandSimulation(native.HandModel(nodes, tets, palm_seed=seed, handle_radius=radius))
    one = ns.SkeletonSimulation(ns.SkeletonModel(nodes, tets, sk.palm_handle_skeleton(seed, radius)))
    for sim in (today, one):
        sim.set_state(handle_velocity=[0.02, 0, 0], handle_angular_velocity=[0.3, -0.5, 0.2])
        sim.set_device([0.001, 0, 0], quat.from_rotation_vector([0.1, 0, 0]), enabled=1)
        sim.step()
    w0, r = today.coupling_linear_model()
    b0, br = one.bone_linear_model()
    assert np.array_equal(w0, b0) and np.array_equal(r, br)
    v = np.array([0.01, -0.02, 0.0, 0.2, 0.1, -0.3])
    assert np.array_equal(today.coupling_response(v), one.bone_response(v))


def test_compare_solvers_takes_the_skeletons_system(sample_hand):
    """hh_compare_solvers on a 16-bone model compares its B-bone Schur solve with the monolithic
    one (the step is not taken)."""
    model, sim, _ = driven_hand(sample_hand)
    before = sim.positions()
    assert sim.compare_solvers() < 1e-10
    assert np.array_equal(sim.positions(), before)


def test_compare_solvers_with_every_bone_prescribed(sample_hand):
    """Every bone of the 16-bone hand prescribed: the step's one flesh solve,
    A_t^-1 (b_t - A_th v_h) (SkeletonSystem::solve), against the monolithic solve of Eq. 7 (the
    same system, so they agree to the round-off of A_t's solve); and a step taken that way moves
    each bone to its target."""
    model, sim, rng = driven_hand(sample_hand)
    p, q, _, _ = sim.bone_states()
    target = p + 0.002 * rng.standard_normal((16, 3))
    sim.set_bone_targets(np.full(16, ns.PRESCRIBED), target, q)
    assert sim.compare_solvers() < 1e-10
    sim.step()
    assert np.allclose(sim.bone_states()[0], target, rtol=0, atol=1e-12)


def test_collinear_bone_and_world_are_refused_with_the_fix():
    nodes, tets = bar()
    on_axis = np.flatnonzero(np.isclose(nodes[:, 1], -0.005) & np.isclose(nodes[:, 2], -0.005))  # a line of 7
    o = np.zeros(3)
    skel = sk.Skeleton([sk.Bone("palm", None, o, o, 0.02), sk.Bone("axis", "palm", o, o, 0, nodes=on_axis)])
    with pytest.raises(native.InvalidInput, match=r"bone 'axis': its 7 nodes lie on a line, so its inertia is singular"):
        ns.SkeletonModel(nodes, tets, skel)
    two = sk.Skeleton([sk.Bone("a", None, np.array([-0.03, 0, 0]), np.array([-0.015, 0, 0]), 0.012),
                       sk.Bone("b", "a", np.array([0.015, 0, 0]), np.array([0.03, 0, 0]), 0.012)])
    sim = ns.SkeletonSimulation(ns.SkeletonModel(nodes, tets, two))
    with pytest.raises(native.InvalidInput, match="hh_coupling_model takes a hand with one handle; this model has 2 bones"):
        sim.coupling_model()
