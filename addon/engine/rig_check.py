"""`check-rig`: checks a hand rig before it is used. It prepares the scene exactly as `simulate`
does (so it refuses what `simulate` refuses, with the same message), then reports the surface,
the tets, the handle, how far the hand droops under gravity while the handle is held still, and
the Schur-complement solve against the monolithic reference on one step of the rig (a skeleton's
bones: rig_check_skeleton)."""

from __future__ import annotations

import numpy as np

from . import bodies as bodies_module
from . import devices
from . import mesh as meshing
from . import native
from . import rig_check_skeleton
from . import scene as scenes
from .rig_droop import DROOP_LIMIT, SCHUR_TOLERANCE, add_droop, add_schur, settle  # the limits and settle, read here too

#: What `simulate` refuses, and so check-rig too.
USER_ERRORS = (meshing.MeshError, scenes.SceneError, native.NativeError, bodies_module.BodyError,
               devices.DeviceError, OSError)


def prepare(scene: scenes.Scene, progress=None):
    """Everything `simulate` does before its first step: the hand's geometry, the memory the run
    needs, the world with every body, and the haptic loop's device. Returns the hand model."""
    from . import session as session_module
    from .scene_world import build_world

    if scene.nodes is None:
        scenes.load_hand_geometry(scene, progress)
    scenes.check_memory(scene, len(scene.nodes))
    world, hand, model, _, _ = build_world(scene)
    if scene.data["haptics"]["enabled"]:
        haptics = session_module.create(world, hand, scene, log_capacity=16)
        try:
            helper = session_module.attach_device(haptics, scene, model)
            if helper is not None:
                helper.stop()
        finally:
            haptics.close()
    return model


def check(scene: scenes.Scene, progress=None) -> dict:
    """Returns a report dict; 'ok' is False when any check failed. Never raises for bad input:
    the failure goes into the report with its message."""
    report = {"ok": True, "checks": [], "warnings": scene.warnings}

    def add(name: str, ok: bool, detail: str, **values):
        report["checks"].append({"name": name, "ok": bool(ok), "detail": detail, **values})
        report["ok"] &= bool(ok)

    try:
        model = prepare(scene, progress)
    except USER_ERRORS as e:
        add("rig", False, str(e))
        return report
    add("surface", True, f"closed, manifold, outward, not self-intersecting: {len(scene.surface_vertices)} vertices, "
                         f"{len(scene.surface_faces)} triangles")
    vols = meshing.tet_signed_volumes(scene.nodes, scene.tets)
    add("tets", True, f"{len(scene.tets)} tets, {len(scene.nodes)} nodes, volumes {vols.min():.3g} to {vols.max():.3g} m^3",
        n_tets=int(len(scene.tets)), n_nodes=int(len(scene.nodes)), min_volume=float(vols.min()))
    if scene.skeleton is not None:
        rig_check_skeleton.add_bones(add, scene, model)
        rig_check_skeleton.add_droop(add, scene, model)
        rig_check_skeleton.add_schur(add, model)
        return report
    info = model.info()
    add("handle", True,
        f"{info['n_handle_nodes']} of {info['n_nodes']} nodes captured, mass {info['handle_mass'] * 1000:.1f} g "
        f"of {info['total_mass'] * 1000:.1f} g",
        n_handle_nodes=info["n_handle_nodes"], handle_mass=info["handle_mass"], total_mass=info["total_mass"],
        handle_com=info["handle_com"], handle_inertia=info["handle_inertia"])
    add_droop(add, scene, model)
    add_schur(add, model)
    return report


def format_report(report: dict) -> str:
    lines = [f"warning: {w}" for w in report.get("warnings", [])]
    lines += [f"{'ok  ' if c['ok'] else 'FAIL'}  {c['name']:<20} {c['detail']}" for c in report["checks"]]
    lines.append("rig is ready" if report["ok"] else "rig has problems: fix the FAIL lines above")
    return "\n".join(lines)
