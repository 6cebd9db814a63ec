"""A skeleton hand's haptic session from a scene through the command line (docs/haptics.md, "A
skeleton hand from a scene"): the pinch sample with the haptic loop on, the simulated glove user
pinching the soft letter, the felt wrench logged per group (the palm, the thumb, the index)."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

SAMPLES = Path(__file__).resolve().parents[2] / "addon" / "engine" / "sample_scenes"
# a glove that holds every bone where its script is: 3e4 N/m fingers and couplings (the session's
# limit), as tests/engine/test_skeleton_haptics.py found necessary (docs/haptics.md says why)
STIFF = {"mass": 1.0, "stiffness": 3e4, "damping": 300.0}
STILL = 10  # the last frames, a third of a second after the glove holds still


def sample(name: str) -> dict:
    """A sample scene with its files named by absolute paths, so that it runs from anywhere."""
    scene = json.loads((SAMPLES / f"{name}.json").read_text())
    for key in ("mesh", "tets"):
        scene["hand"][key] = str(SAMPLES / scene["hand"][key])
    return scene


def simulate(scene: dict, d: Path, name: str) -> dict:
    path = d / f"{name}.json"
    path.write_text(json.dumps(scene))
    proc = subprocess.run([sys.executable, "-m", "haptic_hand", "simulate", str(path), "--out", str(d / f"{name}.npz")],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    out = dict(np.load(d / f"{name}.npz"))
    out["stdout"] = proc.stdout
    return out


def held_still(scene: dict, rest_coms: np.ndarray, poses: np.ndarray) -> dict:
    """The same hand with nothing to touch and no haptic loop, every bone prescribed to `poses` (B, 7: centre of
    mass, quaternion; rest_coms (B, 3) at rest) from half a second on: the keys give each bone's
    head offset from rest and its turn, head = centre + R (rest head - rest centre)."""
    rest_heads = np.array([b["head"] for b in scene["hand"]["skeleton"]])
    heads = poses[:, :3] + Rotation.from_quat(poses[:, 3:]).apply(rest_heads - rest_coms)
    names = [b["name"] for b in scene["hand"]["skeleton"]]
    still = {k: v for k, v in scene.items() if k != "haptics"}
    still["bodies"] = []
    still["skeleton"] = {"drive": {"prescribed": True}, "targets": [
        {"t": 0.0, "bones": {n: {"position": [0.0, 0.0, 0.0]} for n in names}},
        {"t": 0.5, "bones": {n: {"position": list(heads[b] - rest_heads[b]), "quaternion": list(poses[b, 3:])}
                             for b, n in enumerate(names)}}]}
    return still


def test_a_pinch_felt_per_finger_is_the_fingers_contact_force(tmp_path):
    """The glove closes the thumb and the index finger 3.5 mm each onto the letter over 0.5 s and
    holds (gravity off). Settled, each proxy rests between its coupling and the bones' model, so a
    group's felt force is its bones' springs' force on the visual-loop bones. Those carry what the
    flesh holds: the push on the letter and the bending of the flesh between finger and palm. The
    second is what the same bones' poses cost with nothing held (the tare a force-sensing glove
    takes: the hand run again through `simulate`, its bones prescribed to the haptic run's final
    poses); by superposition (small strains) the rest is the finger's contact force, within 3 %."""
    scene = sample("pinch_letter")
    scene["haptics"] = {"enabled": True, "feedback": "groups", "arm": STIFF, "glove": STIFF}
    scene["coupling"] = {"stiffness": 3e4, "damping": 20.0}
    r = simulate(scene, tmp_path, "felt")
    assert list(r["haptic_group_names"]) == ["palm", "thumb", "index"]
    assert "felt per group at the end: palm" in r["stdout"]
    felt = r["haptic_group_feedback"][-STILL:, :, :3]
    contact = r["bone_contact_force"][-1]
    scale = np.linalg.norm(contact[1])
    assert scale > 1.0  # a real pinch, newtons
    # the glove holds still and so does what it feels
    assert np.abs(felt - felt[-1]).max() < 1e-3 * scale
    # gravity off and the hand at rest: the springs carry the contacts, summed over every bone
    assert np.linalg.norm(felt[-1].sum(axis=0) - contact.sum(axis=0)) < 1e-3 * scale

    tare = simulate(held_still(scene, r["bone_pose"][0, :, :3], r["bone_pose"][-1]), tmp_path, "tare")
    assert np.abs(tare["bone_pose"][-1] - r["bone_pose"][-1]).max() < 1e-9  # the same poses
    assert np.abs(tare["bone_contact_force"]).max() == 0.0  # nothing touched
    read = felt[-1] - tare["bone_wrench"][-1, :, :3]  # one bone a group
    for finger in (1, 2):
        assert np.linalg.norm(read[finger] - contact[finger]) < 0.03 * np.linalg.norm(contact[finger]), \
            (r["haptic_group_names"][finger], read[finger], contact[finger])
    assert np.linalg.norm(read[0]) < 0.03 * scale  # the palm touches nothing
