"""Two checkouts of Haptic Hand timed side by side on one mesh: each round runs the hand's step in
a child process of each checkout in turn (its own Python package and native library), so both
see the same machine load; the ratio of their medians is the figure to quote.

    .venv/bin/python bench/compare_checkouts.py OLD_CHECKOUT NEW_CHECKOUT [--mesh M.npz] [--tets 1700]

A checkout is a source tree with its library built (`make native` there). The mesh is a .npz with
`nodes` and `tets` (default: the procedural hand tetrahedralized near --tets by this checkout,
cached in build/bench/). Two scenarios, both with the default parameters and a 30 mm handle: the
device held 1 cm from the handle's rest centre (bench_step.py's, the hand settling under gravity)
and the device waving and turning (bench_step.py's moving scenario). Only the long-standing
Python API is used, so old checkouts can be measured."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys, time
import numpy as np
from haptic_hand.engine import mesh, native

args = json.loads(sys.argv[1])
data = np.load(args["mesh"])
model = native.HandModel(data["nodes"], data["tets"], palm_seed=mesh.procedural_hand_palm_seed(), handle_radius=0.03)
com = np.array(model.info()["handle_com"])
dt = model.params()["dt"]


def turn(w):
    a = float(np.linalg.norm(w))
    return [0.0, 0.0, 0.0, 1.0] if a < 1e-15 else [*(np.sin(a / 2) * w / a), float(np.cos(a / 2))]


out = {}
for scenario in ("held", "moving"):
    sim = native.HandSimulation(model)
    times = []
    for s in range(args["warmup"] + args["steps"]):
        if scenario == "held":
            sim.set_device(com + [0.01, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
        else:
            t = s * dt
            sim.set_device(com + 0.03 * np.array([np.cos(3 * t) - 1, np.sin(3 * t), 0.5 * np.sin(2 * t)]),
                           turn(np.array([0.6 * np.sin(2 * t), 0.4 * np.sin(1.5 * t), 1.5 * t])),
                           [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
        t0 = time.perf_counter()
        sim.step()
        if s >= args["warmup"]:
            times.append(time.perf_counter() - t0)
    out[scenario] = times
print(json.dumps(out))
"""


def package_dir(checkout: Path, scratch: Path) -> Path:
    """A folder whose `haptic_hand` is the checkout's addon/ (the package's source folder)."""
    folder = scratch / checkout.resolve().name.replace("/", "_")
    folder.mkdir(parents=True, exist_ok=True)
    link = folder / "haptic_hand"
    if not link.exists():
        link.symlink_to((checkout / "addon").resolve())
    return folder


def run(checkout: Path, scratch: Path, settings: dict) -> dict:
    env = {"PYTHONPATH": str(package_dir(checkout, scratch)), "PATH": "/usr/bin:/bin",
           "HAPTIC_HAND_LIB": str((checkout / "build" / "native" / "libhaptic_hand.so").resolve()),
           "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", CHILD, json.dumps(settings)], env=env, capture_output=True,
                          text=True, cwd=scratch)
    if done.returncode != 0:
        raise SystemExit(f"{checkout}: the child failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def default_mesh(tets: int) -> Path:
    from haptic_hand.engine import mesh

    path = REPO / "build" / "bench" / f"compare_hand_{tets}.npz"
    if not path.exists():
        v, f = mesh.procedural_hand()
        best = None
        for fac, epsilon in ((0.4, 0.004), (0.3, 0.003), (0.2, 0.002), (0.15, 0.002), (0.1, 0.002)):
            nodes, t = mesh.tetrahedralize(v, f, edge_length_fac=fac, coarsen=True, epsilon=epsilon)
            if best is None or abs(len(t) - tets) < abs(len(best[1]) - tets):
                best = (nodes, t)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, nodes=best[0], tets=best[1])
    return path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path)
    parser.add_argument("new", type=Path)
    parser.add_argument("--mesh", type=Path)
    parser.add_argument("--tets", type=int, default=1700)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--warmup", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args(argv)
    sys.path.insert(0, str(REPO / "bench"))
    from machine import machine_info

    mesh_path = (args.mesh or default_mesh(args.tets)).resolve()
    n_tets = len(np.load(mesh_path)["tets"])
    info = machine_info()
    print(f"# {info['cpu']}, {info['logical_cores']} cores, load {info['load_average']}, {info['date']}")
    print(f"# mesh {mesh_path.name}: {n_tets} tets; {args.rounds} rounds of {args.steps} steps, alternating")
    settings = {"mesh": str(mesh_path), "steps": args.steps, "warmup": args.warmup}
    times = {"old": {"held": [], "moving": []}, "new": {"held": [], "moving": []}}
    with tempfile.TemporaryDirectory() as scratch:
        for r in range(args.rounds):
            order = ("old", "new") if r % 2 == 0 else ("new", "old")
            for name in order:
                result = run(args.old if name == "old" else args.new, Path(scratch), settings)
                for scenario, values in result.items():
                    times[name][scenario].extend(values)
    print(f"{'scenario':10} {'old median ms':>14} {'new median ms':>14} {'new/old':>8}")
    for scenario in ("held", "moving"):
        old, new = np.median(times["old"][scenario]) * 1e3, np.median(times["new"][scenario]) * 1e3
        print(f"{scenario:10} {old:14.3f} {new:14.3f} {new / old:8.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
