"""The command line as a user runs it: `python -m haptic_hand simulate | check-rig`."""

import json
import subprocess
import sys

import numpy as np
import pytest

from haptic_hand.engine import mesh


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "haptic_hand", *args], capture_output=True, text=True,
                          cwd=cwd, timeout=300)


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    """A scene on the procedural hand with its tets stored (so both runs see the same mesh)."""
    d = tmp_path_factory.mktemp("scene")
    v, f = mesh.procedural_hand()
    nodes, tets = mesh.tetrahedralize(v, f, edge_length_fac=0.1, coarsen=True, epsilon=0.002)
    np.savez(d / "hand_tets.npz", nodes=nodes, tets=tets)
    scene = {
        "format": "haptic_hand.scene/1",
        "hand": {"mesh": "procedural", "tets": "hand_tets.npz", "handle_radius": 0.03},
        "dt": 1 / 30, "frames": 15,
        "device": {"trajectory": [
            {"t": 0.0, "position": [0, 0, 0], "quaternion": [0, 0, 0, 1]},
            {"t": 0.2, "position": [0.01, 0, 0], "quaternion": [0, 0, 0, 1]}]},
    }
    (d / "scene.json").write_text(json.dumps(scene))
    return d


def test_simulate_writes_a_documented_result(scene_dir):
    out = scene_dir / "result.npz"
    proc = run_cli("simulate", str(scene_dir / "scene.json"), "--out", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    r = np.load(out)
    n = len(r["rest_nodes"])
    assert r["positions"].shape == (16, n, 3)
    assert r["handle_pose"].shape == r["device_pose"].shape == (16, 7)
    assert r["timings"].shape == (15, 4) and np.all(r["timings"][:, 3] > 0)
    # the device moved 1 cm along x; through the virtual coupling the handle followed it
    device_x = r["device_pose"][-1, 0] - r["device_pose"][0, 0]
    handle_x = r["handle_pose"][-1, 0] - r["handle_pose"][0, 0]
    assert device_x == pytest.approx(0.01, abs=1e-12)
    assert abs(handle_x - device_x) < 1e-3
    # the render surface embedded in the tets comes back at rest
    surface = mesh.interpolate_embedded(r["rest_nodes"], r["tets"], r["surface_tet_index"], r["surface_weights"])
    v, _ = mesh.procedural_hand()
    assert np.abs(surface - v).max() < 1e-9


def test_check_rig_reports_the_handle_and_the_schur_check(scene_dir):
    proc = run_cli("check-rig", str(scene_dir / "scene.json"), "--json")
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    checks = {c["name"]: c for c in report["checks"]}
    assert report["ok"]
    assert checks["handle"]["n_handle_nodes"] >= 4
    assert 0 < checks["handle"]["handle_mass"] < checks["handle"]["total_mass"]
    assert checks["schur_vs_monolithic"]["relative_difference"] < 1e-8
    readable = run_cli("check-rig", str(scene_dir / "scene.json"))
    assert "schur_vs_monolithic" in readable.stdout and "rig is ready" in readable.stdout


def test_check_rig_names_a_seed_outside_the_hand(scene_dir):
    scene = json.loads((scene_dir / "scene.json").read_text())
    scene["hand"]["palm_seed"] = [1.0, 1.0, 1.0]
    bad = scene_dir / "bad_seed.json"
    bad.write_text(json.dumps(scene))
    proc = run_cli("check-rig", str(bad))
    assert proc.returncode == 1
    assert "outside the hand" in proc.stdout and "FAIL" in proc.stdout


def test_bad_scene_fails_cleanly_and_keeps_the_earlier_result(scene_dir):
    out = scene_dir / "kept.npz"
    good = run_cli("simulate", str(scene_dir / "scene.json"), "--out", str(out), "--quiet")
    assert good.returncode == 0
    before = out.read_bytes()
    scene = json.loads((scene_dir / "scene.json").read_text())
    scene["material"] = {"young_modulus": -5}
    bad = scene_dir / "bad_material.json"
    bad.write_text(json.dumps(scene))
    proc = run_cli("simulate", str(bad), "--out", str(out), "--quiet")
    assert proc.returncode == 2
    assert "young_modulus" in proc.stderr and "Traceback" not in proc.stderr
    assert out.read_bytes() == before


def test_unknown_scene_field_is_named(scene_dir):
    bad = scene_dir / "typo.json"
    bad.write_text(json.dumps({"format": "haptic_hand.scene/1", "framez": 3}))
    proc = run_cli("simulate", str(bad), "--out", str(scene_dir / "x.npz"))
    assert proc.returncode == 2 and "framez" in proc.stderr


def test_simulate_a_scene_with_bodies(scene_dir):
    """The scene format's bodies through the command line: a soft box dropped on the ground
    beside the hand, a kinematic pusher following its script, a static wall."""
    scene = json.loads((scene_dir / "scene.json").read_text())
    scene["frames"] = 20
    scene["bodies"] = [
        {"name": "ground", "type": "plane", "point": [0, 0, -0.30], "normal": [0, 0, 1], "friction": 0.5},
        {"name": "cube", "type": "soft", "mesh": "box", "size": [0.04, 0.04, 0.04], "cells": [2, 2, 2],
         "position": [0.2, 0.0, -0.25], "material": {"young_modulus": 1e5}},
        {"name": "pusher", "type": "kinematic", "mesh": "box", "size": [0.02, 0.02, 0.02], "cells": [1, 1, 1],
         "position": [-0.2, 0.0, -0.28], "trajectory": [{"t": 0, "position": [0, 0, 0]},
                                                          {"t": 0.5, "position": [0.05, 0, 0]}]},
        {"name": "wall", "type": "static", "mesh": "box", "size": [0.01, 0.2, 0.1], "cells": [1, 1, 1],
         "position": [0.3, 0.0, -0.25]},
    ]
    path = scene_dir / "bodies.json"
    path.write_text(json.dumps(scene))
    out = scene_dir / "bodies.npz"
    proc = run_cli("simulate", str(path), "--out", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    r = np.load(out)
    assert list(r["body_names"]) == ["ground", "cube", "pusher", "wall"]
    cube = r["body_cube_positions"]
    assert cube.shape[0] == 21
    # the cube fell under gravity (0.05 m to the ground: it reaches it within 20 frames)
    assert cube[-1][:, 2].min() < cube[0][:, 2].min() - 0.01
    assert cube[-1][:, 2].min() > -0.30  # and not through the ground
    # the pusher followed its script exactly; the wall stayed
    pusher = r["body_pusher_pose"]
    assert pusher[-1, 0] - pusher[0, 0] == pytest.approx(0.05, abs=1e-12)
    assert np.array_equal(r["body_wall_pose"][-1], r["body_wall_pose"][0])
    assert r["contact_stats"].shape == (20, 6) and r["contact_stats"][:, 0].max() > 0
    assert r["visual_timings"].shape == (20, 4)


def test_a_bad_body_is_named(scene_dir):
    scene = json.loads((scene_dir / "scene.json").read_text())
    scene["bodies"] = [{"name": "blob", "type": "jelly", "mesh": "box"}]
    path = scene_dir / "bad_body.json"
    path.write_text(json.dumps(scene))
    proc = run_cli("simulate", str(path), "--out", str(scene_dir / "y.npz"))
    assert proc.returncode == 2 and "blob" in proc.stderr and "soft" in proc.stderr


@pytest.mark.parametrize("solver, words", [({"name": "lu"}, "cholesky or reused_cholesky"),
                                           ({"name": "reused_cholesky", "cg_tolerance": 2.0}, "cg_tolerance"),
                                           ({"name": "reused_cholesky", "cg_max_iterations": "many"},
                                            "cg_max_iterations"),
                                           ("reused_cholesky", "must be an object")])
def test_a_bad_body_solver_is_named(scene_dir, solver, words):
    scene = json.loads((scene_dir / "scene.json").read_text())
    scene["bodies"] = [{"name": "cube", "type": "soft", "mesh": "box", "solver": solver}]
    path = scene_dir / "bad_solver.json"
    path.write_text(json.dumps(scene))
    proc = run_cli("simulate", str(path), "--out", str(scene_dir / "z.npz"))
    assert proc.returncode == 2 and "cube" in proc.stderr and words in proc.stderr


def test_a_solver_on_a_body_that_is_not_soft_is_named(scene_dir):
    scene = json.loads((scene_dir / "scene.json").read_text())
    scene["bodies"] = [{"name": "ground", "type": "plane", "solver": {"name": "reused_cholesky"}}]
    path = scene_dir / "plane_solver.json"
    path.write_text(json.dumps(scene))
    proc = run_cli("simulate", str(path), "--out", str(scene_dir / "w.npz"))
    assert proc.returncode == 2 and "ground" in proc.stderr and "only soft bodies" in proc.stderr
