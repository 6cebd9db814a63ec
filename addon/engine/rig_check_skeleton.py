"""`check-rig` for a hand driven by a skeleton (docs/skeleton.md): what each bone holds, how far
each bone's part of the hand droops under gravity with every bone held at rest and how much of
the hand's weight each bone carries (the bones' springs carry it all: sum_b F_b = M g), and the
B-bone Schur solve against the monolithic one."""

from __future__ import annotations

import numpy as np

from . import native_skeleton as ns
from . import rig_droop
from . import scene as scenes

#: Relative error of sum_b F_b = M g, once settled, above which the statics do not close.
WEIGHT_TOLERANCE = 1e-3


def add_bones(add, scene: scenes.Scene, model: ns.SkeletonModel) -> None:
    info = [model.bone_info(b) for b in range(model.n_bones)]
    held = sum(i["n_nodes"] for i in info)
    bones = [{"name": name, "n_nodes": i["n_nodes"], "mass": i["mass"], "radius": bone.radius if bone.nodes is None
              else None} for name, bone, i in zip(scene.skeleton.skeleton.names, scene.skeleton.skeleton.bones, info)]
    counts = ", ".join(f"{b['name']} {b['n_nodes']}" for b in bones)
    add("bones", True, f"{len(bones)} bones hold {held} of {model.n_nodes} nodes ({counts}); "
                       f"{sum(i['mass'] for i in info) * 1000:.1f} g of {model.lumped_masses().sum() * 1000:.1f} g",
        bones=bones)


def settle(scene: scenes.Scene, rig: dict) -> tuple[dict, ns.SkeletonSimulation, ns.SkeletonModel]:
    """The hand's static equilibrium under gravity with every bone held at its rest pose
    (rig_droop.settle's damped steps, every bone prescribed)."""
    model = ns.SkeletonModel(scene.nodes, scene.tets, scene.skeleton.skeleton, scene.skeleton.drive_scales,
                             **rig_droop.settle_params(rig))
    sim = ns.SkeletonSimulation(model)
    p, q, _, _ = sim.bone_states()
    sim.set_bone_targets(np.full(model.n_bones, ns.PRESCRIBED), p, q)
    result = rig_droop.settle_steps(sim, model.nodes, np.flatnonzero(model.node_bones() >= 0))
    return result, sim, model


def add_droop(add, scene: scenes.Scene, model: ns.SkeletonModel) -> None:
    rig = model.params()
    result, sim, settled = settle(scene, rig)
    names = scene.skeleton.skeleton.names
    region = scene.skeleton.skeleton.regions(scene.nodes, settled.node_bones())
    displacement = np.linalg.norm(sim.positions() - scene.nodes, axis=1)
    gravity = np.asarray(rig["gravity"], dtype=float)
    weight = settled.lumped_masses().sum() * gravity
    forces = sim.bone_wrenches()[:, :3]
    g = np.linalg.norm(gravity)
    bones = [{"name": name, "droop": float(displacement[region == b].max(initial=0.0)),
              "carries": float(forces[b] @ gravity / g**2) if g > 0 else 0.0} for b, name in enumerate(names)]
    worst = max(bones, key=lambda b: b["droop"])
    rig_droop.add_droop_result(add, scene, rig, result, f"with every bone held still (most at {worst['name']}",
                               lambda changed: settle(scene, changed)[0]["droop"], bones=bones)
    if g > 0:
        error = np.linalg.norm(forces.sum(axis=0) - weight) / np.linalg.norm(weight)
        carried = ", ".join(f"{b['name']} {b['carries'] * 1000:.1f} g" for b in bones)
        add("weight", error <= WEIGHT_TOLERANCE,
            f"the bones' springs carry {forces.sum(axis=0) @ gravity / g**2 * 1000:.1f} g of the hand's "
            f"{np.linalg.norm(weight) / g * 1000:.1f} g (relative error {error:.1e}): {carried}",
            relative_error=float(error))


def add_schur(add, model: ns.SkeletonModel) -> None:
    """One step with every bone pulled off its target and spinning, so every term is active."""
    sim = ns.SkeletonSimulation(model)
    p, q, v, w = sim.bone_states()
    b = model.n_bones
    offsets = 0.003 * np.stack([np.cos(np.arange(b)), np.sin(np.arange(b)), np.cos(2 * np.arange(b))], axis=1)
    sim.set_bone_targets(np.full(b, ns.COUPLED), p + offsets, q)
    sim.set_bone_states(velocities=0.1 * offsets / 0.003, angular_velocities=0.5 * np.roll(offsets, 1, axis=1) / 0.003)
    diff = sim.compare_solvers()
    add("schur_vs_monolithic", diff < rig_droop.SCHUR_TOLERANCE,
        f"relative difference {diff:.2e} (tolerance {rig_droop.SCHUR_TOLERANCE:.0e}, {b} bones)",
        relative_difference=diff)
