"""The palm handle's droop and Schur checks of `check-rig` (rig_check): the hand's static
equilibrium under gravity with the handle held still, by damped implicit steps of the engine's
own model, the fixes when it droops too far, and one step's Schur solve against the monolithic
reference. A skeleton's bones use the same settle (rig_check_skeleton)."""

from __future__ import annotations

import numpy as np

from . import native
from . import scene as scenes

SCHUR_TOLERANCE = 1e-8
#: Droop (m) above which the rig is not ready: the flesh hangs visibly off the handle.
DROOP_LIMIT = 5e-3
#: The settle of the droop: steps of 0.1 s with mass damping (neither changes the equilibrium).
SETTLE_DT, SETTLE_DAMPING, SETTLE_STEPS = 0.1, 10.0, 300
#: Handle radii tried, as multiples of the scene's, when the droop is too large.
RADIUS_FACTORS = (1.25, 1.5, 2.0, 2.5, 3.0)

def settle_params(rig: dict) -> dict:
    """The rig's parameters for the settle: steps of SETTLE_DT with SETTLE_DAMPING at least."""
    return {**rig, "dt": SETTLE_DT, "rayleigh_alpha": max(rig.get("rayleigh_alpha", 0.0), SETTLE_DAMPING)}


def settle(nodes, tets, rig: dict) -> dict:
    """The hand's static equilibrium under gravity with the handle held at its rest pose, by
    damped implicit steps of the engine's own co-rotational model until the nodes stop moving
    (settle_steps)."""
    model = native.HandModel(nodes, tets, **settle_params(rig))
    sim = native.HandSimulation(model)
    sim.set_device(model.info()["handle_com"], [0.0, 0.0, 0.0, 1.0], [0.0] * 3, [0.0] * 3, enabled=2)
    return settle_steps(sim, model.nodes, model.handle_nodes())


def settle_steps(sim, rest: np.ndarray, held: np.ndarray) -> dict:
    """Steps sim until its nodes stop moving. Returns droop (m, the largest node displacement),
    springs (m, the largest of the held nodes: the springs' stretch), node (the one that droops
    most), steps, settled."""
    x = rest
    for k in range(1, SETTLE_STEPS + 1):
        sim.step()
        x_new = sim.positions()
        moved = np.abs(x_new - x).max()
        x = x_new
        displacement = np.linalg.norm(x - rest, axis=1)
        if moved <= max(1e-9, 1e-5 * displacement.max()):
            break
    return {"droop": float(displacement.max()), "springs": float(displacement[held].max()),
            "node": int(np.argmax(displacement)), "steps": k, "settled": bool(moved <= max(1e-9, 1e-5 * displacement.max()))}


def droop_advice(scene: scenes.Scene, rig: dict, result: dict, droop_of=None) -> str:
    """The fixes for a droop above DROOP_LIMIT, each with the droop it gives: stiffer springs when
    their stretch is most of it; the smallest larger handle radius (of RADIUS_FACTORS) that brings
    it under, or the best of them (the palm handle); stiffer flesh (the droop of the flesh goes as
    1 / E). droop_of(rig): the droop of the rig with other parameters (default: settle's)."""
    droop_of = droop_of or (lambda changed: settle(scene.nodes, scene.tets, changed)["droop"])
    fixes = []
    k = rig["spring_stiffness"]
    if result["springs"] > 0.5 * result["droop"]:
        fixes.append(f"stiffer springs (springs.stiffness about {k * result['springs'] / (0.25 * DROOP_LIMIT):.3g} "
                     f"N/m, now {k:.3g})")
    radius, best = rig["handle_radius"], None
    for factor in RADIUS_FACTORS if scene.skeleton is None else ():  # (bones have radii of their own)
        r = radius * factor
        try:
            native.check_handle(scene.nodes, rig["palm_seed"], r)
        except native.InvalidInput:
            break  # it would hold every node
        best = (r, droop_of({**rig, "handle_radius": r}))
        if best[1] <= DROOP_LIMIT:
            break
    if best is not None:
        fixes.append(f"a larger handle (hand.handle_radius {best[0]:.3g} m droops {best[1] * 1e3:.1f} mm)")
    flesh = result["droop"] - result["springs"]
    if flesh > 0.5 * result["droop"]:
        e = rig["young_modulus"] * flesh / (0.8 * DROOP_LIMIT)
        stiffer = droop_of({**rig, "young_modulus": e})
        fixes.append(f"stiffer flesh (material.young_modulus {e:.3g} Pa droops {stiffer * 1e3:.1f} mm)")
    return ", or ".join(fixes)


def add_droop(add, scene: scenes.Scene, model: native.HandModel) -> None:
    rig = model.params()
    result = settle(scene.nodes, scene.tets, rig)
    add_droop_result(add, scene, rig, result, f"with the handle held still (node {result['node']}")


def add_droop_result(add, scene: scenes.Scene, rig: dict, result: dict, held: str, droop_of=None, **values) -> None:
    """The droop check from a settle's result; `held` says how the hand was held (and where it
    drooped most), droop_of is droop_advice's, values go into the report."""
    detail = (f"{result['droop'] * 1e3:.1f} mm under gravity {held}; the springs stretch "
              f"{result['springs'] * 1e3:.2f} mm)")
    if not result["settled"]:
        detail += f"; still moving after {result['steps']} steps of {SETTLE_DT} s"
    ok = result["droop"] <= DROOP_LIMIT
    if not ok:
        detail += f", over {DROOP_LIMIT * 1e3:.0f} mm: try {droop_advice(scene, rig, result, droop_of)}"
    add("droop", ok, detail, droop=result["droop"], spring_stretch=result["springs"], droop_node=result["node"],
        settle_steps=result["steps"], **values)


def add_schur(add, model: native.HandModel) -> None:
    # One step with the device pulled 1 cm and turned 0.2 rad, so every coupling term is active.
    info = model.info()
    sim = native.HandSimulation(model)
    com = np.array(info["handle_com"])
    half = 0.1
    sim.set_device(com + [0.01, 0.0, 0.0], [np.sin(half), 0.0, 0.0, np.cos(half)], [0.3, 0.0, 0.0], [2.0, 0.0, 0.0])
    sim.set_state(handle_velocity=[0.1, 0.0, 0.0], handle_angular_velocity=[0.5, 0.0, 0.0])
    diff = sim.compare_solvers()
    add("schur_vs_monolithic", diff < SCHUR_TOLERANCE,
        f"relative difference {diff:.2e} (tolerance {SCHUR_TOLERANCE:.0e})", relative_difference=diff)
