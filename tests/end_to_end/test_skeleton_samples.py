"""The skeleton sample scenes (addon/engine/sample_scenes/, written by scripts/skeleton_samples.py)
run through the command line, and do what they show (docs/skeleton.md, Section 8):

- procedural_hand_close: the 16-bone procedural hand closes by keyed targets without tearing;
  the fingers that meet the soft block stop on it, the others reach their targets, and every
  bone at rest is where its drive balances its springs (x_b = p*_b + F_b / k_b);
- grasp_ball: the two-finger hand lifts a soft ball off the ground by the palm's lift and
  holds it where the palm carries it;
- pinch_letter: the thumb and the index finger pinch a soft letter with equal and opposite
  forces (gravity off), and the letter stays put;
- pinch_letter_hand: the grasping hand's index finger and thumb (16 bones) pinch a soft letter
  between their pads: equal and opposite forces, each finger's read force its contact force;
- grasp_ball_hand: the grasping hand's index finger and thumb lift a soft ball off the ground,
  hold it by friction where the palm carries it, and drop it when they open.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bone_results import lumped_masses

SAMPLES = Path(__file__).resolve().parents[2] / "addon" / "engine" / "sample_scenes"


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """Each sample, run once through `simulate`."""
    out = {}
    d = tmp_path_factory.mktemp("samples")
    tare = json.loads((SAMPLES / "pinch_letter_hand.json").read_text())
    # the same bones' poses with nothing held: the tare a force-sensing glove takes
    tare["bodies"] = []
    for key in ("mesh", "tets"):
        tare["hand"][key] = str(SAMPLES / tare["hand"][key])
    (d / "pinch_letter_hand_tare.json").write_text(json.dumps(tare))
    for name in ("procedural_hand_close", "grasp_ball", "pinch_letter", "pinch_letter_hand", "pinch_letter_hand_tare",
                 "grasp_ball_hand"):
        scene = d / f"{name}.json" if name.endswith("_tare") else SAMPLES / f"{name}.json"
        proc = subprocess.run([sys.executable, "-m", "haptic_hand", "simulate", str(scene), "--out",
                               str(d / f"{name}.npz"), "--quiet"], capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr
        out[name] = dict(np.load(d / f"{name}.npz"))
        out[name]["stdout"] = proc.stdout
    return out


def turned(quaternions) -> np.ndarray:
    """Each quaternion's angle from the identity (degrees)."""
    return 2 * np.degrees(np.arccos(np.clip(np.abs(quaternions[..., 3]), 0, 1)))


def bone(result, name: str) -> int:
    return list(result["bone_names"]).index(name)


def test_the_procedural_hand_closes_onto_the_block_and_each_bone_rests_where_its_drive_balances(results):
    r = results["procedural_hand_close"]
    scene = json.loads(str(r["scene"]))
    assert r["inverted_tets"].max() == 0 and "WARNING" not in r["stdout"]
    # the fingers the block does not stop reach most of their keyed turn (the flesh holds them back
    # by what their drives yield)
    for free in ("thumb_3", "little_3"):
        b = bone(r, free)
        assert turned(r["bone_pose"][-1, b, 3:]) > 0.75 * turned(r["bone_target"][-1, b, 3:]), free
    # index, middle and ring press the block and stop short of their targets
    for finger in ("index", "middle", "ring"):
        bones = [bone(r, f"{finger}_{k}") for k in (1, 2, 3)]
        assert np.linalg.norm(r["bone_contact_force"][-1, bones].sum(axis=0)) > 1.0, finger
        assert turned(r["bone_pose"][-1, bones[2], 3:]) < 0.8 * turned(r["bone_target"][-1, bones[2], 3:]), finger
    # at rest, every finger bone's coupling k_b (p*_b - x_b) holds its springs' force F_b, with
    # k_b = m_b (2 pi f)^2 (docs/skeleton.md, Section 4) and m_b its nodes' lumped mass
    masses = lumped_masses(r, scene["material"]["density"])
    f = scene["skeleton"]["drive"]["frequency"]
    for b in range(1, len(r["bone_names"])):
        k = masses[r["bone_nodes"] == b].sum() * (2 * np.pi * f) ** 2
        offset = r["bone_target"][-1, b, :3] - r["bone_pose"][-1, b, :3]
        springs = r["bone_wrench"][-1, b, :3]
        assert np.linalg.norm(k * offset + springs) < 0.03 * np.linalg.norm(springs) + 1e-3, r["bone_names"][b]


def test_the_grasped_ball_rises_with_the_palm_and_stays_where_the_palm_carries_it(results):
    r = results["grasp_ball"]
    scene = json.loads(str(r["scene"]))
    lifted = round(scene["skeleton"]["targets"][-1]["t"] / scene["dt"])  # the frame the palm's lift ends
    ball = r["body_ball_positions"].mean(axis=1)
    palm = r["bone_pose"][:, 0, :3]
    lift = palm[-1, 2] - palm[0, 2]
    assert lift == pytest.approx(scene["skeleton"]["targets"][-1]["bones"]["palm"]["position"][2], abs=1e-3)
    # off the ground by about the palm's lift (the ground is where it started)
    assert abs((ball[-1, 2] - ball[0, 2]) - lift) < 0.003
    assert r["body_ball_positions"][-1][:, 2].min() - r["body_ground_plane"][2] > 0.9 * lift
    # held: from the end of the lift on, within 3 mm of where the palm carries it
    carried = ball[lifted:] - palm[lifted:]
    assert np.linalg.norm(carried - carried[0], axis=1).max() < 0.003
    # by the two fingers alone, each pressing it with the same force from its side
    thumb, index = r["bone_contact_force"][-1, bone(r, "thumb")], r["bone_contact_force"][-1, bone(r, "index")]
    assert np.linalg.norm(r["bone_contact_force"][-1, bone(r, "palm")]) == 0.0
    assert thumb[0] < -0.1 and index[0] > 0.1


def test_the_pinched_letter_is_held_between_equal_and_opposite_finger_forces(results):
    """Gravity off and the letter touched by the two fingers only: once still, the letter's
    momentum balance makes the thumb's push the index finger's, opposite, within a few %."""
    r = results["pinch_letter"]
    assert json.loads(str(r["scene"]))["gravity"] == [0.0, 0.0, 0.0]
    thumb, index = r["bone_contact_force"][-1, bone(r, "thumb")], r["bone_contact_force"][-1, bone(r, "index")]
    assert np.linalg.norm(thumb) > 1.0  # a real pinch, newtons
    assert np.linalg.norm(thumb + index) < 0.03 * np.linalg.norm(thumb)
    assert thumb[0] < 0 < index[0]  # each finger pushed back outwards by the letter
    assert np.linalg.norm(r["bone_contact_force"][-1, bone(r, "palm")]) == 0.0
    # still and in place: the letter's centre within 1 mm of its start, no longer moving
    letter = r["body_letter_positions"].mean(axis=1)
    assert np.linalg.norm(letter[-1] - letter[0]) < 0.001
    assert np.linalg.norm(letter[-1] - letter[-6]) < 1e-5


def finger(result, digit: str) -> list:
    return [bone(result, f"{digit}_{k}") for k in (1, 2, 3)]


def test_the_grasping_hand_pinches_a_letter_between_its_index_and_thumb_pads(results):
    """Gravity off and the letter touched by the index finger and the thumb only: once still, the
    letter's momentum balance makes the two fingers' pushes equal and opposite. The bones are
    prescribed, so the run with nothing held has the same poses; by superposition (small strains)
    each finger's springs' force less that tare is its contact force on the letter, within 2 %."""
    r, tare = results["pinch_letter_hand"], results["pinch_letter_hand_tare"]
    assert json.loads(str(r["scene"]))["gravity"] == [0.0, 0.0, 0.0]
    assert len(r["bone_names"]) == 16 and r["inverted_tets"].max() == 0
    contact = {d: r["bone_contact_force"][-1, finger(r, d)].sum(axis=0) for d in ("index", "thumb")}
    assert np.linalg.norm(contact["thumb"]) > 1.0  # a real pinch, newtons
    assert np.linalg.norm(contact["thumb"] + contact["index"]) < 0.03 * np.linalg.norm(contact["thumb"])
    others = [b for b in range(16) if not str(r["bone_names"][b]).startswith(("index", "thumb"))]
    assert np.abs(r["bone_contact_force"][-1, others]).max() == 0.0
    assert np.abs(tare["bone_pose"][-1] - r["bone_pose"][-1]).max() < 1e-9  # the same poses
    for digit in ("index", "thumb"):
        read = (r["bone_wrench"][-1, finger(r, digit), :3] - tare["bone_wrench"][-1, finger(r, digit), :3]).sum(axis=0)
        assert np.linalg.norm(read - contact[digit]) < 0.02 * np.linalg.norm(contact[digit]), digit
    # still: no longer moving
    letter = r["body_letter_positions"].mean(axis=1)
    assert np.linalg.norm(letter[-1] - letter[-6]) < 1e-5


def test_the_grasping_hand_lifts_a_ball_by_friction_and_opening_drops_it(results):
    """Gravity is square to the squeeze and nothing but the index finger and the thumb touches the
    ball while it is held (not the palm, not the ground): the ball's weight m g is carried by the
    two fingers' forces along the vertical, within the Coulomb cone of their squeeze (|F_up| <=
    mu |F_squeeze|). Held, it stays where the palm carries it; open, it falls free to the ground
    within sqrt(2 h / g) of the fingers' opening."""
    r = results["grasp_ball_hand"]
    scene = json.loads(str(r["scene"]))
    assert len(r["bone_names"]) == 16 and r["inverted_tets"].max() == 0 and "WARNING" not in r["stdout"]
    dt, gravity = scene["dt"], np.array(scene["gravity"])
    g = np.linalg.norm(gravity)
    up = -gravity / g
    times = [key["t"] for key in scene["skeleton"]["targets"]]
    lifted, opening, opened = (round(t / dt) for t in times[3:6])  # the keys: lifted, held until, open
    lift = np.linalg.norm(scene["skeleton"]["targets"][3]["bones"]["palm"]["position"])
    ball, palm = r["body_ball_positions"], r["bone_pose"][:, 0, :3]
    ground = r["body_ground_plane"]
    height = (ball - ground[:3]) @ ground[3:]  # each node's height above the ground
    assert np.allclose(ground[3:], up, atol=1e-6)
    assert (palm[lifted] - palm[0]) @ up == pytest.approx(lift, abs=1e-4)
    # lifted with the palm: off the ground by about the palm's lift while held
    centre = ball.mean(axis=1)
    assert abs((centre[opening] - centre[0]) @ up - lift) < 0.003
    assert height[lifted:opening + 1].min() > 0.9 * lift
    # held 2 s: within 3 mm of where the palm carries it
    assert (opening - lifted) * dt == pytest.approx(2.0)
    carried = centre[lifted:opening + 1] - palm[lifted:opening + 1]
    assert np.linalg.norm(carried - carried[0], axis=1).max() < 0.003
    # by the index finger and the thumb alone, by friction
    mass = scene["bodies"][1]["material"]["density"] * tet_volume(ball[0], r["body_ball_tets"])
    mu = np.sqrt(scene["hand"]["friction"] * scene["bodies"][1]["friction"])
    others = [b for b in range(16) if not str(r["bone_names"][b]).startswith(("index", "thumb"))]
    for k in range(lifted, opening + 1, 5):
        assert np.abs(r["bone_contact_force"][k, others]).max() == 0.0
        index, thumb = (r["bone_contact_force"][k, finger(r, d)].sum(axis=0) for d in ("index", "thumb"))
        # the ball still: the fingers take its weight (the reaction of their pushes on it)
        assert np.linalg.norm(index + thumb - mass * gravity) < 0.05 * mass * g
        squeeze = thumb - index
        squeeze -= (squeeze @ up) * up
        squeeze /= np.linalg.norm(squeeze)
        for force in (index, thumb):
            assert abs(force @ up) <= mu * abs(force @ squeeze)
        assert min(-index @ squeeze, thumb @ squeeze) > mass * g / (2 * mu)  # squeezed enough to hold it
    # open: it falls free (h = g t^2 / 2) and lands on the ground (within the 1 mm contact
    # thickness) by the time the fingers are open plus the fall time, and stays there
    fall = np.sqrt(2 * height[opening].min() / g)
    landed = opened + int(np.ceil(fall / dt)) + 1
    assert height[landed:].min(axis=1).max() < scene.get("contact", {}).get("thickness", 0.001) + 0.0005
    assert (centre[opening] - centre[-1]) @ up > 0.9 * lift


def tet_volume(nodes, tets) -> float:
    a, b, c, d = (nodes[tets[:, k]] for k in range(4))
    return float(np.abs(np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)).sum() / 6)


@pytest.mark.parametrize("name", ["grasp_ball", "pinch_letter", "pinch_letter_hand", "grasp_ball_hand"])
def test_no_frame_of_a_grasp_or_a_pinch_ends_with_the_surfaces_through_each_other(results, name):
    """Fingers closing fast on a soft object are the contact solve's hardest frames (its sweeps
    may stop short of the tolerance there): after every step every contact's signed distance
    stays positive, at most the 1 mm thickness into the layer the surfaces are kept apart by."""
    r = results[name]
    fields = [str(f) for f in r["contact_fields"]]
    closest = r["contact_stats"][:, fields.index("min_distance")]
    deepest = r["contact_stats"][:, fields.index("max_penetration")]
    touching = r["contact_stats"][:, fields.index("contacts")] > 0
    assert touching.any()
    assert closest[touching].min() > 0, closest.min()
    assert deepest.max() < 1e-3
