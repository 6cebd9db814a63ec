#!/usr/bin/env python3
"""Per-step cost of the coupled hand-handle simulation (run by `make bench`).

For hands of about 350, 1700, 5000 and 20000 tets (pytetwild tetrahedralizations of a hand
surface, cached in build/bench_meshes/) this measures one implicit step of Eq. 7 solved through
the Schur complement, with the sparse Cholesky and with the conjugate-gradient deformable
solver, split as the engine reports it (assembly, the 8 deformable solves, the 6x6 Schur
complement, the rest); the monolithic sparse-LU reference step side by side; the cost against
the number of handle nodes; and the issue's targets (1700 tets under 2 ms, 20000 tets under
33 ms on one core). Results go to build/bench/bench_step.json and build/bench/bench_step.png.

Usage: .venv/bin/python bench/bench_step.py [--sizes 350,1700] [--steps N] [--quick]
See bench/README.md for how to read the output.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np

from machine import machine_info, print_machine
from mesh_export import write_tet_mesh
from haptic_hand.engine import mesh, native

REPO = Path(__file__).resolve().parents[1]
SHARED_HAND = REPO.parent / "shared" / "data" / "hand.obj"
SHARED_STATS = SHARED_HAND.parent / "mesh_stats.json"
MESH_CACHE = REPO / "build" / "bench_meshes"
OUT_DIR = REPO / "build" / "bench"

SIZES = (350, 1700, 5000, 20000)
HANDLE_RADIUS = 0.03  # m
MIN_HANDLE_NODES = 4  # the engine's minimum
DEVICE_OFFSET = np.array([0.01, 0.0, 0.0])  # m: the device frame 1 cm from the handle
CG_TOLERANCE = 1e-6
WARMUP_STEPS = 3
MOVING_AMPLITUDE = 0.03  # m: the moving scenario's device loop (moving_device)
MOVING_SOLVERS = ("cholesky", "reused_cholesky", "reused_tight")  # CG is far too slow to matter here
MOVING_MIN_STEPS = 60  # 2 s of motion: about 3 rad of turn
SWEEP_RADII = (0.015, 0.02, 0.025, 0.03, 0.035, 0.04, 0.045, 0.05, 0.055, 0.06)
SWEEP_SIZE = 1700
TARGETS = ((1700, 2e-3), (20000, 33e-3))
# The deformable solvers measured: the exact per-step factorization ("cholesky", the old path),
# the reused warped factor preconditioning CG ("reused_cholesky", HH_SOLVER_REUSED_CHOLESKY, the
# new path) and Jacobi CG.
# "reused_tight": the same reused factor with CG to 1e-10 (the tolerance this path was pinned to
# before it honoured the user's), to show what the last four orders of magnitude cost.
TIGHT_TOLERANCE = 1e-10
SOLVERS = ("cholesky", "reused_cholesky", "reused_tight", "cg")
SOLVER_LABELS = {"cholesky": "cholesky", "reused_cholesky": "reused", "reused_tight": "reused10", "cg": "cg"}
VARIANTS = {"cholesky": ("cholesky", CG_TOLERANCE), "reused_cholesky": ("reused_cholesky", CG_TOLERANCE),
            "reused_tight": ("reused_cholesky", TIGHT_TOLERANCE), "cg": ("cg", CG_TOLERANCE)}  # engine solver, tolerance
MONOLITHIC_SLOW = 5.0  # s: past this a monolithic step is run only twice
MONOLITHIC_BUDGET = 40.0  # s: the monolithic runs of one hand stop at about this much

# pytetwild settings (coarsen, epsilon, edge_length_fac) tried in order until the tet count is
# within MESH_TOLERANCE of the target; the closest is kept. Counts seen on hand.obj (they vary
# from run to run): 350 -> 414 / 405 / 283; 1700 -> ~1570-1600; 5000 -> 4987; 20000 -> 22766.
MESH_SETTINGS = {
    350: [(True, 0.015, 0.5), (True, 0.017, 0.5), (True, 0.018, 0.55)],
    1700: [(True, 0.004, 0.18), (True, 0.004, 0.2), (True, 0.003, 0.15)],
    5000: [(False, 0.002, 0.06), (False, 0.003, 0.05), (False, 0.002, 0.08)],
    20000: [(False, 0.001, 0.023), (False, 0.001, 0.022), (False, 0.001, 0.025)],
}
MESH_TOLERANCE = 0.25

SWEEP_FITS = {
    "t_schur_coupling": "Schur+coupling (= total - deformable)",
    "t_schur_other": "Schur 6x6 + Aht products/rhs (no asm.)",
    "t_schur": "Schur 6x6 alone (engine's t_schur)",
    "t_assembly": "assembly (FEM + springs)",
    "t_deformable": "deformable solves",
    "t_total": "total",
}
PHASES = ("t_assembly", "t_deformable", "t_schur", "t_other")
PHASE_LABELS = {
    "t_assembly": "assembly",
    "t_deformable": "deformable solves (8)",
    "t_schur": "Schur complement (6x6)",
    "t_other": "other (Aht products, rhs, integration)",
}


def ms(seconds: float) -> str:
    return f"{1e3 * seconds:.3f}"


# ------------------------------------------------------------------------------------------
# Machine
# ------------------------------------------------------------------------------------------


# ------------------------------------------------------------------------------------------
# Meshes
# ------------------------------------------------------------------------------------------


def hand_surface(choice: str):
    """(name, V, F, palm_seed, digest of the surface)."""
    if choice in ("auto", "shared") and SHARED_HAND.is_file():
        V, F = mesh.load_obj(SHARED_HAND)
        seed = np.array(json.loads(SHARED_STATS.read_text())["hand.obj"]["suggested_palm_seed"])
        name = "hand.obj"
    elif choice == "shared":
        sys.exit(f"{SHARED_HAND} does not exist; use --surface procedural")
    else:
        V, F = mesh.procedural_hand()
        seed = mesh.procedural_hand_palm_seed()
        name = "procedural"
    digest = hashlib.sha1(np.ascontiguousarray(V, dtype=np.float64).tobytes()
                          + np.ascontiguousarray(F, dtype=np.int64).tobytes()).hexdigest()[:12]
    return name, V, F, np.asarray(seed, dtype=np.float64), digest


def hand_mesh(target: int, surface, remesh: bool) -> dict:
    """Tetrahedralize the surface near `target` tets, or load the cached result."""
    name, V, F, seed, digest = surface
    path = MESH_CACHE / f"{Path(name).stem}_{target}.npz"
    if path.is_file() and not remesh:
        data = np.load(path)
        if str(data["surface_digest"]) == digest:
            return {"nodes": data["nodes"], "tets": data["tets"], "seed": seed, "cache": str(path),
                    "cached": True, "settings": json.loads(str(data["settings"])),
                    "generation_s": float(data["generation_s"])}
    best = None
    for coarsen, epsilon, fac in MESH_SETTINGS[target]:
        t0 = time.perf_counter()
        nodes, tets = mesh.tetrahedralize(V, F, edge_length_fac=fac, coarsen=coarsen, epsilon=epsilon)
        took = time.perf_counter() - t0
        settings = {"coarsen": coarsen, "epsilon": epsilon, "edge_length_fac": fac}
        print(f"  tetrahedralized {name} for ~{target} tets with {settings}: {len(tets)} tets ({took:.1f} s)",
              flush=True)
        error = abs(len(tets) / target - 1)
        if best is None or error < best[0]:
            best = (error, nodes, tets, settings, took)
        if error <= MESH_TOLERANCE:
            break
    _, nodes, tets, settings, took = best
    MESH_CACHE.mkdir(parents=True, exist_ok=True)
    np.savez(path, nodes=nodes, tets=tets, surface_digest=digest, settings=json.dumps(settings),
             generation_s=took, surface=name)
    return {"nodes": nodes, "tets": tets, "seed": seed, "cache": str(path), "cached": False,
            "settings": settings, "generation_s": took}


def handle_radius_for(hand: dict, wanted: float) -> float:
    """The wanted radius, grown in 5 mm steps until the handle captures enough nodes."""
    radius = wanted
    while native.count_captured(hand["nodes"], hand["seed"], radius) < MIN_HANDLE_NODES:
        radius = round(radius + 0.005, 6)
    return radius


# ------------------------------------------------------------------------------------------
# Timing
# ------------------------------------------------------------------------------------------


def make_model(hand: dict, radius: float, variant: str) -> native.HandModel:
    solver, tolerance = VARIANTS[variant]
    return native.HandModel(hand["nodes"], hand["tets"], palm_seed=hand["seed"], handle_radius=radius,
                            solver=solver, cg_tolerance=tolerance)


def displaced_sim(model: native.HandModel) -> native.HandSimulation:
    """A simulation at rest under gravity with the device frame 1 cm from the handle."""
    sim = native.HandSimulation(model)
    com = np.array(model.info()["handle_com"])
    sim.set_device(com + DEVICE_OFFSET, [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    return sim


def with_other(stats: dict) -> dict:
    stats = dict(stats)
    stats["t_other"] = stats["t_total"] - stats["t_assembly"] - stats["t_deformable"] - stats["t_schur"]
    return stats


def summarize(records: list[dict]) -> dict:
    out = {"steps": len(records)}
    for key in PHASES + ("t_total",):
        values = np.array([r[key] for r in records])
        out[key] = {"mean": float(values.mean()), "min": float(values.min()),
                    "median": float(np.median(values)), "max": float(values.max())}
    iterations = np.array([r["cg_iterations"] for r in records])
    out["cg_iterations"] = {"mean": float(iterations.mean()), "min": int(iterations.min()),
                            "max": int(iterations.max())}
    out["max_residual"] = float(max(r["max_residual"] for r in records))
    # reused_cholesky: a step that renewed the factor solves directly (0 CG iterations)
    out["direct_steps"] = int((iterations == 0).sum())
    return out


def time_schur(model, warmup: int, steps: int) -> tuple[dict, list[dict], np.ndarray]:
    sim = displaced_sim(model)
    for _ in range(warmup):
        sim.step()
    records = [with_other(sim.step()) for _ in range(steps)]
    return summarize(records), records, sim.positions()


def quaternion_from_rotation_vector(w: np.ndarray) -> list[float]:
    angle = float(np.linalg.norm(w))
    if angle < 1e-15:
        return [0.0, 0.0, 0.0, 1.0]
    return [*(np.sin(angle / 2) * w / angle), float(np.cos(angle / 2))]  # (x, y, z, w)


def moving_device(t: float, com: np.ndarray) -> tuple[np.ndarray, list[float]]:
    """The device of the moving scenario at time t: a 3 cm loop and a steady turn (1.5 rad/s about
    z with a wobble about x and y), so the flesh keeps rotating away from any earlier factor."""
    position = com + MOVING_AMPLITUDE * np.array([np.cos(3 * t) - 1, np.sin(3 * t), 0.5 * np.sin(2 * t)])
    return position, quaternion_from_rotation_vector(np.array([0.6 * np.sin(2 * t), 0.4 * np.sin(1.5 * t), 1.5 * t]))


def time_moving(model, warmup: int, steps: int) -> tuple[dict, np.ndarray]:
    """Steps with the device moving and turning (moving_device), from rest."""
    sim = native.HandSimulation(model)
    com = np.array(model.info()["handle_com"])
    dt = model.params()["dt"]
    records = []
    for s in range(warmup + steps):
        position, q = moving_device(s * dt, com)
        sim.set_device(position, q, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
        record = with_other(sim.step())
        if s >= warmup:
            records.append(record)
    return summarize(records), sim.positions()


def time_side_by_side(model, warmup: int, steps: int) -> dict:
    """Schur and monolithic steps interleaved, from the same state, on the same model, so the
    ratio is not skewed by a change of machine load between two runs."""
    schur, mono = displaced_sim(model), displaced_sim(model)
    t0 = time.perf_counter()
    mono.step(monolithic=True)  # warm-up, and a measure of how many steps we can afford
    one = time.perf_counter() - t0
    schur.step()
    if one > MONOLITHIC_SLOW:
        n = 2
    else:
        n = max(2, min(steps, int(MONOLITHIC_BUDGET / max(one, 1e-9))))
        for _ in range(warmup - 1):
            schur.step()
            mono.step(monolithic=True)
    a, b = [], []
    for _ in range(n):
        a.append(with_other(schur.step()))
        b.append(with_other(mono.step(monolithic=True)))
    # the two runs must have stayed on the same trajectory (same equations, two solvers)
    moved = np.abs(mono.positions() - model.nodes).max()
    difference = np.abs(schur.positions() - mono.positions()).max() / max(moved, 1e-300)
    s, m = summarize(a), summarize(b)
    return {"steps": n, "first_monolithic_step_s": one, "schur": s, "monolithic": m,
            "schur_over_monolithic": s["t_total"]["mean"] / m["t_total"]["mean"],
            "relative_position_difference": float(difference)}


def handle_sweep(hand: dict, radii, warmup: int, steps: int) -> dict:
    """Cost against the number of handle nodes, the handle radius alone changing.

    The assembly cost depends on the motion (the co-rotation's polar decomposition iterates,
    warm started from the last step), and a larger handle moves the hand differently. So one
    trajectory is recorded (handle radius HANDLE_RADIUS) and replayed for every radius: before
    each step the state is set to the recorded one (handle pose relative to each handle's own
    rest centre of mass), so every radius does the same FEM work and differs only in the handle.
    The radii are run in two passes, ascending then descending, so that a drift of the
    machine's load affects them alike."""
    sweep = {"n_tets": int(len(hand["tets"])), "steps": steps, "statistic": "median", "solver": "cholesky",
             "method": "replay of one recorded trajectory; radii run ascending then descending", "points": [], "skipped": []}
    reference = make_model(hand, hand["radius"], "cholesky")
    sim = displaced_sim(reference)
    rest_com = np.array(reference.info()["handle_com"])
    trajectory = []
    for _ in range(warmup + steps):
        h = sim.handle()
        trajectory.append((sim.positions(), sim.velocities(), h.position - rest_com, h.quaternion, h.velocity,
                           h.angular_velocity))
        sim.step()
    runs = []
    for radius in radii:
        count = native.count_captured(hand["nodes"], hand["seed"], radius)
        if count < MIN_HANDLE_NODES or count >= len(hand["nodes"]):
            sweep["skipped"].append((radius, count))
            continue
        model = make_model(hand, radius, "cholesky")
        runs.append((radius, count, model, displaced_sim(model), np.array(model.info()["handle_com"]), []))
    # Two passes over the radii, ascending then descending, so that a drift of the machine's
    # load cancels out; each radius replays the whole trajectory at once (warm caches).
    for order in (runs, runs[::-1]):
        for radius, count, model, sim, com, records in order:
            for k, (x, v, dp, q, hv, hw) in enumerate(trajectory):
                sim.set_state(x, v, com + dp, q, hv, hw)
                stats = with_other(sim.step())
                if k >= warmup:
                    records.append(stats)
    for radius, count, model, sim, com, records in runs:
        point = {"radius": radius, "n_handle_nodes": count}
        for key in PHASES + ("t_total",):
            point[key] = float(np.median([rec[key] for rec in records]))
        point["t_schur_coupling"] = float(np.median([rec["t_total"] - rec["t_deformable"] for rec in records]))
        point["t_schur_other"] = float(np.median([rec["t_schur"] + rec["t_other"] for rec in records]))
        point["samples"] = len(records)
        sweep["points"].append(point)
    h = [p["n_handle_nodes"] for p in sweep["points"]]
    sweep["fits"] = {key: fit_line(h, [p[key] for p in sweep["points"]])
                     for key in SWEEP_FITS} if len(h) >= 2 else {}
    return sweep


def fit_line(x, y) -> dict:
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    slope, intercept = np.polyfit(x, y, 1)
    residual = y - (slope * x + intercept)
    total = ((y - y.mean()) ** 2).sum()
    r2 = 1.0 - (residual ** 2).sum() / total if total > 0 else float("nan")
    return {"slope_s_per_node": float(slope), "intercept_s": float(intercept), "r2": float(r2)}


# ------------------------------------------------------------------------------------------
# Report
# ------------------------------------------------------------------------------------------


def print_header(header: str) -> None:
    print(header)
    print("-" * len(header))


def print_solver_table(results: list[dict]) -> None:
    print("\n== Per-step time, Schur-complement step (ms; mean / min over the measured steps)")
    header = (f"{'tets':>6} {'nodes':>6} {'hnodes':>6} {'solver':>8} {'steps':>5} | {'assembly':>15} "
              f"{'deformable':>15} {'schur':>15} {'other':>15} {'total':>15} | {'CG it/step':>10}")
    print_header(header)
    for r in results:
        for solver in SOLVERS:
            s = r[solver]
            cells = " ".join(f"{ms(s[k]['mean']):>7}/{ms(s[k]['min']):>7}" for k in PHASES + ("t_total",))
            it = f"{s['cg_iterations']['mean']:10.1f}" if solver != "cholesky" else f"{'-':>10}"
            print(f"{r['n_tets']:>6} {r['n_nodes']:>6} {r['n_handle_nodes']:>6} {SOLVER_LABELS[solver]:>8} "
                  f"{s['steps']:>5} | {cells} | {it}")
    print(f"(reused: HH_SOLVER_REUSED_CHOLESKY to a relative residual of {CG_TOLERANCE:g} like cg; reused10: the same "
          f"to {TIGHT_TOLERANCE:g};\n their CG it/step is summed over the 7 batched solves)")
    bad = [(r["n_tets"], r["cg"]["max_residual"]) for r in results if r["cg"]["max_residual"] > CG_TOLERANCE]
    for tets, residual in bad:
        print(f"note: CG on the {tets}-tet hand stopped at relative residual {residual:.2g} > {CG_TOLERANCE:g} "
              "(iteration cap reached)")


def print_old_vs_new(results: list[dict]) -> None:
    """The exact per-step factorization against the reused warped factor, same run, same hands."""
    print("\n== Old path (cholesky: factor At every step) vs new path (reused: the factor of an earlier step, "
          f"warped,\n   preconditions CG to {CG_TOLERANCE:g}; reused10: to {TIGHT_TOLERANCE:g}), ms per step; "
          "ratio = new / old")
    header = (f"{'tets':>6} {'new':>8} | {'old deformable':>14} {'new deformable':>14} {'ratio':>6} | {'old total':>9} "
              f"{'new total':>9} {'ratio':>6} | {'old max':>8} {'new max':>8} | {'refactor steps':>14} "
              f"{'new max resid.':>14} {'|dx| rel':>10}")
    print_header(header)
    for r, variant in ((r, v) for r in results for v in ("reused_cholesky", "reused_tight")):
        o, n = r["cholesky"], r[variant]
        print(f"{r['n_tets']:>6} {SOLVER_LABELS[variant]:>8} | {ms(o['t_deformable']['mean']):>14} {ms(n['t_deformable']['mean']):>14} "
              f"{n['t_deformable']['mean'] / o['t_deformable']['mean']:>6.2f} | {ms(o['t_total']['mean']):>9} "
              f"{ms(n['t_total']['mean']):>9} {n['t_total']['mean'] / o['t_total']['mean']:>6.2f} | "
              f"{ms(o['t_total']['max']):>8} {ms(n['t_total']['max']):>8} | "
              f"{n['direct_steps']:>6} of {n['steps']:<5} {n['max_residual']:>14.1e} "
              f"{r[f'{variant}_vs_cholesky_position_difference']:>10.1e}")
    print("(refactor steps: measured steps that renewed the factor and solved directly; max: the slowest step;\n"
          " |dx| rel: the two runs' node positions at the end, max difference over the largest displacement)")


def print_moving_table(results: list[dict]) -> None:
    print(f"\n== Moving device (a {1e2 * MOVING_AMPLITUDE:g} cm loop and a 1.5 rad/s turn, from rest; the reused factor "
          "goes stale), ms per step")
    header = (f"{'tets':>6} {'solver':>8} {'steps':>5} | {'mean':>8} {'median':>8} {'min':>8} {'max':>8} | "
              f"{'CG it/step':>10} {'refactor steps':>14} {'max resid.':>10} {'|dx| rel':>9}")
    print_header(header)
    for r in results:
        for variant in MOVING_SOLVERS:
            m = r["moving"][variant]
            t = m["t_total"]
            refactor = f"{m['direct_steps']:>6} of {m['steps']:<5}" if variant != "cholesky" else f"{'-':>14}"
            residual = f"{m['max_residual']:>10.1e}" if variant != "cholesky" else f"{'-':>10}"
            dx = r["moving"].get(f"{variant}_vs_cholesky_position_difference")
            print(f"{r['n_tets']:>6} {SOLVER_LABELS[variant]:>8} {m['steps']:>5} | {ms(t['mean']):>8} {ms(t['median']):>8} "
                  f"{ms(t['min']):>8} {ms(t['max']):>8} | {m['cg_iterations']['mean']:>10.1f} {refactor} {residual} "
                  f"{'-' if dx is None else f'{dx:.1e}':>9}")
    print("(|dx| rel: node positions at the end against the cholesky run, max difference over the largest displacement)")


def print_monolithic_table(results: list[dict]) -> None:
    print("\n== Schur (Cholesky) vs monolithic sparse-LU step, interleaved in one run (ms per step, mean / min)")
    header = (f"{'tets':>6} {'steps':>5} | {'Schur total':>17} {'monolithic total':>17} | "
              f"{'Schur/mono':>10} {'speed-up':>8} | {'|dx| rel':>8}")
    print_header(header)
    for r in results:
        p = r["side_by_side"]
        s, m = p["schur"]["t_total"], p["monolithic"]["t_total"]
        print(f"{r['n_tets']:>6} {p['steps']:>5} | {ms(s['mean']):>8}/{ms(s['min']):>8} "
              f"{ms(m['mean']):>8}/{ms(m['min']):>8} | {p['schur_over_monolithic']:>10.4f} "
              f"{1 / p['schur_over_monolithic']:>7.1f}x | {p['relative_position_difference']:>8.1e}")
    print("(|dx| rel: max difference of the two trajectories' node positions over the largest "
          "displacement; the same equations solved two ways)")


def print_sweep(sweep: dict) -> None:
    print(f"\n== Cost vs handle nodes on the {sweep['n_tets']}-tet hand (Cholesky, ms per step, median of "
          f"{sweep['steps']} steps x 2 passes;\n   one recorded trajectory replayed for every radius, radii run ascending then descending)")
    header = (f"{'radius':>7} {'hnodes':>6} | {'assembly':>9} {'deformable':>10} {'schur':>9} {'other':>9} "
              f"{'schur+coupling':>14} {'total':>9}")
    print_header(header)
    for p in sweep["points"]:
        print(f"{p['radius']:>7.3f} {p['n_handle_nodes']:>6} | {ms(p['t_assembly']):>9} {ms(p['t_deformable']):>10} "
              f"{ms(p['t_schur']):>9} {ms(p['t_other']):>9} {ms(p['t_schur_coupling']):>14} {ms(p['t_total']):>9}")
    for radius, count in sweep["skipped"]:
        print(f"(radius {radius:.3f} m skipped: it captures {count} nodes)")
    print("linear fits against the number of handle nodes (slope in microseconds per handle node):")
    for key, label in SWEEP_FITS.items():
        f = sweep["fits"][key]
        print(f"  {label:<40} slope {1e6 * f['slope_s_per_node']:8.4f} us/node   intercept "
              f"{ms(f['intercept_s'])} ms   R^2 {f['r2']:.3f}")


def judge_targets(results: list[dict]) -> list[dict]:
    verdicts = []
    print("\n== Targets from the issue (coupled step on one core; judged on the mean total time)")
    for size, limit in TARGETS:
        r = next((r for r in results if r["target"] == size), None)
        if r is None:
            print(f"~{size} tets under {1e3 * limit:g} ms: not measured (size not selected)")
            verdicts.append({"target_tets": size, "limit_s": limit, "measured": False})
            continue
        for solver in SOLVERS:
            t = r[solver]["t_total"]
            ok = t["mean"] < limit
            print(f"~{size} tets (actual {r['n_tets']}) under {1e3 * limit:g} ms, {SOLVER_LABELS[solver]:>8}: "
                  f"{'PASS' if ok else 'MISS'}  mean {ms(t['mean'])} ms, min {ms(t['min'])} ms "
                  f"({t['mean'] / limit:.2f}x the target)")
            verdicts.append({"target_tets": size, "limit_s": limit, "measured": True, "actual_tets": r["n_tets"],
                             "solver": solver, "scenario": "settling", "mean_s": t["mean"], "min_s": t["min"],
                             "pass": bool(ok)})
        for solver in MOVING_SOLVERS:
            t = r["moving"][solver]["t_total"]
            ok = t["mean"] < limit
            print(f"~{size} tets (actual {r['n_tets']}) under {1e3 * limit:g} ms, {SOLVER_LABELS[solver]:>8}, moving device: "
                  f"{'PASS' if ok else 'MISS'}  mean {ms(t['mean'])} ms, max {ms(t['max'])} ms ({t['mean'] / limit:.2f}x the target)")
            verdicts.append({"target_tets": size, "limit_s": limit, "measured": True, "actual_tets": r["n_tets"],
                             "solver": solver, "scenario": "moving", "mean_s": t["mean"], "min_s": t["min"],
                             "pass": bool(ok)})
    return verdicts


def plot(results: list[dict], sweep: dict | None, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = {"t_assembly": "#4c72b0", "t_deformable": "#dd8452", "t_schur": "#55a868", "t_other": "#8c8c8c"}
    n = max(len(results), 1)
    fig = plt.figure(figsize=(max(12.0, 3.3 * n + 1.5), 8.6), constrained_layout=True)
    grid = fig.add_gridspec(2, n, height_ratios=[1.15, 1])
    limits = dict(TARGETS)
    for i, r in enumerate(results):
        ax = fig.add_subplot(grid[0, i])
        labels = ["Schur\nCholesky", f"Schur\nreused\n{CG_TOLERANCE:g}", f"Schur\nreused\n{TIGHT_TOLERANCE:g}",
                  f"Schur\nCG\n{CG_TOLERANCE:g}", "mono-\nlithic LU"]
        bars = [r["cholesky"], r["reused_cholesky"], r["reused_tight"], r["cg"]]
        for j, s in enumerate(bars):
            bottom = 0.0
            for key in PHASES:
                value = 1e3 * max(s[key]["mean"], 0.0)
                ax.bar(j, value, bottom=bottom, color=colors[key], width=0.65,
                       label=PHASE_LABELS[key] if i == 0 and j == 0 else None)
                bottom += value
        mono = 1e3 * r["side_by_side"]["monolithic"]["t_total"]["mean"]
        ax.bar(len(bars), mono, color="#c44e52", width=0.65, hatch="//", edgecolor="white",
               label="monolithic (total)" if i == 0 else None)
        totals = [1e3 * s["t_total"]["mean"] for s in bars] + [mono]
        top = max(totals)
        for j, t in enumerate(totals):
            ax.text(j, t + 0.01 * top, f"{t:.0f}" if t >= 100 else f"{t:.3g}", ha="center", va="bottom",
                    fontsize=8)
        if r["target"] in limits:
            ax.axhline(1e3 * limits[r["target"]], color="k", ls="--", lw=1)
            ax.text(-0.45, 1e3 * limits[r["target"]], f"target {1e3 * limits[r['target']]:g} ms",
                    ha="left", va="bottom", fontsize=8,
                    bbox=dict(facecolor="white", edgecolor="none", pad=1, alpha=0.8))
            top = max(top, 1e3 * limits[r["target"]])
        ax.set_ylim(0, 1.12 * top)
        ax.set_xticks(range(len(labels)), labels, fontsize=7)
        ax.set_title(f"{r['n_tets']} tets, {r['n_handle_nodes']} handle nodes\n"
                     f"Schur/monolithic {r['side_by_side']['schur_over_monolithic']:.2f}", fontsize=9)
        if i == 0:
            ax.set_ylabel("ms per step (mean)")
    handles, names = [], []
    for ax in fig.axes:
        h, l = ax.get_legend_handles_labels()
        handles += h
        names += l
    fig.legend(handles, names, loc="outside upper center", ncol=3, fontsize=8, frameon=False,
               title="Haptic Hand: wall-clock cost of one implicit step (dt 1/30 s, one core)",
               title_fontsize=10)

    if sweep and sweep["points"]:
        bottom = grid[1, :].subgridspec(1, 2, width_ratios=[1.3, 1])
        h = np.array([p["n_handle_nodes"] for p in sweep["points"]])
        xs = np.array([h.min(), h.max()])
        panels = (
            (fig.add_subplot(bottom[0]), 1e3, "ms", 1.7,
             (("t_total", "total", "k", "o"), ("t_deformable", "deformable solves", colors["t_deformable"], "o"),
              ("t_schur_coupling", "Schur+coupling (total - deformable)", "#8172b3", "x"),
              ("t_assembly", "assembly (FEM + springs)", colors["t_assembly"], "o"))),
            (fig.add_subplot(bottom[1]), 1e6, "us", 1.35,
             (("t_schur_other", "Schur 6x6 + Aht products, rhs, integration", "#8172b3", "o"),
              ("t_schur", "Schur complement 6x6 (engine's t_schur)", colors["t_schur"], "o"))),
        )
        for ax, scale, unit, headroom, series in panels:
            for key, label, color, marker in series:
                y = scale * np.array([p[key] for p in sweep["points"]])
                f = sweep["fits"][key]
                ax.plot(h, y, marker, color=color, ms=6 if marker == "x" else 4,
                        label=f"{label}: {1e6 * f['slope_s_per_node']:.3g} us/node, R$^2$ {f['r2']:.2f}")
                ax.plot(xs, scale * (f["slope_s_per_node"] * xs + f["intercept_s"]), "-", color=color, lw=1)
            ax.set_ylim(0, ax.get_ylim()[1] * headroom)
            ax.legend(fontsize=7, loc="upper left")
            ax.set_xlabel(f"handle nodes (handle radius {1e3 * sweep['points'][0]['radius']:g}-"
                          f"{1e3 * sweep['points'][-1]['radius']:g} mm)")
            ax.set_ylabel(f"{unit} per step (median)")
        panels[0][0].set_title(f"Cost vs handle nodes: {sweep['n_tets']} tets, Cholesky,\none trajectory replayed for every radius",
                               fontsize=9)
        panels[1][0].set_title("zoom on the handle's share outside\nassembly and deformable solves", fontsize=9)
    else:
        ax = fig.add_subplot(grid[1, :])
        ax.text(0.5, 0.5, f"handle-node sweep not run (needs the ~{SWEEP_SIZE}-tet hand)", ha="center",
                va="center", transform=ax.transAxes)
        ax.set_axis_off()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------------------------------------
# Main
# ------------------------------------------------------------------------------------------


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", help="comma-separated target tet counts out of 350,1700,5000,20000 "
                                        "(default: all; with --quick: 350,1700)")
    parser.add_argument("--steps", type=int, default=None, help="measured steps per run (default 20; --quick: 3)")
    parser.add_argument("--quick", action="store_true", help="fast smoke run: few steps, small hands, 3 radii")
    parser.add_argument("--surface", choices=("auto", "shared", "procedural"), default="auto",
                        help="hand surface: shared hand.obj when present (auto), or the procedural hand")
    parser.add_argument("--remesh", action="store_true", help="tetrahedralize again instead of using the cache")
    parser.add_argument("--out", type=Path, default=OUT_DIR, help="where to write bench_step.json and .png")
    parser.add_argument("--export-meshes", type=Path, default=None, metavar="DIR",
                        help="only write the hands (cached or new) as DIR/hand_<size>.bin for bench/compare_builds "
                             "and exit")
    args = parser.parse_args(argv)

    if args.sizes:
        try:
            sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
        except ValueError:
            parser.error(f"--sizes takes comma-separated integers out of {SIZES}, got {args.sizes!r}")
        unknown = [s for s in sizes if s not in SIZES]
        if unknown or not sizes:
            parser.error(f"--sizes must be out of {','.join(map(str, SIZES))}; got {args.sizes!r}")
    else:
        sizes = [350, 1700] if args.quick else list(SIZES)
    steps = args.steps if args.steps is not None else (3 if args.quick else 20)
    if steps < 1:
        parser.error("--steps must be at least 1")
    warmup = 1 if args.quick else WARMUP_STEPS
    radii = (0.02, 0.03, 0.05) if args.quick else SWEEP_RADII
    sweep_steps = steps if args.quick else max(steps, 40)
    started = time.perf_counter()

    info = machine_info(("native",))
    print_machine(info)

    print("\n== Hands")
    surface = hand_surface(args.surface)
    print(f"surface: {surface[0]} ({len(surface[1])} vertices, {len(surface[2])} triangles), "
          f"palm seed {np.round(surface[3], 4).tolist()} m")
    hands = {}
    for size in sorted(sizes):
        hand = hand_mesh(size, surface, args.remesh)
        hand["target"] = size
        hand["radius"] = handle_radius_for(hand, HANDLE_RADIUS)
        hand["n_handle_nodes"] = native.count_captured(hand["nodes"], hand["seed"], hand["radius"])
        note = "" if hand["radius"] == HANDLE_RADIUS else f" (grown from {1e3 * HANDLE_RADIUS:g} mm to capture >= {MIN_HANDLE_NODES} nodes)"
        origin = "cached" if hand["cached"] else "new"
        print(f"~{size:>5}: {len(hand['tets']):>6} tets {len(hand['nodes']):>6} nodes {hand['n_handle_nodes']:>4} "
              f"handle nodes, handle radius {1e3 * hand['radius']:g} mm{note}; pytetwild {hand['settings']}, "
              f"{origin} {Path(hand['cache']).relative_to(REPO)}")
        hands[size] = hand

    if args.export_meshes:
        args.export_meshes.mkdir(parents=True, exist_ok=True)
        for size, hand in hands.items():
            path = write_tet_mesh(args.export_meshes / f"hand_{size}.bin", hand["nodes"], hand["tets"], hand["seed"])
            print(f"wrote {path}")
        return 0

    print(f"\nsteps: {warmup} warm-up + {steps} measured per run; device frame {1e3 * DEVICE_OFFSET[0]:g} mm "
          f"from the handle, gravity on, dt 1/30 s; CG: Jacobi, tolerance {CG_TOLERANCE:g}, warm started",
          flush=True)
    results = []
    for size in sorted(sizes):
        hand = hands[size]
        r = {"target": size, "n_tets": int(len(hand["tets"])), "n_nodes": int(len(hand["nodes"])),
             "n_handle_nodes": int(hand["n_handle_nodes"]), "handle_radius": hand["radius"],
             "mesh_settings": hand["settings"], "mesh_cache": hand["cache"]}
        positions = {}
        for solver in SOLVERS:
            t0 = time.perf_counter()
            model = make_model(hand, hand["radius"], solver)
            r[solver], r[f"{solver}_steps"], positions[solver] = time_schur(model, warmup, steps)
            print(f"  {r['n_tets']:>6} tets, {SOLVER_LABELS[solver]:>8}: {ms(r[solver]['t_total']['mean'])} ms per step "
                  f"({time.perf_counter() - t0:.1f} s)", flush=True)
        # the two Cholesky runs took the same steps from the same state: how far apart they ended
        moved = np.abs(positions["cholesky"] - hand["nodes"]).max()
        for variant in ("reused_cholesky", "reused_tight"):
            r[f"{variant}_vs_cholesky_position_difference"] = float(
                np.abs(positions[variant] - positions["cholesky"]).max() / max(moved, 1e-300))
        # the moving scenario: the device loops and turns, so the reused factor goes stale
        moving_positions = {}
        r["moving"] = {}
        for variant in MOVING_SOLVERS:
            t0 = time.perf_counter()
            r["moving"][variant], moving_positions[variant] = time_moving(
                make_model(hand, hand["radius"], variant), warmup, max(steps, MOVING_MIN_STEPS))
            print(f"  {r['n_tets']:>6} tets, {SOLVER_LABELS[variant]:>8}, moving device: "
                  f"{ms(r['moving'][variant]['t_total']['mean'])} ms per step ({time.perf_counter() - t0:.1f} s)", flush=True)
        moved = np.abs(moving_positions["cholesky"] - hand["nodes"]).max()
        for variant in MOVING_SOLVERS[1:]:
            r["moving"][f"{variant}_vs_cholesky_position_difference"] = float(
                np.abs(moving_positions[variant] - moving_positions["cholesky"]).max() / max(moved, 1e-300))
        t0 = time.perf_counter()
        r["side_by_side"] = time_side_by_side(make_model(hand, hand["radius"], "cholesky"), warmup, steps)
        print(f"  {r['n_tets']:>6} tets, monolithic: {ms(r['side_by_side']['monolithic']['t_total']['mean'])} ms "
              f"per step, {r['side_by_side']['steps']} steps side by side ({time.perf_counter() - t0:.1f} s)",
              flush=True)
        results.append(r)

    sweep = None
    if SWEEP_SIZE in hands:
        t0 = time.perf_counter()
        sweep = handle_sweep(hands[SWEEP_SIZE], radii, warmup, sweep_steps)
        print(f"  handle-node sweep on the {sweep['n_tets']}-tet hand: {len(sweep['points'])} radii "
              f"({time.perf_counter() - t0:.1f} s)", flush=True)

    print_solver_table(results)
    print_old_vs_new(results)
    print_moving_table(results)
    print_monolithic_table(results)
    if sweep and sweep["fits"]:
        print_sweep(sweep)
    verdicts = judge_targets(results)

    args.out.mkdir(parents=True, exist_ok=True)
    json_path, png_path = args.out / "bench_step.json", args.out / "bench_step.png"
    report = {"machine": info, "settings": {"steps": steps, "warmup": warmup, "cg_tolerance": CG_TOLERANCE,
                                            "tight_tolerance": TIGHT_TOLERANCE,
                                            "device_offset_m": DEVICE_OFFSET.tolist(), "quick": args.quick,
                                            "surface": surface[0], "palm_seed": surface[3].tolist()},
              "hands": results, "handle_sweep": sweep, "targets": verdicts,
              "wall_time_s": time.perf_counter() - started}
    json_path.write_text(json.dumps(report, indent=1))
    plot(results, sweep, png_path)
    print(f"\nwrote {json_path} and {png_path} ({time.perf_counter() - started:.0f} s in all)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
