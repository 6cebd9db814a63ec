"""A haptic session on a skeleton hand (issue 40; docs/skeleton.md, Section 6): one proxy per bone,
each coupled to its own device frame, stepped at 1 kHz against the bones' model with contacts
held; a glove of one frame per bone (the simulated glove user, an external glove), and the
feedback per bone and per group of bones. Offline, in lockstep."""

from pathlib import Path

import numpy as np
import pytest

from haptic_hand.engine import gripper, mesh, native
from haptic_hand.engine import native_session as nsess
from haptic_hand.engine import native_skeleton as ns
from haptic_hand.engine import native_world as nw
from haptic_hand.engine import skeleton as sk

SAMPLES = Path(sk.__file__).resolve().parent / "sample_scenes"
DT = 1.0 / 30.0


def gripper_world(gravity=(0.0, 0.0, 0.0), **world):
    """The two-finger gripper (a palm and two finger bones, fingers down) 1 mm above the ground,
    friction 0.5; world: more hh_world_params."""
    w = nw.World(dt=DT, gravity=list(gravity), **world)
    hand, model, nodes = gripper.add_gripper(w, gripper.GAP, 0.5, gravity)
    w.add_plane([0.0, 0.0, nodes[:, 2].min() - 0.002], [0.0, 0.0, 1.0], friction=0.5)
    return w, hand, model, nodes


def sample_hand(gravity=(0.0, 0.0, 0.0), **world):
    """The rigged procedural hand (16 bones, the stored sample tets, fingers down) in a world."""
    stored = np.load(SAMPLES / "procedural_hand_tets.npz")
    nodes, tets = stored["nodes"], stored["tets"]
    skeleton = sk.procedural_hand_skeleton()
    model = ns.SkeletonModel(nodes, tets, skeleton, dt=DT, gravity=list(gravity))
    w = nw.World(dt=DT, gravity=list(gravity), **world)
    sn, sw = nw.vertex_surface(len(nodes))
    hand = w.add_hand(model, sn, sw, mesh.tet_boundary_faces(tets), friction=0.5)
    return w, hand, model, skeleton, nodes


@pytest.mark.parametrize("digit", ["index", "middle"])
def test_a_pressed_fingertip_feels_its_contact_force(digit):
    """The 16-bone hand (gravity off) lowered 2.5 mm by a glove onto a block under one fingertip
    (1.5 mm below it), the glove holding every bone at its frame: stiff couplings (3e4 N/m, the
    session's limit) and stiff simulated fingers (3e4 N/m). Settled (1.5 s), each proxy is at rest
    between its coupling and the bones' model: each bone's felt force is its springs' force on
    the visual-loop bone. The flesh is in equilibrium, so the springs carry what the block
    pushes: summed over every bone, the felt force is the contact force; and with every bone held
    where its frame is, the flesh away from the fingertip is not strained, so the pressed
    digit's group (its three bones) feels the whole contact force (2 %) and every other group
    almost none (2 % of it). (With the table's soft simulated arm, 300 N/m, every finger pushing,
    the fingers that do not touch push through the flesh onto the one that does: the index's
    group felt 63 % of its contact force.)"""
    w, hand, model, skeleton, nodes = sample_hand(tolerance=1e-9, stall_factor=0.0, max_iterations=20000)
    owner = model.node_bones()
    tip = nodes[owner == skeleton.index(f"{digit}_3")]
    low = tip[np.argmin(tip[:, 2])]
    block, block_tets = mesh.structured_box((0.02, 0.02, 0.01), (1, 1, 1), low - [0.01, 0.01, 0.0115])
    w.add_mesh_body(nw.STATIC, block, mesh.tet_boundary_faces(block_tets), friction=0.5)
    session = nsess.NativeSession(w, hand, coupling_stiffness=3e4, coupling_damping=20.0)
    groups, names = skeleton.feedback_groups()
    session.set_feedback_groups(groups)
    p0, q0, _ = w.bone_states(hand)
    down = p0 - [0.0, 0.0, 0.0025]
    session.device_simulated_glove([0.0, 0.3, 10.0], np.stack([p0, down, down]), np.stack([q0, q0, q0]), arm_mass=1.0,
                                   arm_stiffness=3e4, arm_damping=300.0)
    session.run_offline(45)
    assert session.fetch_frame()
    felt = session.frame_bones()["feedback"][:, :3]
    per_node = w.node_contact_forces(hand)
    contact = per_node.sum(axis=0)
    assert contact[2] > 1.0  # the block pushes the fingertip up
    assert set(owner[np.abs(per_node).sum(axis=1) > 0]) == {skeleton.index(f"{digit}_3")}
    scale = np.linalg.norm(contact)
    assert np.abs(felt - w.bone_states(hand)[2][:, :3]).max() < 1e-6 * scale
    assert np.linalg.norm(felt.sum(axis=0) - contact) < 1e-6 * scale
    by_group = session.frame_groups()[:, :3]
    pressed = names.index(f"{digit}_1")
    assert np.linalg.norm(by_group[pressed] - contact) < 0.02 * scale, (by_group[pressed], contact)
    others = np.delete(by_group, pressed, axis=0)
    assert np.linalg.norm(others, axis=1).max() < 0.02 * scale


def test_group_feedback_sums_its_bones_about_its_first_frame():
    """The 16-bone hand with an external glove pushed along a wave, the wrist and the five digits
    as groups (Skeleton.feedback_groups): each group's force is its bones' sum and its torque their
    torques plus each force's moment about the group's first device frame, as numpy sums them;
    and the glove reads the feedback the frame shows."""
    w, hand, model, skeleton, _ = sample_hand(gravity=(0.0, 0.0, -9.81))
    session = nsess.NativeSession(w, hand)
    assert session.n_bones == 16
    groups, names = skeleton.feedback_groups()
    assert names == ["palm", "thumb_1", "index_1", "middle_1", "ring_1", "little_1"]
    assert groups[skeleton.index("index_3")] == 2 and groups[0] == 0
    session.set_feedback_groups(groups)
    session.device_external_frames(timeout=1.0)
    p0, q0, _ = w.bone_states(hand)
    for k in range(4):
        session.push_device_frames(p0 + [0.0, 0.004 * k, 0.0], q0)
        session.run_offline(1)
    assert session.fetch_frame()
    bones = session.frame_bones()
    sums = session.frame_groups()
    f, d = bones["feedback"], bones["devices"][:, :3]
    assert np.abs(f[:, :3]).max() > 1e-3  # the hand's weight and the wave's pull
    for g in range(len(names)):
        members = np.flatnonzero(groups == g)
        arm = d[members] - d[members[0]]
        torque = f[members, 3:].sum(axis=0) + np.cross(arm, f[members, :3]).sum(axis=0)
        assert np.allclose(sums[g, :3], f[members, :3].sum(axis=0), rtol=1e-12, atol=1e-15)
        assert np.allclose(sums[g, 3:], torque, rtol=1e-10, atol=1e-15)
    glove_bones, glove_groups, t = session.device_feedback()
    assert np.array_equal(glove_bones, f) and np.array_equal(glove_groups, sums)
    assert t == pytest.approx(w.time(), abs=1e-3)
    w0, k, held = session.bone_coupling_model()
    assert w0.shape == (96,) and k.shape == (96, 96) and held == 0
    assert np.linalg.norm(w0.reshape(16, 6)[:, :3].sum(axis=0) - model.lumped_masses().sum() * np.array([0, 0, -9.81])) \
        < 0.2 * model.lumped_masses().sum() * 9.81  # the bones carry about the hand's weight (it moves a little)


def test_a_glove_has_one_frame_per_bone_and_a_palm_session_one_frame(procedural_rig):
    w, hand, _, _ = gripper_world()
    session = nsess.NativeSession(w, hand)
    with pytest.raises(native.InvalidInput, match="this session's hand has 3 bones: give it a device of one frame per "
                                                  "bone"):
        session.device_external()
    with pytest.raises(native.InvalidInput, match="group 1 has no bone: number the groups 0 .. n - 1"):
        session.set_feedback_groups([0, 2, 2], 3)
    palm = native.HandModel(procedural_rig.nodes, procedural_rig.tets, palm_seed=procedural_rig.seed,
                            handle_radius=procedural_rig.radius)
    w1 = nw.World(dt=DT)
    sn, sw = nw.vertex_surface(len(procedural_rig.nodes))
    h1 = w1.add_hand(palm, sn, sw, mesh.tet_boundary_faces(procedural_rig.tets))
    palm_session = nsess.NativeSession(w1, h1)
    with pytest.raises(native.InvalidInput, match="the hand has one handle: give it the one-frame external device"):
        palm_session.device_external_frames()
    with pytest.raises(native.InvalidInput, match="feedback groups sum the bones of a skeleton hand"):
        palm_session.set_feedback_groups([0])


def pinch_scene(feedback: str, root_device: bool = False, **haptics) -> "scenes.Scene":
    """The pinch sample (gravity off) with the haptic loop on: the glove's root a simulated arm and
    its fingers firm (3000 N/m), or haptics' own settings."""
    import json

    from haptic_hand.engine import scene as scenes

    data = json.loads((SAMPLES / "pinch_letter.json").read_text())
    firm = {"mass": 0.2, "stiffness": 3000.0, "damping": 50.0}
    data["haptics"] = {"enabled": True, "feedback": feedback, "arm": firm, "glove": firm, **haptics}
    data["skeleton"]["root_device"] = root_device
    return scenes.from_dict(data, SAMPLES)


@pytest.mark.parametrize("feedback", ["bones", "palm"])
def test_a_scenes_glove_pushes_the_frames_it_renders_and_poses_the_others(feedback):
    """The simulated glove of a scene (engine/glove.py) pinching the letter, held still for a
    second: a frame its bone's feedback pushes is a simulated arm at rest, k (x* - x) + F = 0, so
    it sits F / k off its script (the root always; the fingers with feedback per bone); a posed
    frame (the fingers with the palm's feedback) sits on its script whatever its bone feels."""
    from haptic_hand.engine import simulate

    scene = pinch_scene(feedback)
    r = simulate.run(scene)
    k = scene.data["haptics"]["glove"]["stiffness"]
    off = r["haptic_bone_device"][-1, :, :3] - r["bone_target"][-1, :, :3]
    felt = r["haptic_bone_feedback"][-1, :, :3]
    assert np.linalg.norm(felt[1:], axis=1).min() > 1.0  # the fingers feel the pinch (and the flesh)
    pushed = [0, 1, 2] if feedback == "bones" else [0]
    for b in pushed:
        assert np.linalg.norm(off[b] - felt[b] / k) < 0.02 * np.linalg.norm(felt[b] / k) + 1e-9, b
    for b in set(range(3)) - set(pushed):
        assert np.array_equal(r["haptic_bone_device"][-1, b], r["bone_target"][-1, b]), b


def test_with_the_root_on_the_device_the_simulated_arm_on_the_wrist_feels_the_whole_hand():
    """skeleton.root_device: the simulated arm on the device trajectory is the wrist device and the
    fingers are posed on it (engine/glove.pose_fingers). Pinching the letter, held still: the arm's
    spring holds the whole hand's force, k (x* - x) + sum_b F_b = 0, so its frame sits sum F / k off
    the trajectory (the pinch's squeeze is internal to the hand: the sum is what the letter pushes
    back, near zero, while each finger feels newtons); each finger frame is the arm's frame carried
    by the finger's pose relative to the root, as the recorded scripts give it (1e-12 m and rad);
    the log holds the whole hand's force."""
    from scipy.spatial.transform import Rotation

    from haptic_hand.engine import simulate

    scene = pinch_scene("palm", root_device=True)
    r = simulate.run(scene)
    k = scene.data["haptics"]["arm"]["stiffness"]
    felt = r["haptic_bone_feedback"][-1, :, :3]
    devices = r["haptic_bone_device"][-1]
    assert np.linalg.norm(felt[1:], axis=1).min() > 1.0  # the fingers feel the pinch
    total = felt.sum(axis=0)
    assert np.linalg.norm(r["haptic"]["force"][-1] - total) < 1e-12 * (1 + np.linalg.norm(felt))
    off = devices[0, :3] - r["bone_target"][-1, 0, :3]
    # the root's own force (0.03 N) would put the arm 1e-5 m off: the sum puts it within 2 % of that
    assert np.linalg.norm(felt[0]) > 0.01 and np.linalg.norm(total) < 0.01 * np.linalg.norm(felt[0])
    assert np.linalg.norm(off - total / k) < 0.02 * np.linalg.norm(felt[0] / k), (off, total / k)
    # Each finger's pose relative to the root, from the scripts the run recorded as the bones'
    # targets (composed here with scipy, not by engine/glove): a finger's script is its animated
    # pose carried by the root's, T_root T_root,anim^-1 T_b,anim, so T_root^-1 times it is the
    # relative pose the wrist device must carry.
    root, wrist = r["bone_target"][-1, 0], Rotation.from_quat(devices[0, 3:])
    for b in (1, 2):
        target = r["bone_target"][-1, b]
        rel_p = Rotation.from_quat(root[3:]).inv().apply(target[:3] - root[:3])
        rel_q = Rotation.from_quat(root[3:]).inv() * Rotation.from_quat(target[3:])
        assert np.linalg.norm(devices[b, :3] - (devices[0, :3] + wrist.apply(rel_p))) < 1e-12, b
        assert (Rotation.from_quat(devices[b, 3:]) * (wrist * rel_q).inv()).magnitude() < 1e-12, b


@pytest.mark.parametrize("sample", ["pinch_letter", "grasp_ball"])
def test_the_samples_settle_on_the_tables_soft_glove(sample):
    """The two-finger samples with the haptic loop on and the table's glove (a relaxed finger:
    20 g at 50 N/m; the root on the simulated arm, 1 kg at 300 N/m). The fingers yield to what
    they feel, so they close on nothing; once the glove's scripts hold still, the hand does too:
    over the last third of a second every bone's springs' force on the visual-loop bone stays put,
    each proxy at rest feels it, and each frame sits F / k off its script, its arm's spring
    holding its felt force (2 % of the largest felt force). (With each bone's free-space reference continued with the
    acceleration of its last two steps, the pinch's bones' springs' force swung between 0.03 and
    11 N from frame to frame and the grasp's haptic step's force became non-finite.)"""
    import json

    from haptic_hand.engine import scene as scenes
    from haptic_hand.engine import simulate

    data = json.loads((SAMPLES / f"{sample}.json").read_text())
    data["haptics"] = {"enabled": True, "feedback": "bones"}
    scene = scenes.from_dict(data, SAMPLES)
    r = simulate.run(scene)
    h = scene.data["haptics"]
    k = np.array([h["arm"]["stiffness"]] + [h["glove"]["stiffness"]] * 2)
    wrench, felt = r["bone_wrench"][-10:, :, :3], r["haptic_bone_feedback"][-1, :, :3]
    scale = np.linalg.norm(felt, axis=1).max()
    assert scale > 0.1  # the fingers hold their flesh bent (and with gravity, the hand's weight)
    assert np.linalg.norm(wrench - wrench[-1], axis=2).max() < 0.02 * scale
    assert np.linalg.norm(felt - wrench[-1], axis=1).max() < 0.02 * scale
    off = r["haptic_bone_device"][-1, :, :3] - r["bone_target"][-1, :, :3]
    assert (np.linalg.norm(off - felt / k[:, None], axis=1) < 0.02 * scale / k).all()
