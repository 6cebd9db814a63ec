"""`check-rig`: checks a hand rig before it is used and cross-checks the Schur-complement
solve against the monolithic reference on one step of that rig."""

from __future__ import annotations

import numpy as np

from . import mesh as meshing
from . import native
from . import scene as scenes

SCHUR_TOLERANCE = 1e-8


def check(scene: scenes.Scene, progress=None) -> dict:
    """Returns a report dict; 'ok' is False when any check failed. Never raises for bad input:
    the failure goes into the report with its message."""
    report = {"ok": True, "checks": []}

    def add(name: str, ok: bool, detail: str, **values):
        report["checks"].append({"name": name, "ok": bool(ok), "detail": detail, **values})
        report["ok"] &= bool(ok)

    try:
        scenes.load_hand_geometry(scene, progress)
        add("surface", True, f"closed, manifold, outward: {len(scene.surface_vertices)} vertices, "
                             f"{len(scene.surface_faces)} triangles")
        vols = meshing.tet_signed_volumes(scene.nodes, scene.tets)
        add("tets", bool(vols.min() > 0),
            f"{len(scene.tets)} tets, {len(scene.nodes)} nodes, volumes {vols.min():.3g} to {vols.max():.3g} m^3",
            n_tets=int(len(scene.tets)), n_nodes=int(len(scene.nodes)), min_volume=float(vols.min()))
        model = native.HandModel(scene.nodes, scene.tets, **scene.engine_params())
    except (meshing.MeshError, scenes.SceneError, native.NativeError) as e:
        add("rig", False, str(e))
        return report

    info = model.info()
    add("handle", True,
        f"{info['n_handle_nodes']} of {info['n_nodes']} nodes captured, mass {info['handle_mass'] * 1000:.1f} g "
        f"of {info['total_mass'] * 1000:.1f} g",
        n_handle_nodes=info["n_handle_nodes"], handle_mass=info["handle_mass"], total_mass=info["total_mass"],
        handle_com=info["handle_com"], handle_inertia=info["handle_inertia"])

    # One step with the device pulled 1 cm and turned 0.2 rad, so every coupling term is active.
    sim = native.HandSimulation(model)
    com = np.array(info["handle_com"])
    half = 0.1
    sim.set_device(com + [0.01, 0.0, 0.0], [np.sin(half), 0.0, 0.0, np.cos(half)], [0.3, 0.0, 0.0], [2.0, 0.0, 0.0])
    sim.set_state(handle_velocity=[0.1, 0.0, 0.0], handle_angular_velocity=[0.5, 0.0, 0.0])
    diff = sim.compare_solvers()
    add("schur_vs_monolithic", diff < SCHUR_TOLERANCE,
        f"relative difference {diff:.2e} (tolerance {SCHUR_TOLERANCE:.0e})", relative_difference=diff)
    return report


def format_report(report: dict) -> str:
    lines = [f"{'ok  ' if c['ok'] else 'FAIL'}  {c['name']:<20} {c['detail']}" for c in report["checks"]]
    lines.append("rig is ready" if report["ok"] else "rig has problems: fix the FAIL lines above")
    return "\n".join(lines)
