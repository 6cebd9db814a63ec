"""Offline simulation of a scene: the device trajectory drives the handle through the
virtual coupling, one implicit step per frame, everything recorded in a result file
(docs/scene_format.md describes its arrays)."""

from __future__ import annotations

import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

from . import mesh as meshing
from . import native
from . import scene as scenes

RESULT_FORMAT = "haptic_hand.result/1"
TIMING_FIELDS = ("t_assembly", "t_deformable", "t_schur", "t_total")


def text_progress(fraction: float, message: str) -> None:
    """A one-line progress bar on stderr for the command line."""
    width = 30
    filled = int(round(fraction * width))
    sys.stderr.write(f"\r[{'#' * filled}{'.' * (width - filled)}] {fraction * 100:5.1f}% {message:<40}")
    if fraction >= 1.0:
        sys.stderr.write("\n")
    sys.stderr.flush()


def run(scene: scenes.Scene, progress=None) -> dict:
    """Simulates scene.frames steps and returns the result arrays."""
    model = scenes.build_model(scene, progress=(lambda f, m: progress(0.2 * f, m)) if progress else None)
    sim = native.HandSimulation(model)
    info = model.info()
    trajectory = scene.trajectory(np.array(info["handle_com"]))
    device_on = bool(scene.data["device"]["enabled"])
    frames, dt, n = scene.frames, scene.dt, model.n_nodes

    positions = np.empty((frames + 1, n, 3))
    handle_pose = np.empty((frames + 1, 7))
    device_pose = np.empty((frames + 1, 7))
    wrench = np.empty((frames + 1, 6))
    timings = np.zeros((frames, len(TIMING_FIELDS)))
    cg_iterations = np.zeros(frames, dtype=np.int32)

    def record(k: int, t: float) -> None:
        positions[k] = sim.positions()
        h = sim.handle()
        handle_pose[k] = np.concatenate([h.position, h.quaternion])
        p, q = trajectory.pose(t)
        device_pose[k] = np.concatenate([p, q])
        f, tq = sim.coupling_wrench()
        wrench[k] = np.concatenate([f, tq])

    record(0, 0.0)
    for k in range(frames):
        t = (k + 1) * dt
        p, q = trajectory.pose(t)
        v, w = trajectory.velocity(t, dt)
        sim.set_device(p, q, v, w, enabled=device_on)
        stats = sim.step()
        timings[k] = [stats[f] for f in TIMING_FIELDS]
        cg_iterations[k] = stats["cg_iterations"]
        record(k + 1, t)
        if progress and (k % 5 == 0 or k == frames - 1):
            progress(0.2 + 0.8 * (k + 1) / frames, f"frame {k + 1}/{frames}")

    tet_index, weights = meshing.embed_points(scene.nodes, scene.tets, scene.surface_vertices)
    return {
        "format": np.array(RESULT_FORMAT),
        "scene": np.array(json.dumps(scene.data)),
        "time": np.arange(frames + 1) * dt,
        "positions": positions,
        "handle_pose": handle_pose,
        "device_pose": device_pose,
        "coupling_wrench": wrench,
        "timings": timings,
        "timing_fields": np.array(TIMING_FIELDS),
        "cg_iterations": cg_iterations,
        "rest_nodes": scene.nodes,
        "tets": scene.tets,
        "handle_nodes": model.handle_nodes(),
        "lumped_masses": model.lumped_masses(),
        "surface_faces": scene.surface_faces,
        "surface_tet_index": tet_index,
        "surface_weights": weights,
        "machine": np.array(f"{platform.machine()} {platform.processor() or ''} {platform.system()}".strip()),
    }


def write(result: dict, path: Path | str) -> Path:
    """Writes the result atomically: a failed run never leaves a half-written file behind
    and never replaces an earlier good one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial.npz")
    np.savez_compressed(tmp, **result)
    tmp.replace(path)
    return path


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    x, y, z, s = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - s * z), 2 * (x * z + s * y)],
        [2 * (x * y + s * z), 1 - 2 * (x * x + z * z), 2 * (y * z - s * x)],
        [2 * (x * z - s * y), 2 * (y * z + s * x), 1 - 2 * (x * x + y * y)],
    ])


def flesh_deformation(result: dict) -> np.ndarray:
    """Per frame, the largest distance (m) of a node from where the handle's rigid motion alone
    would carry it: how much the flesh lags, sags or bulges."""
    rest, com0 = result["rest_nodes"], result["handle_pose"][0, :3]
    out = np.empty(len(result["time"]))
    for k, pose in enumerate(result["handle_pose"]):
        rigid = pose[:3] + (rest - com0) @ rotation_matrix(pose[3:]).T
        out[k] = np.linalg.norm(result["positions"][k] - rigid, axis=1).max()
    return out


def summary(result: dict) -> str:
    t = result["timings"]
    n_frames = len(result["time"]) - 1
    travel = np.linalg.norm(result["handle_pose"][:, :3] - result["handle_pose"][0, :3], axis=1)
    force = np.linalg.norm(result["coupling_wrench"][:, :3], axis=1)
    return "\n".join([
        f"frames: {n_frames} at dt = {result['time'][1]:.4f} s ({result['time'][-1]:.2f} s simulated)",
        f"hand: {len(result['rest_nodes'])} nodes, {len(result['tets'])} tets, "
        f"{len(result['handle_nodes'])} handle nodes",
        f"handle travel: up to {travel.max() * 1000:.1f} mm from its start",
        f"flesh deformation (distance from the handle's rigid motion): up to {flesh_deformation(result).max() * 1000:.1f} mm",
        f"coupling force on handle: max {force.max():.3f} N, final {force[-1]:.3f} N",
        f"step time: mean {t[:, 3].mean() * 1e3:.2f} ms (assembly {t[:, 0].mean() * 1e3:.2f}, "
        f"deformable solves {t[:, 1].mean() * 1e3:.2f}, Schur {t[:, 2].mean() * 1e3:.3f})",
    ])
