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

--haptic instead measures the haptic step of a session on each hand (docs/skeleton.md, Section
6): offline, an external device (one frame per bone for the 16 bones) pushed along the same
loop, the cost of every haptic step from the session's log (the step alone: its device read,
the proxies' step against the model, the feedback), the two sessions alternating frame by frame.

    .venv/bin/python bench/bench_skeleton.py --haptic [--frames 60]
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
    ap.add_argument("--haptic", action="store_true", help="measure the haptic step instead")
    ap.add_argument("--frames", type=int, default=60, help="--haptic: visual frames per session")
    args = ap.parse_args()
    stored = np.load(args.tets)
    nodes, tets = stored["nodes"], stored["tets"]
    print_machine(machine_info())
    if args.haptic:
        haptic(nodes, tets, args.frames)
        return
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


def haptic(nodes, tets, frames: int) -> None:
    """Per-step cost of the haptic loop of a 1-bone and a 16-bone session, alternating frames."""
    from haptic_hand.engine import native_session as nsess
    from haptic_hand.engine import native_world as nw

    sessions = {}
    for name, model in (("1 bone", native.HandModel(nodes, tets, palm_seed=mesh.procedural_hand_palm_seed(),
                                                    handle_radius=0.03)),
                        ("16 bones", ns.SkeletonModel(nodes, tets, sk.procedural_hand_skeleton()))):
        world = nw.World(dt=model.params()["dt"])
        sn, sw = nw.vertex_surface(len(nodes))
        hand = world.add_hand(model, sn, sw, mesh.tet_boundary_faces(tets))
        session = nsess.NativeSession(world, hand)
        p, q, _ = world.bone_states(hand)
        if name == "1 bone":
            session.device_external()
        else:
            session.device_external_frames()
        sessions[name] = (world, session, p, q)
    costs = {name: [] for name in sessions}
    for k in range(frames):
        for name, (world, session, p, q) in sessions.items():
            t = world.time()
            offset = LOOP * np.array([np.cos(2 * np.pi * t / PERIOD) - 1.0, np.sin(2 * np.pi * t / PERIOD), 0.0])
            if name == "1 bone":
                session.push_device_pose(p[0] + offset, q[0])
            else:
                session.push_device_frames(p + offset, q)
            session.run_offline(1)
            log = session.read_log()
            if k >= 3:  # (the first frames fault their pages in)
                costs[name].extend(log[:, 2])
    print(f"hand: {len(tets)} tets; haptic steps at 1 kHz, offline, {frames} frames per session, alternating")
    print(f"{'step cost (us)':>16}{'p50':>10}{'p99':>10}{'max':>10}{'steps':>8}")
    p50 = {}
    for name, c in costs.items():
        c = 1e6 * np.asarray(c)
        p50[name] = float(np.median(c))
        print(f"{name:>16}{p50[name]:10.2f}{np.percentile(c, 99):10.2f}{c.max():10.2f}{len(c):8d}")
    print(f"16 bones / 1 bone: {p50['16 bones'] / p50['1 bone']:.1f}x; per bone {p50['16 bones'] / 16:.2f} us")


def many_rest(sim):
    p, q, _, _ = sim.bone_states()
    return p.copy(), q.copy()


if __name__ == "__main__":
    main()
