#!/usr/bin/env python3
"""The coupled step of a hand of 16 bones against the one-handle step, in one run
(docs/skeleton.md, Section 11; issue 40's target: 16 bones under 3 ms for ~1,700 tets, against
~1.1 ms for one handle).

The rigged procedural hand (the stored sample tets, or --tets file.npz with `nodes`, `tets`),
stepped with the sparse Cholesky solver: the palm-handle model (today's step) and the 16-bone
skeleton model, every bone coupled to a target moving on a small loop, the two alternating
step by step in the same process so that the machine's load falls on both alike. Prints the
median of each part of the step (assembly, the A_t solves, the Schur complement), the ratio
16 bones / 1 bone, and the machine. Only the ratio of one run is meant to be compared.

    .venv/bin/python bench/bench_skeleton.py [--steps 200] [--tets file.npz]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from machine import machine_info, print_machine
from haptic_hand.engine import mesh, native
from haptic_hand.engine import native_skeleton as ns
from haptic_hand.engine import skeleton as sk

SAMPLE = Path(sk.__file__).resolve().parent / "sample_scenes" / "procedural_hand_tets.npz"
PARTS = ("t_assembly", "t_deformable", "t_schur", "t_total")
LOOP = 0.005  # m: the targets' loop radius
PERIOD = 2.0  # s


def targets(sim, rest_p, rest_q, t, modes):
    """Every bone's target on a loop about its rest pose (the root's through set_device)."""
    offset = LOOP * np.array([np.cos(2 * np.pi * t / PERIOD) - 1.0, np.sin(2 * np.pi * t / PERIOD), 0.0])
    if modes is None:
        sim.set_device(rest_p + offset, rest_q, enabled=1)
    else:
        sim.set_bone_targets(modes, rest_p + offset, rest_q)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--tets", type=Path, default=SAMPLE)
    args = ap.parse_args()
    stored = np.load(args.tets)
    nodes, tets = stored["nodes"], stored["tets"]
    print_machine(machine_info())
    one = native.HandModel(nodes, tets, palm_seed=mesh.procedural_hand_palm_seed(), handle_radius=0.03)
    many = ns.SkeletonModel(nodes, tets, sk.procedural_hand_skeleton())
    sims = {"1 bone": native.HandSimulation(one), "16 bones": ns.SkeletonSimulation(many)}
    rest = {"1 bone": (np.array(one.info()["handle_com"]), np.array([0.0, 0.0, 0.0, 1.0]), None),
            "16 bones": (*many_rest(sims["16 bones"]), np.full(16, ns.COUPLED))}
    dt = one.params()["dt"]
    times = {name: {p: [] for p in PARTS} for name in sims}
    for k in range(args.steps + 3):
        for name, sim in sims.items():
            p, q, modes = rest[name]
            targets(sim, p, q, (k + 1) * dt, modes)
            stats = sim.step()
            if k >= 3:  # (the first steps allocate)
                for part in PARTS:
                    times[name][part].append(stats[part])
    held = (many.node_bones() >= 0).sum()
    print(f"hand: {len(tets)} tets, {len(nodes)} nodes; 1 bone holds {len(one.handle_nodes())} nodes, "
          f"16 bones hold {held}; {args.steps} steps each, alternating; sparse Cholesky, one thread")
    print(f"{'median (ms)':>14}" + "".join(f"{p[2:]:>12}" for p in PARTS))
    medians = {name: {p: 1e3 * float(np.median(v)) for p, v in t.items()} for name, t in times.items()}
    for name, m in medians.items():
        print(f"{name:>14}" + "".join(f"{m[p]:12.3f}" for p in PARTS))
    ratio = medians["16 bones"]["t_total"] / medians["1 bone"]["t_total"]
    print(f"16 bones / 1 bone, whole step: {ratio:.2f}x")


def many_rest(sim):
    p, q, _, _ = sim.bone_states()
    return p.copy(), q.copy()


if __name__ == "__main__":
    main()
