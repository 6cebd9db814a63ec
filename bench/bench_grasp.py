#!/usr/bin/env python3
"""The grasp scene's visual loop (issue 40's target: 60 Hz or more on one core).

The two-finger soft gripper (`haptic_hand.engine.gripper`, 3 bones) closes on a soft ball on the
ground, lifts it 3 cm, holds it 2 s and opens: the scene of tests/engine/test_grasp.py, at the
visual loop's 1/30 s step, the world on one thread (`contact.threads` 1) and on two, the two runs
alternating step by step in the same process so that the machine's load falls on both alike.
Prints the median and the slowest step, their frame rates, the median's split (dynamics, contact)
and the machine.

    .venv/bin/python bench/bench_grasp.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from machine import machine_info, print_machine
from haptic_hand.engine import gripper as gr
from haptic_hand.engine import native_skeleton as ns


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3, help="runs of the whole scene per thread count")
    args = ap.parse_args()
    print_machine(machine_info())
    walls = {1: [], 2: []}
    split = {1: [], 2: []}
    for _ in range(args.repeats):
        runs = {threads: gr.grasp_world(0.8, threads=threads) for threads in walls}
        rest = {threads: runs[threads][0].bone_states(runs[threads][1])[:2] for threads in walls}
        for k in range(gr.HELD + gr.OPEN_FOR):
            for threads, (w, hand, _) in runs.items():
                p0, q0 = rest[threads]
                w.set_bone_targets(hand, np.full(3, ns.PRESCRIBED), gr.grasp_targets(p0, k), q0)
                t0 = time.perf_counter()
                stats = w.step()
                walls[threads].append(time.perf_counter() - t0)
                split[threads].append((stats["t_dynamics"], stats["t_contact"]))
    print(f"grasp scene, {gr.HELD + gr.OPEN_FOR} steps of {gr.DT:.4f} s, x {args.repeats}")
    for threads, wall in walls.items():
        median, p95, worst = np.median(wall), np.percentile(wall, 95), np.max(wall)
        slowest_step = int(np.argmax(wall)) % (gr.HELD + gr.OPEN_FOR)
        dynamics, contact = np.median(np.array(split[threads]), axis=0)
        print(f"  {threads} thread(s): median {1e3 * median:.2f} ms ({1 / median:.0f} Hz), 95th percentile "
              f"{1e3 * p95:.2f} ms ({1 / p95:.0f} Hz), slowest {1e3 * worst:.2f} ms ({1 / worst:.0f} Hz, step "
              f"{slowest_step}); dynamics {1e3 * dynamics:.2f} ms, contact {1e3 * contact:.2f} ms")
    print(f"  ratio 1 thread / 2 threads (median): {np.median(walls[1]) / np.median(walls[2]):.2f}")


if __name__ == "__main__":
    main()
