"""Offline simulation of a scene: the device trajectory drives the handle through the
virtual coupling, one implicit step per frame, everything recorded in a result file
(docs/scene_format.md describes its arrays)."""

from __future__ import annotations

import json
import math
import platform
import sys
from pathlib import Path

import numpy as np

from . import bone_drive, glove, hand_integrity
from . import native_world, quaternion
from . import scene as scenes
from . import session as session_module
from .scene_world import build_world

RESULT_FORMAT = "haptic_hand.result/2"
TIMING_FIELDS = ("t_assembly", "t_deformable", "t_schur", "t_total")  # the hand's implicit step
VISUAL_TIMING_FIELDS = ("t_detection", "t_dynamics", "t_contact", "t_total")  # the whole visual step
CONTACT_FIELDS = ("contacts", "self_contacts", "max_penetration", "min_distance", "residual", "iterations")


def text_progress(fraction: float, message: str) -> None:
    """A one-line progress bar on stderr for the command line."""
    width = 30
    filled = int(round(fraction * width))
    sys.stderr.write(f"\r[{'#' * filled}{'.' * (width - filled)}] {fraction * 100:5.1f}% {message:<40}")
    if fraction >= 1.0:
        sys.stderr.write("\n")
    sys.stderr.flush()


class ScriptedInputs:
    """What drives a scene without haptics: the device trajectory, through the virtual coupling,
    applied for the step that ends at time t (kinematic bodies follow their scripts natively);
    a skeleton's bones by their targets (bone_drive), the root on the device if the scene says."""

    def __init__(self, scene: scenes.Scene, world, hand: int, model):
        self.world, self.hand = world, hand
        self.device = scene.trajectory(np.array(model.info()["handle_com"]))
        self.device_on = bool(scene.data["device"]["enabled"])
        self.bones = bone_drive.for_scene(scene, model) if scene.skeleton is not None else None

    def apply(self, t: float, dt: float):
        """Sets the inputs of the step that ends at t; returns the bones' targets (None: no skeleton)."""
        if self.bones is not None:
            return self.bones.apply(self.world, self.hand, t, dt)
        p, q = self.device.pose(t)
        v, w = self.device.velocity(t, dt)
        self.world.set_device(self.hand, p, q, v, w, enabled=self.device_on)
        return None


class BoneRecord:
    """A skeleton hand's bones frame by frame: poses and targets (centre of mass, quaternion),
    their springs' wrenches, and the contacts' push on the nodes of each bone's region (the
    bone's own nodes and the flesh nearest its segment at rest)."""

    def __init__(self, scene: scenes.Scene, model, frames: int):
        rig = scene.skeleton.skeleton
        b = len(rig)
        self.owner = model.node_bones()
        self.region = rig.regions(scene.nodes, self.owner)
        self.names, self.parents = np.array(rig.names), np.asarray(rig.parents, dtype=np.int32)
        self.pose, self.target = np.empty((frames + 1, b, 7)), np.empty((frames + 1, b, 7))
        self.wrench, self.contact = np.empty((frames + 1, b, 6)), np.empty((frames + 1, b, 3))

    def record(self, k: int, world, hand: int, targets) -> None:
        p, q, w = world.bone_states(hand)
        self.pose[k], self.wrench[k] = np.concatenate([p, q], axis=1), w
        self.target[k] = np.concatenate(targets, axis=1)
        per_node = world.node_contact_forces(hand)
        self.contact[k] = [per_node[self.region == bone].sum(axis=0) for bone in range(len(self.names))]

    def arrays(self) -> dict:
        return {"bone_names": self.names, "bone_parents": self.parents, "bone_nodes": self.owner,
                "bone_region": self.region, "bone_pose": self.pose, "bone_target": self.target,
                "bone_wrench": self.wrench, "bone_contact_force": self.contact}


class FeltRecord:
    """A skeleton hand's haptic session frame by frame: each bone's device frame (position,
    quaternion) and felt wrench, and each group's (haptics.feedback "groups"), as the frame
    after each visual step shows them (its last haptic step's)."""

    def __init__(self, scene: scenes.Scene, session, frames: int):
        b, fb = session.n_bones, scene.feedback
        self.groups = fb.group_names
        self.device, self.bones = np.empty((frames + 1, b, 7)), np.empty((frames + 1, b, 6))
        self.group = np.empty((frames + 1, len(self.groups), 6))
        self.group_of_bone = fb.group_of_bone if fb.group_of_bone is not None else np.full(b, -1, dtype=np.int32)

    def record(self, k: int, session) -> None:
        """Frame k, from the session's fetched frame."""
        frame = session.frame_bones()
        self.device[k], self.bones[k] = frame["devices"], frame["feedback"]
        self.group[k] = session.frame_groups()

    def arrays(self) -> dict:
        out = {"haptic_bone_device": self.device, "haptic_bone_feedback": self.bones}
        if self.groups:
            out.update({"haptic_group_names": np.array(self.groups), "haptic_bone_group": self.group_of_bone,
                        "haptic_group_feedback": self.group})
        return out


def run(scene: scenes.Scene, progress=None) -> dict:
    """Simulates scene.frames visual-loop steps and returns the result arrays."""
    world, hand, model, others, (tet_index, weights) = build_world(
        scene, progress=(lambda f, m: progress(0.2 * f, m)) if progress else None)
    inputs = ScriptedInputs(scene, world, hand, model)
    trajectory = inputs.device
    frames, dt, n = scene.frames, scene.dt, model.n_nodes
    haptics = None
    if scene.data["haptics"]["enabled"]:
        # the haptic loop in lockstep, in virtual time, a step at every multiple of 1/rate: its
        # log holds every haptic step
        steps = math.ceil(frames * dt * scene.data["haptics"]["rate"]) + 2
        haptics = session_module.create(world, hand, scene, log_capacity=steps)
        session_module.attach_device(haptics, scene, model)
    felt = FeltRecord(scene, haptics, frames) if haptics is not None and haptics.n_bones > 1 else None

    positions = np.empty((frames + 1, n, 3))
    handle_pose = np.empty((frames + 1, 7))
    device_pose = np.empty((frames + 1, 7))
    wrench = np.empty((frames + 1, 6))
    timings = np.zeros((frames, len(TIMING_FIELDS)))
    visual_timings = np.zeros((frames, len(VISUAL_TIMING_FIELDS)))
    contact_stats = np.zeros((frames, len(CONTACT_FIELDS)))
    cg_iterations = np.zeros(frames, dtype=np.int32)
    body_frames = {b.name: [] for b in others if b.kind != native_world.PLANE}
    bones = BoneRecord(scene, model, frames) if scene.skeleton is not None else None

    def record(k: int, t: float) -> None:
        positions[k] = world.nodes(hand)[0]
        p, q, f, tq = world.hand_state(hand)
        handle_pose[k] = np.concatenate([p, q])
        if haptics is not None:
            haptics.fetch_frame()
            device_pose[k] = np.array(haptics.frame_info.device)
            if felt is not None:
                felt.record(k, haptics)
        else:
            dp, dq = trajectory.pose(t)
            device_pose[k] = np.concatenate([dp, dq])
        wrench[k] = np.concatenate([f, tq])
        for b in others:
            if b.kind == native_world.SOFT:
                body_frames[b.name].append(world.nodes(b.index)[0])
            elif b.kind != native_world.PLANE:
                bp, bq, _, _ = world.pose(b.index)
                body_frames[b.name].append(np.concatenate([bp, bq]))

    kind = str(scene.data["haptics"]["device"]).partition(":")[0]
    read_frames = felt is not None and scene.skeleton.root_device and kind != "simulated"

    def bone_targets(t: float):
        """The bones' targets at t: with haptics, the glove's scripts (glove.py); for a device
        with no script (a playback, OpenHaptics, HID, external on the wrist), the frames it read."""
        if read_frames:
            haptics.fetch_frame()
            devices = haptics.frame_bones()["devices"]
            return devices[:, :3], devices[:, 3:]
        if haptics is not None:
            return glove.targets(inputs.bones, t)
        start = world.bone_states(hand)
        return inputs.bones.targets(t, (start[0][0], start[1][0]))

    record(0, 0.0)
    if bones is not None:
        bones.record(0, world, hand, bone_targets(0.0))
    for k in range(frames):
        t = (k + 1) * dt
        if haptics is not None:
            haptics.run_offline(1)
            vis = world.stats()
            if bones is not None:
                bones.record(k + 1, world, hand, bone_targets(t))
        else:
            targets = inputs.apply(t, dt)
            vis = world.step()
            if bones is not None:
                bones.record(k + 1, world, hand, targets)
        stats = world.hand_step_stats(hand)
        timings[k] = [stats[f] for f in TIMING_FIELDS]
        cg_iterations[k] = stats["cg_iterations"]
        visual_timings[k] = [vis[f] for f in VISUAL_TIMING_FIELDS]
        contact_stats[k] = [vis[f] for f in CONTACT_FIELDS]
        record(k + 1, t)
        if progress and (k % 5 == 0 or k == frames - 1):
            progress(0.2 + 0.8 * (k + 1) / frames, f"frame {k + 1}/{frames}")

    result = {}
    if haptics is not None:
        result["haptic"] = session_module.log_arrays(haptics.read_log())
        haptics.close()
    result.update({
        "format": np.array(RESULT_FORMAT),
        "scene": np.array(json.dumps({k: v for k, v in scene.data.items()}, default=str)),
        "time": np.arange(frames + 1) * dt,
        "positions": positions,
        "handle_pose": handle_pose,
        "device_pose": device_pose,
        "coupling_wrench": wrench,
        "timings": timings,
        "timing_fields": np.array(TIMING_FIELDS),
        "visual_timings": visual_timings,
        "visual_timing_fields": np.array(VISUAL_TIMING_FIELDS),
        "contact_stats": contact_stats,
        "contact_fields": np.array(CONTACT_FIELDS),
        "cg_iterations": cg_iterations,
        "rest_nodes": scene.nodes,
        "tets": scene.tets,
        "handle_nodes": model.handle_nodes(),
        "lumped_masses": model.lumped_masses(),
        "surface_faces": scene.surface_faces,
        "surface_tet_index": tet_index,
        "surface_weights": weights,
        "body_names": np.array([b.name for b in others]),
        "body_types": np.array([b.spec["type"] for b in others]),
        **(bones.arrays() if bones is not None else {}),
        **(felt.arrays() if felt is not None else {}),
        "machine": np.array(f"{platform.machine()} {platform.processor() or ''} {platform.system()}".strip()),
    })
    # whether the hand stayed whole: a violent input tears it or pulls the flesh off the handle
    verdict = hand_integrity.check(positions, scene.nodes, scene.tets, handle_pose, result["time"],
                                   flesh_deformation(result), skeleton=bones is not None)
    result.update({"inverted_tets": verdict["inverted_tets"], "torn_frame": np.array(verdict["torn_frame"]),
                   "strayed_frame": np.array(verdict["strayed_frame"]),
                   "warnings": np.array(verdict["warnings"], dtype=str)})
    for b in others:
        key = f"body_{b.name}"
        if b.kind == native_world.PLANE:
            result[f"{key}_plane"] = np.concatenate([b.spec["point"], b.spec["normal"]]).astype(float)
            continue
        result[f"{key}_faces"] = b.faces
        if b.kind == native_world.SOFT:
            result[f"{key}_positions"] = np.array(body_frames[b.name])
            result[f"{key}_tets"] = b.tets
            result[f"{key}_surface_tet_index"] = b.tet_index
            result[f"{key}_surface_weights"] = b.weights
        else:
            poses = np.array(body_frames[b.name])
            result[f"{key}_pose"] = poses
            # vertices in the body frame: rest vertices about the rest centre of mass
            result[f"{key}_local_vertices"] = b.vertices - poses[0, :3]
    return result


def partial_path(path: Path | str) -> Path:
    """Where write() puts the result until it is whole."""
    path = Path(path)
    return path.with_name(path.name + ".partial.npz")


def remove_partial(path: Path | str) -> None:
    """Removes a partial result left by a run that was killed (kill -9) while writing it."""
    partial_path(path).unlink(missing_ok=True)


def write(result: dict, path: Path | str) -> Path:
    """Writes the result atomically: a failed or interrupted run never leaves a half-written
    file behind and never replaces an earlier good one."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"the result path {path} is a directory: give a file name")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = partial_path(path)
    flat = {}
    for key, value in result.items():
        if isinstance(value, dict):  # the haptic log: haptic_t, haptic_force, ...
            flat.update({f"{key}_{k}": v for k, v in value.items()})
        else:
            flat[key] = value
    try:
        np.savez_compressed(tmp, **flat)
        tmp.replace(path)
    except BaseException:  # a full disk, Ctrl-C (SIGTERM too, through the command line's handler)
        tmp.unlink(missing_ok=True)
        raise
    return path


def flesh_deformation(result: dict) -> np.ndarray:
    """Per frame, the largest distance (m) of a node from where the handle's rigid motion alone
    would carry it (a skeleton's: its region's bone, BoneRecord): how much the flesh lags, sags
    or bulges."""
    rest = result["rest_nodes"]
    if "bone_pose" in result:
        poses, region = result["bone_pose"], result["bone_region"]
    else:
        poses, region = result["handle_pose"][:, None], np.zeros(len(rest), dtype=int)
    out = np.empty(len(result["time"]))
    for k, frame in enumerate(poses):
        rigid = np.empty_like(rest)
        for b, pose in enumerate(frame):
            mine = region == b
            rigid[mine] = pose[:3] + (rest[mine] - poses[0, b, :3]) @ quaternion.to_matrix(pose[3:]).T
        out[k] = np.linalg.norm(result["positions"][k] - rigid, axis=1).max()
    return out


def bones_summary(result: dict) -> str:
    """A skeleton hand's bones on the summary's hand line: how many hold how many nodes, and the
    bone furthest from its target at the end (nothing for the palm handle)."""
    if "bone_pose" not in result:
        return ""
    gap = np.linalg.norm(result["bone_pose"][-1, :, :3] - result["bone_target"][-1, :, :3], axis=1)
    held = int((result["bone_nodes"] >= 0).sum())
    return (f" of the root; {len(result['bone_names'])} bones hold {held} nodes, the furthest from its target at the "
            f"end {result['bone_names'][int(np.argmax(gap))]} ({gap.max() * 1000:.1f} mm)")


def felt_summary(result: dict) -> list[str]:
    """A skeleton hand's session: the felt force at the end per group (or the largest bone's)."""
    if "haptic_group_feedback" in result:
        felt = np.linalg.norm(result["haptic_group_feedback"][-1, :, :3], axis=1)
        return ["felt per group at the end: " + ", ".join(f"{name} {f:.3f} N" for name, f in
                                                          zip(result["haptic_group_names"], felt))]
    if "haptic_bone_feedback" in result:
        felt = np.linalg.norm(result["haptic_bone_feedback"][-1, :, :3], axis=1)
        return [f"felt per bone at the end: up to {felt.max():.3f} N ({result['bone_names'][int(np.argmax(felt))]})"]
    return []


def summary(result: dict) -> str:
    t = result["timings"]
    vt = result["visual_timings"]
    cs = result["contact_stats"]
    thickness = json.loads(str(result["scene"]))["contact"]["thickness"]
    n_frames = len(result["time"]) - 1
    travel = np.linalg.norm(result["handle_pose"][:, :3] - result["handle_pose"][0, :3], axis=1)
    force = np.linalg.norm(result["coupling_wrench"][:, :3], axis=1)
    haptic = []
    if result.get("haptic") is not None and len(result["haptic"]["t"]):
        h = result["haptic"]
        felt = np.linalg.norm(h["force"], axis=1)
        haptic = [f"haptic loop: {len(h['t'])} steps ({len(h['t']) / max(h['t'][-1], 1e-12):.0f} Hz), felt force "
                  f"max {felt.max():.3f} N, final {felt[-1]:.3f} N, step cost median {np.median(h['cost']) * 1e6:.1f} us"]
    return "\n".join([
        f"frames: {n_frames} at dt = {result['time'][1]:.4f} s ({result['time'][-1]:.2f} s simulated)",
        f"hand: {len(result['rest_nodes'])} nodes, {len(result['tets'])} tets, "
        f"{len(result['handle_nodes'])} handle nodes" + bones_summary(result),
        f"handle travel: up to {travel.max() * 1000:.1f} mm from its start",
        f"flesh deformation (distance from the handle's rigid motion): up to {flesh_deformation(result).max() * 1000:.1f} mm",
        f"coupling force on handle: max {force.max():.3f} N, final {force[-1]:.3f} N",
        f"hand step: mean {t[:, 3].mean() * 1e3:.2f} ms (assembly {t[:, 0].mean() * 1e3:.2f}, "
        f"deformable solves {t[:, 1].mean() * 1e3:.2f}, Schur {t[:, 2].mean() * 1e3:.3f})",
        f"visual step: mean {vt[:, 3].mean() * 1e3:.2f} ms (collision detection {vt[:, 0].mean() * 1e3:.2f}, "
        f"dynamics {vt[:, 1].mean() * 1e3:.2f}, contact solve {vt[:, 2].mean() * 1e3:.2f}): "
        f"{1.0 / vt[:, 3].mean():.0f} Hz",
        f"contacts: up to {int(cs[:, 0].max())} ({int(cs[:, 1].max())} between fingers), deepest into the "
        f"{thickness * 1e3:.1f} mm thickness: {cs[:, 2].max() * 1e3:.3f} mm",
    ] + haptic + felt_summary(result) + [str(w) for w in result.get("warnings", [])])
