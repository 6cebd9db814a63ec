#!/usr/bin/env python3
"""The grasp scenes' visual loop (issue 40's target: 60 Hz or more on one core).

- `hand`: the 16-bone grasping hand's ball grasp, `addon/engine/sample_scenes/grasp_ball_hand.json`
  (index finger and thumb close on a soft 4 cm ball, the palm lifts it 3 cm, holds it 2 s, opens);
- `gripper`: the two-finger soft gripper (`haptic_hand.engine.gripper`, 3 bones) on a soft ball,
  the scene of tests/engine/test_grasp.py;
- `one handle`: the grasping hand's tets on the palm handle alone (on the scene's solver), no
  bodies, held still: the one-handle step the ratios are taken against;
- `hand, per-step factor`: the ball grasp with the hand's flesh factored every step
  (`solver.name` cholesky) instead of the scene's reused factor, on one thread.

Each at the visual loop's 1/30 s step, the world on one thread (`contact.threads` 1) and on two,
all in the same process, twice: whole runs one after another (each world has the cache to
itself through its run, as in an application's loop), then all runs alternating step by step
(the machine's load falls on each alike; each step finds the cache filled by the other worlds).
Prints, for each, the median, mean (the loop's rate over the run), 95th percentile and slowest
step, their frame rates, the median's split (dynamics, contact), the share of steps over 1/60 s
(of all the runs' steps, and of the steps over it in every run: the code's cost there, apart
from moments the shared machine spent elsewhere), the ratios to the one-handle step and the
machine; for the hand on one thread, its phases and the steps over 1/60 s in every run, with
their engine's parts in their fastest run (detection, dynamics, contact).

    .venv/bin/python bench/bench_grasp.py [--repeats 3] [--plot docs/images/grasp_steps.png] [--solve-separating]
"""

from __future__ import annotations

import argparse
import copy
import time
from pathlib import Path

import numpy as np

from machine import machine_info, print_machine
from haptic_hand.engine import gripper as gr
from haptic_hand.engine import native_skeleton as ns
from haptic_hand.engine import scene as scenes
from haptic_hand.engine.scene_world import build_world
from haptic_hand.engine.simulate import ScriptedInputs

SCENE = Path(__file__).resolve().parents[1] / "addon" / "engine" / "sample_scenes" / "grasp_ball_hand.json"
THREADS = (1, 2)


def scene_stepper(data: dict, threads: int):
    """A step function of a scene's world (its inputs, then the world's step); returns its stats."""
    data = copy.deepcopy(data)
    data["contact"] = {**data.get("contact", {}), "threads": threads}
    scene = scenes.from_dict(data, SCENE.parent)
    world, hand, model, _, _ = build_world(scene)
    inputs, clock = ScriptedInputs(scene, world, hand, model), [0]

    def step():
        clock[0] += 1
        inputs.apply(clock[0] * scene.dt, scene.dt)
        return world.step()
    return step, world


def gripper_stepper(threads: int):
    w, hand, _ = gr.grasp_world(0.8, threads=threads)
    p0, q0 = w.bone_states(hand)[:2]
    clock = [0]

    def step():
        w.set_bone_targets(hand, np.full(3, ns.PRESCRIBED), gr.grasp_targets(p0, clock[0]), q0)
        clock[0] += 1
        return w.step()
    return step, w


def one_handle(data: dict) -> dict:
    """The grasping hand on its palm handle alone: no bones, no bodies, held at rest."""
    data = copy.deepcopy(data)
    data["hand"]["skeleton"], data["skeleton"], data["bodies"] = None, {}, []
    data["hand"]["palm_seed"] = [0.0, 0.0, -0.03]  # inside the palm slab (mesh.procedural_hand)
    return data


def steppers(hand: dict) -> dict:
    """A fresh step function per (scene, threads)."""
    runs = {}
    for threads in THREADS:
        runs["hand", threads] = scene_stepper(hand, threads)[0]
        runs["gripper", threads] = gripper_stepper(threads)[0]
    runs["one handle", 1] = scene_stepper(one_handle(hand), 1)[0]
    runs["hand, per-step factor", 1] = scene_stepper({**hand, "solver": {"name": "cholesky"}}, 1)[0]
    return runs


def timed(step, walls: list, split: list) -> None:
    t0 = time.perf_counter()
    stats = step()
    walls.append(time.perf_counter() - t0)
    split.append((stats["t_dynamics"], stats["t_contact"], stats["t_detection"]))


def whole_runs(hand: dict, steps: dict, repeats: int) -> tuple[dict, dict]:
    """Each scene's run alone, one after the other, the order repeated: each world keeps the
    cache to itself through its run, as one application's visual loop does."""
    walls, split = {}, {}
    for _ in range(repeats):
        for key, step in steppers(hand).items():
            for _ in range(steps[key[0]]):
                timed(step, walls.setdefault(key, []), split.setdefault(key, []))
    return walls, split


def interleaved(hand: dict, steps: dict, repeats: int) -> tuple[dict, dict]:
    """All runs alternating step by step: the machine's load falls on each alike, and each
    step finds the cache filled by the other worlds."""
    walls, split = {}, {}
    for _ in range(repeats):
        runs = steppers(hand)
        for k in range(max(steps.values())):
            for key, step in runs.items():
                if k < steps[key[0]]:
                    timed(step, walls.setdefault(key, []), split.setdefault(key, []))
    return walls, split


def over_in_every_run(wall: list, frames: int) -> float:
    """The share of steps over 1/60 s in each of the runs (the fastest of a step's runs over it):
    what the code costs there, apart from the moments the shared machine was busy elsewhere."""
    return float(np.mean(np.array(wall).reshape(-1, frames).min(axis=0) > 1 / 60))


def report(title: str, walls: dict, split: dict, steps: dict) -> None:
    base = np.median(walls["one handle", 1])
    print(title)
    for (name, threads), wall in walls.items():
        median, mean, p95, worst = np.median(wall), np.mean(wall), np.percentile(wall, 95), np.max(wall)
        dynamics, contact = np.median(np.array(split[name, threads])[:, :2], axis=0)
        every = over_in_every_run(wall, steps[name])
        print(f"  {name}, {threads} thread(s): median {1e3 * median:.2f} ms ({1 / median:.0f} Hz, "
              f"{median / base:.2f}x one handle), mean {1e3 * mean:.2f} ms (the loop's rate over its run: "
              f"{1 / mean:.0f} Hz), 95th percentile {1e3 * p95:.2f} ms ({1 / p95:.0f} Hz), slowest "
              f"{1e3 * worst:.2f} ms (step {int(np.argmax(wall)) % steps[name]}); dynamics {1e3 * dynamics:.2f} ms, "
              f"contact {1e3 * contact:.2f} ms; over 1/60 s: {np.mean(np.array(wall) > 1 / 60):.0%} of the steps, "
              f"{every:.0%} in every run")


def by_phase(wall: list, hand: dict) -> None:
    """The hand's steps between its keyed targets (close, lift, hold, open), step k ending at k dt."""
    keys = [key["t"] for key in hand["skeleton"]["targets"]] + [hand["frames"] * hand["dt"]]
    frames, end = hand["frames"], np.arange(1, hand["frames"] + 1) * hand["dt"]
    wall = np.array(wall).reshape(-1, frames)
    for t0, t1 in zip(keys[:-1], keys[1:]):
        inside = wall[:, (end > t0 + 1e-9) & (end <= t1 + 1e-9)]
        if inside.size:
            print(f"    t {t0:.1f}-{t1:.1f} s: median {1e3 * np.median(inside):.1f} ms, slowest {1e3 * inside.max():.1f} ms")


def over_in_every(wall: list, split: list, frames: int) -> None:
    """The steps over 1/60 s in every run, each with its fastest run's wall time and its engine's
    parts (detection, dynamics, contact: where the step's time goes)."""
    wall, split = np.array(wall).reshape(-1, frames), np.array(split).reshape(-1, frames, 3)
    run = wall.argmin(axis=0)
    over = [f"{k} ({1e3 * wall[run[k], k]:.1f} ms: detection {1e3 * split[run[k], k, 2]:.1f}, dynamics "
            f"{1e3 * split[run[k], k, 0]:.1f}, contact {1e3 * split[run[k], k, 1]:.1f})"
            for k in np.nonzero(wall.min(axis=0) > 1 / 60)[0]]
    print("  hand, 1 thread, steps over 1/60 s in every run (their fastest run): " + (", ".join(over) or "none"))


def plot_steps(wall: list, hand: dict, path: str) -> None:
    """The hand's steps (one thread, median over the runs) against time, the keyed targets'
    phases shaded, the 1/60 s budget drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    frames, dt = hand["frames"], hand["dt"]
    per_step = 1e3 * np.median(np.array(wall).reshape(-1, frames), axis=0)
    keys = [key["t"] for key in hand["skeleton"]["targets"]] + [frames * dt]
    fig, ax = plt.subplots(figsize=(8, 3.2))
    for k, (t0, t1) in enumerate(zip(keys[:-1], keys[1:])):
        ax.axvspan(t0, t1, color="0.92" if k % 2 else "white", lw=0)
    ax.plot(np.arange(1, frames + 1) * dt, per_step, ".-", color="tab:blue", lw=1, label="visual-loop step")
    ax.axhline(1e3 / 60, color="tab:red", lw=1, ls="--", label="1/60 s")
    ax.set_xlabel("scene time (s); bands: close, settle, lift, hold, open, after")
    ax.set_ylabel("wall time (ms)")
    ax.set_ylim(0, min(60.0, 1.1 * per_step.max()))
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    ax.set_title("16-bone grasp of a soft ball, one thread")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"  wrote {path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3, help="runs of each whole scene per thread count")
    ap.add_argument("--plot", metavar="PNG", help="also draw the hand's steps on one thread against time")
    ap.add_argument("--solve-separating", action="store_true",
                    help="contact.defer_separating off in the hand's scene: every speculative contact solved")
    args = ap.parse_args()
    print_machine(machine_info())
    hand = scenes.load(SCENE).data
    if args.solve_separating:
        hand["contact"] = {**hand.get("contact", {}), "defer_separating": False}
        print("contact.defer_separating: false (every speculative contact solved)")
    steps = {"hand": hand["frames"], "gripper": gr.HELD + gr.OPEN_FOR, "one handle": hand["frames"],
             "hand, per-step factor": hand["frames"]}
    print(f"steps of 1/30 s, x {args.repeats}: hand {steps['hand']}, gripper {steps['gripper']}")
    walls, split = whole_runs(hand, steps, args.repeats)
    report("whole runs, one after another:", walls, split, steps)
    print("  hand, 1 thread, between its keyed targets:")
    by_phase(walls["hand", 1], hand)
    over_in_every(walls["hand", 1], split["hand", 1], hand["frames"])
    if args.plot:
        plot_steps(walls["hand", 1], hand, args.plot)
    report("interleaved step by step:", *interleaved(hand, steps, args.repeats), steps)


if __name__ == "__main__":
    main()
