#!/usr/bin/env python3
"""A soft body's solver, measured: the per-step Cholesky against the reused factor, side by side.

A soft block (a cube of n x n x n cells, six tets each: 384, 2058, 6000 and 20250 tets by
default) rests on the ground. Per size two worlds, identical but for the block's solver:
`cholesky` (its system factored every step, every contact response solved on that factor) and
`reused_cholesky` (an earlier step's warped factor preconditions CG to cg_tolerance and is the
contact response operator, its blocks kept between factorizations; docs/contact.md). Both are
stepped frame by frame in turn, so both see the same machine load. The block drops 0.1 mm onto
the ground and settles (--settle frames); then --frames frames are timed (the engine's own
t_total, one world thread unless --threads).

Physics check: at the end both blocks must rest at the same height (the mean height of their
nodes, within --height-tolerance) and carry their weight (the ground's force within
--force-tolerance of m g, and within it of each other).

Prints per size the ms per frame of each solver (mean, median, slowest: a frame that renews the
reused factor costs about a per-step one), the ratio of the means, the sweeps, the physics summary and whether it agrees, then the rule the sizes support
(one solver everywhere, or a tet count above which the reused factor is faster). Results go to
build/bench/bench_soft_solver.json.

Usage: .venv/bin/python bench/bench_soft_solver.py [--cells 4,7,10,15] [--settle 60] [--frames 60] [--quick]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from machine import REPO, machine_info, print_machine

from haptic_hand.engine import mesh
from haptic_hand.engine import native_world as W

SOLVERS = ("cholesky", "reused_cholesky")
G = 9.81


def make_world(cells: int, solver: str, args) -> tuple[W.World, int]:
    """The ground plane and a cube of `args.size` m made of cells^3 cubes, 0.1 mm above it."""
    world = W.World(dt=args.dt, contact_thickness=1e-3, threads=args.threads)
    world.add_plane([0, 0, 0], [0, 0, 1], friction=0.5)
    half = args.size / 2
    nodes, tets = mesh.structured_box([args.size] * 3, [cells] * 3, (-half, -half, 1e-3 + 1e-4))
    sn, sw = W.vertex_surface(len(nodes))
    block = world.add_soft_body(nodes, tets, sn, sw, mesh.tet_boundary_faces(tets), young_modulus=args.young_modulus,
                                density=args.density)
    if solver != "cholesky":
        world.set_body_solver(block, solver, cg_tolerance=args.cg_tolerance)
    return world, block


def run_size(cells: int, args) -> dict:
    worlds = {s: make_world(cells, s, args) for s in SOLVERS}
    n_tets = 6 * cells**3
    times = {s: [] for s in SOLVERS}
    sweeps = {s: [] for s in SOLVERS}
    for frame in range(args.settle + args.frames):
        for s in SOLVERS:  # (in turn: both under the same load)
            world, _ = worlds[s]
            stats = world.step()
            if frame >= args.settle:
                times[s].append(stats["t_total"])
                sweeps[s].append(stats["iterations"])
    weight = args.density * args.size**3 * G
    out = {"cells": cells, "tets": n_tets, "solvers": {}}
    for s in SOLVERS:
        world, block = worlds[s]
        x, v = world.nodes(block)
        t = np.array(times[s])
        out["solvers"][s] = {
            "ms_mean": 1e3 * t.mean(), "ms_median": 1e3 * float(np.median(t)), "ms_max": 1e3 * t.max(),
            "sweeps": float(np.mean(sweeps[s])), "height": float(x[:, 2].mean()), "speed": float(np.abs(v).max()),
            "force_over_weight": float(world.contact_force(block)[2] / weight),
        }
    c, r = out["solvers"]["cholesky"], out["solvers"]["reused_cholesky"]
    out["ratio"] = r["ms_mean"] / c["ms_mean"]
    out["height_difference"] = abs(r["height"] - c["height"])
    out["force_difference"] = abs(r["force_over_weight"] - c["force_over_weight"])
    out["agree"] = bool(out["height_difference"] <= args.height_tolerance
                        and out["force_difference"] <= args.force_tolerance
                        and all(abs(s["force_over_weight"] - 1) <= args.force_tolerance for s in (c, r)))
    return out


def rule(results: list[dict]) -> str:
    """The default the sizes support: the faster solver at every size, or a tet count above
    which the reused factor wins (the largest size where the per-step factor was faster)."""
    faster = [r["ratio"] < 1 for r in results]
    if all(faster):
        return (f"reused_cholesky was faster at every size measured ({results[0]['tets']} to {results[-1]['tets']} "
                "tets): it supports reused_cholesky as the soft bodies' default")
    if not any(faster):
        return "cholesky was faster at every size measured: it supports cholesky as the soft bodies' default"
    slower = [r["tets"] for r, f in zip(results, faster) if not f]
    return (f"cholesky was faster up to {max(slower)} tets, reused_cholesky above: it supports an `auto` rule with "
            f"the reused factor above ~{max(slower)} tets")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cells", default="4,7,10,15", help="cells per edge of each block (6 n^3 tets)")
    ap.add_argument("--settle", type=int, default=60, help="frames before the timing (the block lands and settles)")
    ap.add_argument("--frames", type=int, default=60, help="timed frames per solver and size")
    ap.add_argument("--quick", action="store_true", help="smoke run: 4 and 7 cells, 20 + 10 frames")
    ap.add_argument("--threads", type=int, default=1, help="the world step's threads (contact.threads)")
    ap.add_argument("--dt", type=float, default=1 / 30)
    ap.add_argument("--size", type=float, default=0.1, help="m, the block's edge")
    ap.add_argument("--young-modulus", type=float, default=1e5, help="Pa")
    ap.add_argument("--density", type=float, default=1000.0, help="kg/m^3")
    ap.add_argument("--cg-tolerance", type=float, default=1e-6, help="the reused factor's CG tolerance")
    ap.add_argument("--height-tolerance", type=float, default=1e-5, help="m: the two rest heights' largest difference")
    ap.add_argument("--force-tolerance", type=float, default=0.01, help="the ground's force: largest relative error")
    ap.add_argument("--out", type=Path, default=REPO / "build" / "bench")
    args = ap.parse_args(argv)
    if args.quick:
        args.cells, args.settle, args.frames = "4,7", 20, 10
    cells = [int(c) for c in args.cells.split(",")]
    info = machine_info()
    print_machine(info)
    print(f"\n== A {100 * args.size:g} cm soft block resting on the ground (E {args.young_modulus:g} Pa, "
          f"{args.density:g} kg/m^3, dt {args.dt:.4g} s, {args.threads} thread(s)): {args.settle} frames to settle, "
          f"{args.frames} timed; ms per frame, the two solvers stepped in turn", flush=True)
    header = (f"{'tets':>6} | {'cholesky mean/median/max':>25} | {'reused mean/median/max':>23} | {'reused/chol':>11} | "
              f"{'sweeps c/r':>10} | {'height diff um':>14} | {'force/weight c, r':>17} | agree")
    print(header)
    print("-" * len(header))
    results = []
    started = time.perf_counter()
    for n in cells:
        r = run_size(n, args)
        results.append(r)
        c, u = r["solvers"]["cholesky"], r["solvers"]["reused_cholesky"]
        print(f"{r['tets']:>6} | {c['ms_mean']:>8.2f}/{c['ms_median']:.2f}/{c['ms_max']:<8.2f} | "
              f"{u['ms_mean']:>7.2f}/{u['ms_median']:.2f}/{u['ms_max']:<7.2f} | "
              f"{r['ratio']:>11.2f} | {c['sweeps']:>4.1f}/{u['sweeps']:<5.1f} | {1e6 * r['height_difference']:>14.3f} | "
              f"{c['force_over_weight']:>8.4f}, {u['force_over_weight']:<7.4f} | {'yes' if r['agree'] else 'NO'}", flush=True)
    verdict = rule(results)
    agree = all(r["agree"] for r in results)
    print(f"\n{verdict}" + ("" if agree else "\nWARNING: the two solvers' rest states disagree at some size (see 'agree')"))
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "bench_soft_solver.json"
    path.write_text(json.dumps({"machine": info, "settings": {k: (str(v) if isinstance(v, Path) else v)
                                                               for k, v in vars(args).items()},
                                "results": results, "rule": verdict, "agree": agree,
                                "wall_time_s": time.perf_counter() - started}, indent=1))
    print(f"wrote {path} ({time.perf_counter() - started:.0f} s)")
    return 0 if agree else 1


if __name__ == "__main__":
    sys.exit(main())
