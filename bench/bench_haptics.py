"""The live haptic loop's timing under load (issue 37): a live session of the bunny scene with the
simulated user, the visual loop on its threads and the 1 kHz haptic loop on its own, for 60 s
while a competing load keeps every core busy. Prints the distribution of the period's error from
the nominal period, the misses (periods over 1.5x nominal) per minute, the longest gap, the
haptic step's cost, the loop's real-time setup (priority, CPU, memory locked, page faults inside
the loop) and the machine; draws the histograms.

    .venv/bin/python bench/bench_haptics.py [--seconds 60] [--rate 1000] [--load busy|none]
                                            [--threads 2] [--scene bunny_press]

The load (`busy`) is one process per core, each filling, summing and freeing a 32 MB array in a
loop: the cores, the caches and the memory allocator all stay busy, as in a parallel build.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import time
from pathlib import Path

import numpy as np

from machine import REPO, machine_info

from haptic_hand.engine import scene as scenes
from haptic_hand.engine import session

SAMPLES = REPO / "addon" / "engine" / "sample_scenes"
MISS = 1.5  # a period longer than this many nominal periods is a miss


def churn(stop) -> None:
    """One core's share of the competing load: compute and memory traffic until told to stop."""
    while not stop.is_set():
        a = np.empty(4 << 20)  # 32 MB, fresh pages every time
        a.fill(1.0)
        float(a.sum())
        del a


def start_load(kind: str):
    if kind == "none":
        return None, []
    stop = multiprocessing.Event()
    workers = [multiprocessing.Process(target=churn, args=(stop,), daemon=True) for _ in range(os.cpu_count() or 1)]
    for w in workers:
        w.start()
    return stop, workers


def stop_load(stop, workers) -> None:
    if stop is not None:
        stop.set()
    for w in workers:
        w.join(timeout=5)
        if w.is_alive():
            w.terminate()
            w.join()


def run(args) -> dict:
    """One live session of the scene for args.seconds of wall time."""
    sc = scenes.load(SAMPLES / f"{args.scene}.json")
    sc.data["haptics"].update({"enabled": True, "device": "simulated"})
    sc.data["contact"]["threads"] = args.threads
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
    return {"frames": frames, "realtime": realtime, "steps": len(log["t"]), "loop": live.native.loop_info(),
            "period_us": log["period"][1:] * 1e6, "cost_us": log["cost"] * 1e6}


def report(args, r: dict, load: str) -> None:
    nominal = 1e6 / args.rate
    period, cost = r["period_us"], r["cost_us"]
    error = period - nominal
    q = lambda a, p: float(np.percentile(a, p))  # noqa: E731
    minutes = args.seconds / 60
    misses = int((period > MISS * nominal).sum())
    loop = r["loop"]
    refused = f", refused {loop['unlocked_bytes'] / 1e6:.1f} MB (RLIMIT_MEMLOCK)" if loop["unlocked_bytes"] else ""
    cpu = f"{loop['cpu']}{' (isolated)' if loop['cpu_isolated'] else ''}" if loop["cpu"] >= 0 else "not pinned"
    print(f"\nscene {args.scene}, world step on {args.threads} thread(s), load: {load}")
    print(f"{r['steps']} haptic steps and {r['frames']} visual frames in {args.seconds:.0f} s of wall time: "
          f"haptic {r['steps'] / args.seconds:.0f} Hz (nominal {args.rate:.0f}), visual {r['frames'] / args.seconds:.1f} Hz")
    print(f"haptic thread: real-time priority (SCHED_FIFO) {'yes' if r['realtime'] else 'no (needs CAP_SYS_NICE or an rtprio limit)'}; "
          f"CPU {cpu}; memory locked {loop['locked_bytes'] / 1e6:.1f} MB{refused}; "
          f"page faults in the loop: {loop['minor_faults']} minor, {loop['major_faults']} major")
    print(f"period error from {nominal:.0f} us (us): p0.1 {q(error, 0.1):+.1f}  p50 {q(error, 50):+.1f}  "
          f"p99 {q(error, 99):+.1f}  p99.9 {q(error, 99.9):+.1f}  p99.99 {q(error, 99.99):+.1f}  worst {error.max():+.1f}")
    print(f"|error| (us): p50 {q(np.abs(error), 50):.1f}  p99 {q(np.abs(error), 99):.1f}  p99.9 {q(np.abs(error), 99.9):.1f}")
    print(f"misses (period > {MISS * nominal:.0f} us): {misses} in {args.seconds:.0f} s = {misses / minutes:.1f} per minute; "
          f"longest period {period.max() / 1e3:.2f} ms")
    print(f"haptic step cost (us): p50 {q(cost, 50):.2f}  p99 {q(cost, 99):.2f}  worst {cost.max():.2f}")


def plot(args, r: dict, info: dict, load: str) -> None:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    nominal = 1e6 / args.rate
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    axes[0].hist(r["period_us"] - nominal, bins=200, log=True, color="#3a6ea5")
    axes[0].axvline((MISS - 1) * nominal, color="#a55a3a", lw=0.8, label=f"miss: period > {MISS * nominal:.0f} µs")
    axes[0].set_xlabel(f"period − {nominal:.0f} µs (µs)")
    axes[0].set_ylabel("steps")
    axes[0].legend(fontsize=8)
    axes[1].hist(r["cost_us"], bins=200, log=True, color="#3a6ea5")
    axes[1].set_xlabel("haptic step cost (µs)")
    fig.suptitle(f"haptic loop for {args.seconds:.0f} s beside {args.scene}, load {load} ({info.get('cpu', '')})", fontsize=9)
    fig.tight_layout()
    path = out / "haptic_timing.png"
    fig.savefig(path, dpi=110)
    print(f"histograms: {path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--load", choices=("busy", "none"), default="busy")
    ap.add_argument("--threads", type=int, choices=(1, 2), default=2)
    ap.add_argument("--scene", default="bunny_press")
    ap.add_argument("--out", default=str(REPO / "out" / "bench"))
    args = ap.parse_args()

    info = machine_info()
    print("machine:", ", ".join(f"{k}={v}" for k, v in info.items()))
    stop, workers = start_load(args.load)
    load = f"{len(workers)} busy processes (one per core)" if workers else "none"
    try:
        r = run(args)
    finally:
        stop_load(stop, workers)
    print(f"load average after the run: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")
    report(args, r, load)
    plot(args, r, info, load)


if __name__ == "__main__":
    main()
