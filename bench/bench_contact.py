#!/usr/bin/env python3
"""Old vs new contact solve, side by side, on the sample scenes as they are stored.

Runs addon/engine/sample_scenes/<scene>.json (its own hand and body tets, device trajectory,
contact settings) through two builds of the native library, alternating between them in fresh
processes round after round so both see the same machine load, and prints per scene and library
the mean / p95 of the visual step and of its contact part, the Gauss-Seidel sweeps and the share
of frames at the sweep cap, plus physics summaries (largest penetration, mean force on the hand)
that should agree between the two.

Usage:
  .venv/bin/python bench/bench_contact.py --old build/contact_old/libhaptic_hand.so \\
      --new build/contact/libhaptic_hand.so [--scenes bunny_press,letters_push] [--frames N] [--rounds R]

Build the old library from an earlier commit into its own directory, for example:
  git archive <commit> native | tar -x -C /tmp/old && cmake -S /tmp/old/native -B build/contact_old \\
      -DCMAKE_BUILD_TYPE=Release && cmake --build build/contact_old -j2 --target haptic_hand
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SCENES = REPO / "addon" / "engine" / "sample_scenes"
WARMUP = 2  # frames left out (symbolic factorizations, first contacts)


def child(scene_name: str, frames: int) -> None:
    """Runs in a fresh process with HAPTIC_HAND_LIB set: the scene's loop, stats as JSON."""
    from haptic_hand.engine import scene as scenes
    from haptic_hand.engine import simulate

    sc = scenes.load(SCENES / f"{scene_name}.json")
    world, hand, model, others, _ = simulate.build_world(sc)
    inputs = simulate.ScriptedInputs(sc, world, hand, model)
    n = min(frames, int(sc.data.get("frames", frames))) if frames > 0 else int(sc.data["frames"])
    out = []
    for k in range(n):
        inputs.apply((k + 1) * sc.dt, sc.dt)
        s = world.step()
        rec = {key: float(s[key]) for key in ("t_detection", "t_dynamics", "t_contact", "t_total", "residual",
                                              "max_penetration")}
        rec.update(contacts=int(s["contacts"]), iterations=int(s["iterations"]),
                   hand_force=float(np.linalg.norm(world.contact_force(hand))))
        out.append(rec)
    print(json.dumps(out))


def run(lib: str, scene: str, frames: int) -> list[dict]:
    env = dict(os.environ, HAPTIC_HAND_LIB=str(Path(lib).resolve()))
    res = subprocess.run([sys.executable, __file__, "--child", scene, "--frames", str(frames)], env=env,
                         capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def summary(records: list[dict], cap: int) -> dict:
    r = records[WARMUP:]
    col = lambda k: np.array([x[k] for x in r])  # noqa: E731
    return {
        "frames": len(r),
        "total_mean": col("t_total").mean(), "total_p95": np.percentile(col("t_total"), 95),
        "contact_mean": col("t_contact").mean(), "contact_p95": np.percentile(col("t_contact"), 95),
        "detection_mean": col("t_detection").mean(), "dynamics_mean": col("t_dynamics").mean(),
        "contacts": col("contacts").mean(), "sweeps": col("iterations").mean(),
        "at_cap": float(np.mean(col("iterations") >= cap)),
        "max_penetration": col("max_penetration").max(), "hand_force_mean": col("hand_force").mean(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--old", default=str(REPO / "build" / "contact_old" / "libhaptic_hand.so"))
    ap.add_argument("--new", default=os.environ.get("HAPTIC_HAND_LIB", str(REPO / "build" / "native" / "libhaptic_hand.so")))
    ap.add_argument("--scenes", default="bunny_press,letters_push")
    ap.add_argument("--frames", type=int, default=0, help="frames per run (default: the whole scene)")
    ap.add_argument("--rounds", type=int, default=2, help="old/new alternations per scene")
    ap.add_argument("--out", default=str(REPO / "build" / "bench" / "bench_contact.json"))
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child, args.frames)
        return

    sys.path.insert(0, str(Path(__file__).parent))
    from machine import machine_info, print_machine

    print_machine(machine_info())
    print(f"old: {args.old}\nnew: {args.new}\n")
    results = {}
    for scene in args.scenes.split(","):
        cap = json.loads((SCENES / f"{scene}.json").read_text()).get("contact", {}).get("max_iterations", 300)
        runs = {"old": [], "new": []}
        for _ in range(args.rounds):
            for which in ("old", "new"):
                runs[which].append(run(getattr(args, which), scene, args.frames))
        results[scene] = {w: [summary(r, cap) for r in rs] for w, rs in runs.items()}
        print(f"== {scene} ({results[scene]['old'][0]['frames']} frames after {WARMUP} warm-up, "
              f"{args.rounds} rounds alternating; ms mean/p95, best round by mean total)")
        print(f"{'lib':4} {'total':>15} {'rate Hz':>8} {'contact':>15} {'detect':>7} {'dynam':>7} | "
              f"{'contacts':>8} {'sweeps':>7} {'at cap':>6} | {'max pen mm':>10} {'hand F N':>8}")
        best = {}
        for w in ("old", "new"):
            s = min(results[scene][w], key=lambda x: x["total_mean"])
            best[w] = s
            print(f"{w:4} {1e3 * s['total_mean']:7.2f}/{1e3 * s['total_p95']:7.2f} {1 / s['total_mean']:8.1f} "
                  f"{1e3 * s['contact_mean']:7.2f}/{1e3 * s['contact_p95']:7.2f} {1e3 * s['detection_mean']:7.2f} "
                  f"{1e3 * s['dynamics_mean']:7.2f} | {s['contacts']:8.1f} {s['sweeps']:7.1f} {100 * s['at_cap']:5.0f}% | "
                  f"{1e3 * s['max_penetration']:10.4f} {s['hand_force_mean']:8.3f}")
        print(f"new/old: total {best['new']['total_mean'] / best['old']['total_mean']:.2f}, "
              f"contact {best['new']['contact_mean'] / best['old']['contact_mean']:.2f}\n")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"old": args.old, "new": args.new, "results": results}, indent=1, default=float))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
