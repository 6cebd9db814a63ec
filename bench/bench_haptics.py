"""The haptic loop's timing (issue 4): a live session of the bunny scene with the simulated
user, the visual loop on one thread and the 1 kHz haptic loop on another, run twice: the world
step on one thread, then on two (its worker thread, contact.threads = 2). Prints the achieved
rate, the period distribution (p50, p99, p99.9, worst) and the haptic step's cost, side by side
with the visual loop's rate, plus the machine; draws the histograms.

    .venv/bin/python bench/bench_haptics.py [--seconds 10] [--rate 1000] [--scene bunny_press]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from machine import REPO, machine_info

from haptic_hand.engine import scene as scenes
from haptic_hand.engine import session

SAMPLES = REPO / "addon" / "engine" / "sample_scenes"


def run(args, threads: int) -> dict:
    """One live session of the scene with the world step on `threads` threads (contact.threads)."""
    sc = scenes.load(SAMPLES / f"{args.scene}.json")
    sc.data["haptics"].update({"enabled": True, "device": "simulated"})
    sc.data["contact"]["threads"] = threads
    live = session.LiveSession(sc, device="simulated", haptic_rate=args.rate)
    live.start()
    frames = 0
    t_end = time.monotonic() + args.seconds
    while time.monotonic() < t_end and live.running:
        if live.poll() is not None:
            frames += 1
        time.sleep(0.005)
    realtime = live.native.status()["realtime"]
    live.stop()
    if live.error:
        raise SystemExit(f"the session stopped: {live.error}")
    log = live.haptic_log()
    return {"threads": threads, "frames": frames, "realtime": realtime, "steps": len(log["t"]),
            "period_us": log["period"][1:] * 1e6, "cost_us": log["cost"] * 1e6}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--scene", default="bunny_press")
    ap.add_argument("--out", default=str(REPO / "out" / "bench"))
    args = ap.parse_args()

    info = machine_info()
    print("machine:", ", ".join(f"{k}={v}" for k, v in info.items()))
    # the world step on one thread and on two (its worker thread beside the haptic thread), in turn
    runs = [run(args, threads) for threads in (1, 2)]
    nominal = 1e6 / args.rate
    q = lambda a, p: float(np.percentile(a, p))  # noqa: E731
    wall = args.seconds
    for r in runs:
        period_us, cost_us = r["period_us"], r["cost_us"]
        print(f"\n-- world step on {r['threads']} thread(s)")
        print(f"scene {args.scene}: {r['steps']} haptic steps and {r['frames']} visual frames in {wall:.1f} s of wall time")
        print(f"haptic thread real-time priority (SCHED_FIFO): {'yes' if r['realtime'] else 'no (needs CAP_SYS_NICE)'}")
        print(f"haptic rate achieved: {r['steps'] / wall:.0f} Hz (nominal {args.rate:.0f} Hz); "
              f"visual loop: {r['frames'] / wall:.1f} Hz")
        print(f"haptic period (us): p50 {q(period_us, 50):.1f}  p99 {q(period_us, 99):.1f}  "
              f"p99.9 {q(period_us, 99.9):.1f}  worst {period_us.max():.1f}  (nominal {nominal:.0f}; "
              f"target: p99.9 within 100 us of it)")
        print(f"haptic step cost (us): p50 {q(cost_us, 50):.2f}  p99 {q(cost_us, 99):.2f}  worst {cost_us.max():.2f} "
              f"(target under 20 us so that 10 kHz fits); ratio period/cost at p50: {q(period_us, 50) / q(cost_us, 50):.0f}x")
    one, two = runs
    print(f"\ntwo threads against one: visual loop {two['frames'] / max(one['frames'], 1):.2f}x the frames; haptic p99.9 "
          f"period {q(two['period_us'], 99.9):.1f} vs {q(one['period_us'], 99.9):.1f} us")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    colors = {1: "#3a6ea5", 2: "#a55a3a"}
    for r in runs:
        label = f"world on {r['threads']} thread{'s' if r['threads'] > 1 else ''}"
        axes[0].hist(r["period_us"], bins=200, log=True, color=colors[r["threads"]], alpha=0.6,
                     label=f"{label}: p99.9 {q(r['period_us'], 99.9):.0f} µs")
        axes[1].hist(r["cost_us"], bins=200, log=True, color=colors[r["threads"]], alpha=0.6,
                     label=f"{label}: median {q(r['cost_us'], 50):.2f} µs")
    axes[0].axvline(nominal, color="k", lw=0.8)
    axes[0].set_xlabel("haptic period (µs)")
    axes[0].set_ylabel("steps")
    axes[1].set_xlabel("haptic step cost (µs)")
    for ax in axes:
        ax.legend(fontsize=8)
    fig.suptitle(f"haptic loop while the visual loop runs {args.scene} ({info.get('cpu', '')})", fontsize=9)
    fig.tight_layout()
    path = out / "haptic_timing.png"
    fig.savefig(path, dpi=110)
    print(f"histograms: {path}")


if __name__ == "__main__":
    main()
