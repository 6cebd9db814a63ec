"""The skeleton of many handles (issue 40; docs/skeleton.md): bone capture and Eq. 3 per bone
(addon/engine/skeleton.py), the rigged procedural hand, joint layouts and tracking streams
(addon/engine/tracking.py), and the independent reference of one B-bone implicit step
(reference_skeleton.py) against today's native single-handle step."""

import json
from pathlib import Path

import numpy as np
import pytest

import reference_skeleton as ref
from haptic_hand.engine import mesh, native, tracking
from haptic_hand.engine import quaternion as quat
from haptic_hand.engine import skeleton as sk

SAMPLES = Path(sk.__file__).resolve().parent / "sample_scenes"


@pytest.fixture(scope="module")
def sample_hand():
    """The stored procedural hand tets (937 nodes) and their lumped masses."""
    stored = np.load(SAMPLES / "procedural_hand_tets.npz")
    nodes, tets = stored["nodes"], stored["tets"]
    masses = np.zeros(len(nodes))
    np.add.at(masses, tets.ravel(), np.repeat(0.25 * 1000.0 * mesh.tet_signed_volumes(nodes, tets), 4))
    return nodes, tets, masses


def bar():
    """A 6 x 3 x 3 cm bar of 324 tets: a small rig for exact comparisons."""
    return mesh.structured_box((0.06, 0.03, 0.03), (6, 3, 3), (-0.03, -0.015, -0.015))


# --------------------------------------------------------------------------------------------
# Capture (docs/skeleton.md, Section 1)
# --------------------------------------------------------------------------------------------


def test_segment_distance_is_to_the_segment_and_a_zero_length_bone_is_a_sphere():
    p = np.array([[0.0, 1.0, 0.0], [-2.0, 0.0, 0.0], [5.0, 0.0, 3.0]])
    d = sk.segment_distance(p, np.zeros(3), np.array([4.0, 0.0, 0.0]))
    assert np.allclose(d, [1.0, 2.0, np.hypot(1.0, 3.0)])
    seed = np.array([0.1, 0.2, 0.3])
    assert np.array_equal(sk.segment_distance(p, seed, seed.copy()), np.linalg.norm(p - seed, axis=1))


def line_of_boxes():
    nodes, _ = mesh.structured_box((0.08, 0.02, 0.02), (8, 2, 2), (0.0, -0.01, -0.01))
    return nodes


def test_nearest_bone_wins_and_ties_go_to_the_bone_listed_first():
    nodes = line_of_boxes()
    a = sk.Bone("a", None, np.array([0.0, 0, 0]), np.array([0.03, 0, 0]), 0.0125)
    b = sk.Bone("b", "a", np.array([0.05, 0, 0]), np.array([0.08, 0, 0]), 0.0125)
    owner = sk.Skeleton([a, b]).capture(nodes)
    x, held = nodes[:, 0], owner >= 0
    assert (owner[np.abs(nodes[:, 1] * nodes[:, 2]) > 0] == -1).all()  # the edges, 14 mm off the axis
    assert (owner[held & (x < 0.04 - 1e-9)] == 0).all() and (owner[held & (x > 0.04 + 1e-9)] == 1).all()
    assert (owner[held & np.isclose(x, 0.04)] == 0).all() and (held & np.isclose(x, 0.04)).any()  # a tie
    # a node in no capsule stays flesh
    owner = sk.Skeleton([a, sk.Bone("b", "a", b.head, b.tail, 0.005)]).capture(nodes)
    assert (owner[x > 0.045] != 0).all() and (owner == -1).any()


def test_explicit_node_sets_win_over_capsules():
    nodes = line_of_boxes()
    group = np.flatnonzero(nodes[:, 0] <= 0.011)
    a = sk.Bone("a", None, np.array([0.0, 0, 0]), np.array([0.08, 0, 0]), 0.0125)
    b = sk.Bone("b", "a", np.zeros(3), np.zeros(3), 0.0, nodes=group)
    owner = sk.Skeleton([a, b]).capture(nodes)
    assert np.array_equal(np.flatnonzero(owner == 1), group)
    assert (owner[(owner != 1) & (np.abs(nodes[:, 1] * nodes[:, 2]) == 0)] == 0).all()


@pytest.mark.parametrize("case, message", [
    ("few", "bone 'tip': its capsule of radius 0.001 m captures 0 node(s) of its own; a rigid bone needs at least 4"),
    ("twice", "node 0 is in the vertex groups of both 'a' and 'b'; a node belongs to at most one bone"),
    ("all", "the bones capture all 81 nodes, so nothing of the hand is soft"),
    ("range", "bone 'b': node 999 of its vertex group is not a tet node (0..80)"),
    ("parent", "bone 'b' has parent 'nope', which is not a bone of the skeleton"),
    ("cycle", "is its own ancestor: the parents must form a tree"),
    ("radius", "bone 'b' has capsule radius 0.0 m and no vertex group"),
    ("names", "two bones are named 'a'"),
    ("group", "bone 'b': its vertex group holds 2 node(s) of its own"),
])
def test_bad_skeletons_are_refused_with_the_bone_and_the_fix(case, message):
    nodes = line_of_boxes()
    o, e = np.zeros(3), np.array([0.08, 0, 0])
    a = sk.Bone("a", None, o, e, 0.012)
    bones = {
        "few": [a, sk.Bone("tip", "a", np.array([0.2, 0, 0]), np.array([0.3, 0, 0]), 0.001)],
        "twice": [sk.Bone("a", None, o, o, 0, nodes=np.arange(6)), sk.Bone("b", "a", o, o, 0, nodes=np.arange(4) * 2)],
        "all": [sk.Bone("a", None, o, e, 1.0)],
        "range": [a, sk.Bone("b", "a", o, o, 0, nodes=np.array([1, 999]))],
        "parent": [a, sk.Bone("b", "nope", o, e, 0.01)],
        "cycle": [sk.Bone("a", "b", o, e, 0.01), sk.Bone("b", "a", o, e, 0.01)],
        "radius": [a, sk.Bone("b", "a", o, e, 0.0)],
        "names": [a, sk.Bone("a", None, o, e, 0.01)],
        "group": [a, sk.Bone("b", "a", o, o, 0, nodes=np.array([1, 2]))],
    }[case]
    with pytest.raises(sk.SkeletonError, match=message.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")):
        sk.Skeleton(bones).capture(nodes)


def test_collinear_nodes_are_refused():
    nodes = line_of_boxes()
    on_axis = np.flatnonzero((np.abs(nodes[:, 1]) < 1e-12) & (np.abs(nodes[:, 2]) < 1e-12))
    skel = sk.Skeleton([sk.Bone("a", None, np.zeros(3), np.zeros(3), 0, nodes=on_axis)])
    with pytest.raises(sk.SkeletonError, match="bone 'a': its 9 nodes lie on a line"):
        skel.bodies(nodes, np.ones(len(nodes)))


def test_one_bone_is_the_palm_handle(sample_hand):
    """The zero-length bone at the seed captures the native handle's nodes, in its order, and
    Eq. 3 gives its mass, centre and inertia (the native ones, from the native lumped masses)."""
    nodes, tets, _ = sample_hand
    seed, radius = mesh.procedural_hand_palm_seed(), 0.03
    model = native.HandModel(nodes, tets, palm_seed=seed, handle_radius=radius)
    skel = sk.palm_handle_skeleton(seed, radius)
    (body,) = skel.bodies(nodes, model.lumped_masses())
    info = model.info()
    assert np.array_equal(body.nodes, model.handle_nodes())
    assert body.mass == pytest.approx(info["handle_mass"], rel=1e-14)
    assert np.allclose(body.com, info["handle_com"], rtol=0, atol=1e-15)
    assert np.allclose(body.inertia, info["handle_inertia"], rtol=1e-12, atol=0)


# --------------------------------------------------------------------------------------------
# The rigged procedural hand (docs/skeleton.md, Section 9)
# --------------------------------------------------------------------------------------------


def test_procedural_rig_has_sixteen_bones_in_a_tree():
    skel = sk.procedural_hand_skeleton()
    assert len(skel) == 16 and skel.names[0] == "palm" and skel.parents[0] == -1
    for digit in sk.DIGITS:
        chain = [skel.index(f"{digit}_{k}") for k in (1, 2, 3)]
        assert skel.parents[chain[0]] == 0 and list(skel.parents[chain[1:]]) == chain[:2]
        for parent, child in zip(chain, chain[1:]):  # each phalanx starts where its parent ends
            assert np.allclose(skel.bones[parent].tail, skel.bones[child].head)


def test_every_procedural_bone_holds_enough_nodes_and_the_fingers_are_covered(sample_hand):
    nodes, _, masses = sample_hand
    skel = sk.procedural_hand_skeleton()
    owner = skel.capture(nodes)
    bodies = skel.bodies(nodes, masses, owner)  # raises for < 4 nodes or collinear ones
    assert min(len(b.nodes) for b in bodies) >= 8
    assert (owner < 0).sum() > 0.2 * len(nodes)  # flesh is left (docs/skeleton.md, Section 9)
    segments = dict(zip(("little", "ring", "middle", "index", "thumb"), mesh._finger_segments()))
    for digit, (root, tip, radius, _) in segments.items():
        axis = (tip - root) / np.linalg.norm(tip - root)
        outside_palm = (nodes[:, 1] > 0.045) if digit == "thumb" else (nodes[:, 2] < mesh._KNUCKLE_Z)
        finger = outside_palm & (sk.segment_distance(nodes, root, tip) <= 1.1 * radius)
        bones = [skel.index(f"{digit}_{k}") for k in (1, 2, 3)]
        assert finger.sum() > 40
        assert np.isin(owner[finger], bones).all(), f"{digit}: finger nodes left to flesh or another bone"
        along = [((nodes[owner == b] - root) @ axis).mean() for b in bones]
        assert along[0] < along[1] < along[2], f"{digit}: phalanges out of order"
        assert max((nodes[owner == bones[2]] - root) @ axis) > np.linalg.norm(tip - root)  # reaches the tip


# --------------------------------------------------------------------------------------------
# Joint layouts and tracking streams (docs/skeleton.md, Section 8)
# --------------------------------------------------------------------------------------------


def test_layouts_are_trees_and_map_onto_every_procedural_bone():
    assert len(tracking.OPENXR.joints) == 26 and len(tracking.MANO.joints) == 16
    assert tracking.OPENXR.joints[:3] == ("palm", "wrist", "thumb_metacarpal")
    assert tracking.OPENXR.joints[-1] == "little_tip" and tracking.MANO.joints[7] == "pinky1"
    for layout in (tracking.OPENXR, tracking.MANO):
        roots = [j for j, p in enumerate(layout.parents) if p < 0]
        assert [layout.joints[j] for j in roots] == ["wrist"]
        for j, p in enumerate(layout.parents):  # every chain ends at the root
            seen = {j}
            while p >= 0:
                assert p not in seen
                seen.add(p)
                p = layout.parents[p]
        skel = sk.procedural_hand_skeleton()
        driven = tracking.check_map(layout, skel, tracking.PROCEDURAL_MAPS[layout.name])
        assert sorted(driven) == list(range(16))


def rest_stream(layout, times, skel=None):
    """A stream whose joints sit on the procedural bones' heads (a rest hand), moved rigidly by
    a turn about z and a shift growing with time."""
    skel = skel or sk.procedural_hand_skeleton()
    joint_of = {j: b for j, b in tracking.PROCEDURAL_MAPS[layout.name].items()}
    rest_p = np.array([skel.bones[skel.index(joint_of[j])].head if j in joint_of else np.zeros(3)
                       for j in layout.joints])
    rest_q = np.tile([0.0, 0.0, 0.0, 1.0], (len(layout.joints), 1))
    ps, qs = [], []
    for t in times:
        q = quat.from_rotation_vector([0.0, 0.0, 0.3 * t])
        ps.append(rest_p @ quat.to_matrix(q).T + [0.01 * t, 0.0, 0.0])
        qs.append(np.tile(q, (len(layout.joints), 1)))
    return tracking.TrackingStream(layout, np.array(times, float), np.array(ps), np.array(qs), rest_p, rest_q)


@pytest.mark.parametrize("suffix", [".csv", ".json"])
@pytest.mark.parametrize("layout", [tracking.OPENXR, tracking.MANO])
def test_streams_round_trip(tmp_path, suffix, layout):
    stream = rest_stream(layout, [0.0, 0.5, 1.25])
    path = tmp_path / f"s{suffix}"
    tracking.write(path, stream)
    back = tracking.read(path)
    assert back.layout == layout
    for name in ("times", "positions", "quaternions", "rest_positions", "rest_quaternions"):
        assert np.allclose(getattr(back, name), getattr(stream, name), rtol=0, atol=1e-15), name
    # without a rest entry the first sample is the rest pose
    tracking.write(path, stream, with_rest=False)
    assert np.array_equal(tracking.read(path).rest_positions, tracking.read(path).positions[0])


def csv_text(rows, layout="mano", header="t,joint,x,y,z,qx,qy,qz,qw"):
    return "\n".join([f"# {tracking.FORMAT}", f"# layout: {layout}", header] + rows) + "\n"


def mano_rows(t, skip=(), extra=(), q="0,0,0,1"):
    return [f"{t},{j},0,0,0,{q}" for j in tracking.MANO.joints if j not in skip] + list(extra)


@pytest.mark.parametrize("text, message", [
    ("t,joint\n", r"s.csv:1: a CSV tracking stream starts with the line '# haptic_hand.tracking/1'"),
    (csv_text(mano_rows(0), layout="leap"), r"s.csv:2: layout 'leap' is unknown: use one of openxr, mano"),
    (csv_text(mano_rows(0), header="t,j,x"), r"s.csv:3: the header must be"),
    (csv_text(mano_rows(0, skip=("ring2",))), r"the end of the file lacks joint\(s\) ring2 of the mano layout"),
    (csv_text(mano_rows(0, extra=("0,elbow,0,0,0,0,0,0,1",))), r"s.csv:20: joint 'elbow' is not in the mano layout"),
    (csv_text(mano_rows(0, extra=("0,wrist,0,0,0,0,0,0,1",))), r"s.csv:20: joint 'wrist' appears twice at t = 0.0"),
    (csv_text(mano_rows(0, q="0,0,0,2")), r"s.csv:4: joint 'wrist' has a quaternion of norm 2: give unit quaternions"),
    (csv_text(mano_rows(0, q="0,0,nan,1")), r"s.csv:4: joint 'wrist' has a non-finite value"),
    (csv_text(mano_rows(0, q="0,0,x,1")), r"s.csv:4: joint 'wrist' has a pose .* that is not 7 numbers"),
    (csv_text(mano_rows(1) + mano_rows(0.5)), r"has time 0.5 s after 1.0 s: times must strictly increase"),
    (csv_text(["a,wrist,0,0,0,0,0,0,1"]), r"s.csv:4: time 'a' is not a number"),
    (csv_text(["0,wrist,0,0"]), r"s.csv:4: 4 fields; a row is t,joint"),
    (csv_text([]), r"the stream has no samples"),
])
def test_bad_csv_streams_are_refused_with_the_line_and_fix(tmp_path, text, message):
    path = tmp_path / "s.csv"
    path.write_text(text)
    with pytest.raises(tracking.TrackingError, match=message):
        tracking.read(path)


def json_doc(**change):
    doc = {"format": tracking.FORMAT, "layout": "mano",
           "frames": [{"t": 0.0, "poses": {j: [0, 0, 0, 0, 0, 0, 1] for j in tracking.MANO.joints}}]}
    doc.update(change)
    return json.dumps(doc)


@pytest.mark.parametrize("text, message", [
    ("{", r"s.json:1: not valid JSON"),
    (json_doc(format="other/2"), r"a JSON tracking stream is an object with \"format\": \"haptic_hand.tracking/1\""),
    (json_doc(layout=None), r"layout None is unknown"),
    (json_doc(frames={}), r"\"frames\" must be a list"),
    (json_doc(frames=[{"poses": {}}]), r"frames\[0\] must be an object with a number \"t\""),
    (json_doc(frames=[{"t": 0, "poses": {"wrist": [0, 0, 0, 0, 0, 0, 1]}}]), r"frames\[0\] lacks joint\(s\) index1"),
    (json_doc(frames=[{"t": 0, "poses": {"hip": [0] * 7}}]), r"frames\[0\].poses has joint 'hip', not in the mano"),
    (json_doc(rest={"wrist": [0, 0, 0, 1]}), r"rest: joint 'wrist' has 4 numbers; a pose is 7"),
])
def test_bad_json_streams_are_refused_with_the_frame_and_fix(tmp_path, text, message):
    path = tmp_path / "s.json"
    path.write_text(text)
    with pytest.raises(tracking.TrackingError, match=message):
        tracking.read(path)


def test_missing_or_misnamed_stream_files_are_refused(tmp_path):
    with pytest.raises(tracking.TrackingError, match="no such file"):
        tracking.read(tmp_path / "none.csv")
    with pytest.raises(tracking.TrackingError, match=r"a tracking stream is a \.csv or \.json file"):
        tracking.read(tmp_path / "s.bvh")


def test_retargeting_moves_a_rigidly_moved_hand_rigidly(sample_hand):
    nodes, _, masses = sample_hand
    skel = sk.procedural_hand_skeleton()
    coms = np.array([b.com for b in skel.bodies(nodes, masses)])
    for layout in (tracking.OPENXR, tracking.MANO):
        stream = rest_stream(layout, [0.0, 1.0, 2.0], skel)
        joint_map = tracking.PROCEDURAL_MAPS[layout.name]
        p, q = tracking.bone_targets(stream, skel, coms, joint_map, 0.0)
        assert np.allclose(p, coms, atol=1e-15) and np.allclose(q, [0, 0, 0, 1], atol=1e-15)
        p, q = tracking.bone_targets(stream, skel, coms, joint_map, 1.5)  # halfway: slerp of a rigid motion
        turn = quat.from_rotation_vector([0.0, 0.0, 0.45])
        assert np.allclose(p, coms @ quat.to_matrix(turn).T + [0.015, 0.0, 0.0], atol=1e-14)
        assert np.allclose(q, turn, atol=1e-14)


def test_retargeting_keeps_the_rigs_bone_lengths(sample_hand):
    """A tracked index finger bent at its knuckle and stretched (a longer tracked hand): the
    rig's middle and distal phalanges stay attached at their heads to the turned proximal one."""
    nodes, _, masses = sample_hand
    skel = sk.procedural_hand_skeleton()
    coms = np.array([b.com for b in skel.bodies(nodes, masses)])
    stream = rest_stream(tracking.MANO, [0.0], skel)
    bend = quat.from_rotation_vector([0.0, 0.8, 0.0])
    j1 = tracking.MANO.index("index1")
    stream.quaternions[0, j1:j1 + 3] = bend
    stream.positions[0, j1 + 1:j1 + 3] *= 1.3  # the tracked finger's proportions are not the rig's
    p, q = tracking.bone_targets(stream, skel, coms, tracking.PROCEDURAL_MAPS["mano"], 0.0)
    r = quat.to_matrix(bend)
    i1, i2 = skel.index("index_1"), skel.index("index_2")
    head1 = skel.bones[i1].head
    tail1 = head1 + r @ (skel.bones[i1].tail - head1)
    assert np.allclose(p[i1], head1 + r @ (coms[i1] - head1), atol=1e-15)
    assert np.allclose(p[i2], tail1 + r @ (coms[i2] - skel.bones[i2].head), atol=1e-15)
    assert np.allclose(p[skel.index("middle_2")], coms[skel.index("middle_2")], atol=1e-15)


# --------------------------------------------------------------------------------------------
# The reference step (tests/engine/reference_skeleton.py)
# --------------------------------------------------------------------------------------------


def perturbed(rig: ref.Rig, rng, angle=0.1) -> ref.State:
    s = ref.rest_state(rig)
    b = len(rig.bones)
    s.x = rig.rest + 1e-3 * rng.standard_normal(rig.rest.shape)
    s.v = 0.05 * rng.standard_normal(rig.rest.shape)
    s.bq = np.array([quat.from_rotation_vector(angle * rng.standard_normal(3)) for _ in range(b)])
    s.bv = 0.05 * rng.standard_normal((b, 3))
    s.bw = 0.5 * rng.standard_normal((b, 3))
    return s


def coupled_drive(state: ref.State, rng, gains) -> ref.Drive:
    b = len(state.bx)
    return ref.Drive(np.full(b, ref.COUPLED), state.bx + 0.01 * rng.standard_normal((b, 3)),
                     np.array([quat.from_rotation_vector(0.1 * rng.standard_normal(3)) for _ in range(b)]),
                     0.1 * rng.standard_normal((b, 3)), rng.standard_normal((b, 3)), np.tile(gains, (b, 1)))


def test_reference_jacobians_match_finite_differences():
    """Eq. 11 per spring, rotations as theta: central differences of the forces (Eqs. 4-5)."""
    rng = np.random.default_rng(1)
    k, d = 1e4, 10.0
    xa, va, r = rng.standard_normal((3, 5, 3)) * np.array([0.02, 0.1, 0.02])[:, None, None]
    bx, bv, bw = rng.standard_normal((3, 3)) * np.array([0.01, 0.1, 2.0])[:, None]
    bq = quat.from_rotation_vector(rng.standard_normal(3))

    def forces(xa, va, bx, bq, bv, bw):
        s = ref.springs(k, d, xa, va, r, bx, bq, bv, bw)
        return s.f_node, s.wrench

    base = ref.springs(k, d, xa, va, r, bx, bq, bv, bw)
    h = 1e-6
    for which in range(6):  # node x, node v, bone x, bone theta, bone v, bone omega
        for c in range(3):
            e = np.zeros(3)
            e[c] = h

            def moved(sign):
                args = [xa, va, bx, bq, bv, bw]
                if which < 2:
                    args[which] = args[which] + sign * e  # every node moves: compare summed wrench
                elif which == 3:
                    args[3] = quat.multiply(quat.from_rotation_vector(sign * e), bq)
                else:
                    args[{2: 2, 4: 4, 5: 5}[which]] = args[{2: 2, 4: 4, 5: 5}[which]] + sign * e
                return forces(*args)

            (fp, wp), (fm, wm) = moved(1), moved(-1)
            dfa, dw = (fp - fm) / (2 * h), (wp - wm) / (2 * h)
            if which == 0:
                assert np.allclose(dfa, base.dfa_dxa[0] * e / h, atol=1e-4)
                assert np.allclose(dw, base.dfh_dxa.sum(0)[:, c], rtol=1e-7, atol=1e-4)
            elif which == 1:
                assert np.allclose(dfa, base.dfa_dxa[1] * e / h, atol=1e-6)
                assert np.allclose(dw, base.dfh_dva.sum(0)[:, c], rtol=1e-7, atol=1e-6)
            else:
                col = {2: c, 3: 3 + c, 4: c, 5: 3 + c}[which]
                jac_a = base.dfa_dxh if which in (2, 3) else base.dfa_dvh
                jac_h = base.dfh_dxh if which in (2, 3) else base.dfh_dvh
                scale = np.abs(jac_h).max()
                assert np.allclose(dfa, jac_a[:, :, col], rtol=1e-6, atol=1e-7 * scale)
                assert np.allclose(dw, jac_h[:, col], rtol=1e-6, atol=1e-7 * scale)


def one_bone_rig(**params):
    nodes, tets = bar()
    seed, radius = np.array([0.0, 0.0, 0.0]), 0.012
    base = dict(palm_seed=seed, handle_radius=radius, young_modulus=5e4, poisson_ratio=0.3, density=1000.0,
                rayleigh_alpha=0.5, rayleigh_beta=0.01, spring_stiffness=1e4, spring_damping=10.0,
                coupling_stiffness=2e3, coupling_damping=20.0, coupling_angular_stiffness=20.0,
                coupling_angular_damping=0.2, dt=1.0 / 30.0, gravity=[0.0, 0.0, -9.81])
    base.update(params)
    model = native.HandModel(nodes, tets, **base)
    owner = sk.palm_handle_skeleton(seed, radius).capture(nodes)
    rig = ref.Rig(nodes, tets, young=base["young_modulus"], poisson=base["poisson_ratio"], density=base["density"],
                  alpha=base["rayleigh_alpha"], beta=base["rayleigh_beta"], k=base["spring_stiffness"],
                  d=base["spring_damping"], dt=base["dt"], gravity=np.array(base["gravity"]),
                  bone_nodes=[np.flatnonzero(owner == 0)])
    gains = [base[f"coupling_{g}"] for g in ("stiffness", "damping", "angular_stiffness", "angular_damping")]
    return model, rig, gains


def native_and_reference_steps(mode):
    """One step of today's native single-handle model (Schur, Cholesky) and of the reference's
    one-bone rig from the same state, where every term of Eq. 7 is active."""
    model, rig, gains = one_bone_rig()
    assert np.allclose(rig.masses, model.lumped_masses(), rtol=1e-13, atol=0)
    rng = np.random.default_rng(7)
    state = perturbed(rig, rng)
    drive = coupled_drive(state, rng, gains)
    drive.mode[:] = mode
    # The native step advances the hand by its own turn at the start-of-step angular
    # velocity and linearizes Eq. 7 about the state and velocities that turn gives (docs/maths.md,
    # "Rotation-consistent integration"); the reference takes the paper's step, linearized at the
    # start state. From a still hand (deformed, turned, driven) the two steps are the same.
    state.v[:] = 0.0
    state.bv[:] = 0.0
    state.bw[:] = 0.0
    sim = native.HandSimulation(model)
    sim.set_state(state.x, state.v, state.bx[0], state.bq[0], state.bv[0], state.bw[0])
    sim.set_device(drive.position[0], drive.quaternion[0], drive.velocity[0], drive.angular_velocity[0],
                   enabled=mode)  # 0 free, 1 coupled, 2 prescribed: the native codes
    sim.step()
    return sim, state, ref.step(rig, state, drive)


def step_differences(sim, state, after) -> dict:
    """Largest relative difference of each part of the native step from the reference's."""
    def rel(a, b):
        return np.abs(np.asarray(a) - np.asarray(b)).max() / np.abs(np.asarray(b)).max()
    h = sim.handle()
    return {"v": rel(sim.velocities(), after.v), "dx": rel(sim.positions() - state.x, after.x - state.x),
            "v_h": rel(h.velocity, after.bv[0]), "omega_h": rel(h.angular_velocity, after.bw[0]),
            "dx_h": rel(h.position - state.bx[0], after.bx[0] - state.bx[0]),
            "q_h": np.abs(h.quaternion - after.bq[0]).max()}


@pytest.mark.parametrize("mode", [ref.FREE, ref.COUPLED, ref.PRESCRIBED])
def test_reference_one_bone_matches_native_step(mode):
    """With exact polar rotations (numpy's SVD), the reference's one-bone step is today's native
    step to round-off: every convention agrees, and the native polar iteration takes its last
    step (left out, each rotation was up to ~1e-9 rad off and a free handle's angular velocity
    differed by 8e-10 relative)."""
    diff = step_differences(*native_and_reference_steps(mode))
    assert max(diff.values()) < 1e-12, diff


def test_reference_sixteen_bones_schur_equals_monolithic(sample_hand):
    """docs/skeleton.md's Schur path (forward passes only for S) equals the monolithic solve,
    16 bones of the procedural rig, every bone coupled and moving."""
    nodes, tets, masses = sample_hand
    skel = sk.procedural_hand_skeleton()
    owner = skel.capture(nodes)
    rig = ref.Rig(nodes, tets, alpha=0.5, bone_nodes=[np.flatnonzero(owner == b) for b in range(16)])
    rng = np.random.default_rng(11)
    state = perturbed(rig, rng)
    drive = coupled_drive(state, rng, [50.0, 1.0, 0.05, 0.001])
    drive.mode[3] = ref.PRESCRIBED
    drive.mode[5] = ref.FREE
    a, rhs = ref.assemble(rig, state, drive)
    mono = ref.solve_monolithic(a, rhs)
    schur = ref.solve_schur(a, rhs, 16)
    assert np.abs(schur - mono).max() < 1e-10 * np.abs(mono).max()
    assert np.abs(a @ mono - rhs).max() < 1e-12 * np.abs(rhs).max()


def test_ath_is_aht_transposed_but_for_the_damping_turn():
    """docs/skeleton.md, Section 3: per node, A_th = A_ht^T + dt^2 d [0 | [omega]x [R r]x], so
    the sparse path needs L^-1 A_ht^T and L^-1 of three angular columns per bone, not twelve."""
    model, rig, gains = one_bone_rig()
    rng = np.random.default_rng(3)
    state = perturbed(rig, rng)
    a, _ = ref.assemble(rig, state, coupled_drive(state, rng, gains))
    aht, ath = a[:6, 6:].toarray(), a[6:, :6].toarray()
    nodes = rig.bones[0].nodes
    rr = rig.bones[0].r_body @ ref.quat_matrix(state.bq[0]).T
    turn = np.zeros_like(ath)
    for i, r in zip(nodes, rr):
        turn[3 * i:3 * i + 3, 3:] = rig.dt ** 2 * rig.d * ref.skew(state.bw[0]) @ ref.skew(r)
    assert np.allclose(ath, aht.T + turn, rtol=0, atol=1e-15 * np.abs(ath).max())
    assert np.abs(turn).max() > 1e-6 * np.abs(ath).max()  # the term is there


def test_reference_hanging_two_bone_bar_bones_carry_its_weight():
    """A bar held still by two bones at its ends (prescribed at rest) settles; then the springs'
    forces on the bones add up to the flesh's weight (gravity acts on the flesh only)."""
    nodes, tets = bar()
    bones = [sk.Bone("a", None, np.array([-0.03, 0, 0]), np.array([-0.015, 0, 0]), 0.012),
             sk.Bone("b", "a", np.array([0.015, 0, 0]), np.array([0.03, 0, 0]), 0.012)]
    owner = sk.Skeleton(bones).capture(nodes)
    rig = ref.Rig(nodes, tets, alpha=2.0, bone_nodes=[np.flatnonzero(owner == b) for b in range(2)])
    state, drive = ref.rest_state(rig), ref.free_drive(2)
    drive.mode[:], drive.position[:] = ref.PRESCRIBED, state.bx
    for _ in range(25):
        state = ref.step(rig, state, drive)
    force = sum(ref.springs(rig.k, rig.d, state.x[b.nodes], state.v[b.nodes], b.r_body, state.bx[i], state.bq[i],
                            state.bv[i], state.bw[i]).wrench[:3] for i, b in enumerate(rig.bones))
    weight = rig.masses.sum() * rig.gravity
    assert np.abs(force - weight).max() < 1e-9 * np.linalg.norm(weight)
    assert np.abs(state.x - rig.rest).max() > 1e-6  # it did sag onto its springs
