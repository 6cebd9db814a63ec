#!/usr/bin/env python3
"""Collision detection, old vs new library, side by side, and whether both detect the same.

Runs the scenes of bench_visual.py (the paper-size bunny_press / letters_push with the ~350 or
~1700-tet hand, and the 10x scenes, meshes from build/bench_meshes/) through two builds of the
native library, alternating between them in fresh processes round after round so both see the
same machine load. Per scene and library it prints the mean / median / p95 of the engine's
`t_detection` (detection of all pairs, the hand's self-collision and the patch reduction).

Detection must not change the physics, so the two runs of a scene must agree exactly: per frame
the kept contacts, the self-contacts, the largest penetration and the smallest distance, and at
the end every body's node positions. The script says whether they do (bit for bit).

Usage:
  .venv/bin/python bench/bench_detection.py --old build/h_detect_old/libhaptic_hand.so \\
      --new build/h_detect/libhaptic_hand.so [--cases paper_bunny_1700,10x_bunny] [--frames N] [--rounds R]

  .venv/bin/python bench/bench_detection.py --samples   # the stored sample scenes, bit for bit

Cases: paper_bunny_350, paper_bunny_1700, paper_letters_350, paper_letters_1700, 10x_bunny,
10x_letters (default: paper_bunny_1700, paper_letters_1700, 10x_bunny, 10x_letters).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SCENES = REPO / "addon" / "engine" / "sample_scenes"
WARMUP = 2  # frames left out of the timings (first contacts, caches)
DEFAULT_CASES = "paper_bunny_1700,paper_letters_1700,10x_bunny,10x_letters"
DEFAULT_FRAMES = {"paper": 150, "10x": 20}


def parse_case(case: str) -> tuple[str, str, int]:
    scale, scene, *size = case.split("_")
    scene = {"bunny": "bunny_press", "letters": "letters_push"}[scene]
    return scene, scale, int(size[0]) if size else 17000


def build_case(case: str):
    """The benchmark scene of a case (bench_visual's meshes and settings), its World and its
    scripted inputs."""
    sys.path.insert(0, str(Path(__file__).parent))
    import bench_visual as bv
    from haptic_hand.engine import simulate

    scene_name, scale, n = parse_case(case)
    hand = bv.hand_mesh(n, False)
    bunny = bv.bunny_mesh(271 if scale == "paper" else 2710, False) if scene_name == "bunny_press" else None
    letters = {ch: bv.letter_10x_mesh(ch, False) for ch in "HAPTIC"} if scale == "10x" and bunny is None else None
    scene, _, _ = bv.prepare_scene(scene_name, scale, hand, letters, bunny)
    world, hand_id, model, others, _ = simulate.build_world(scene)
    return scene, world, hand_id, others, simulate.ScriptedInputs(scene, world, hand_id, model)


def child(case: str, frames: int) -> None:
    """Runs in a fresh process with HAPTIC_HAND_LIB set: the case's loop, records as JSON."""
    from haptic_hand.engine import native_world

    scene, world, hand_id, others, inputs = build_case(case)
    records = []
    for k in range(min(frames, scene.frames)):
        inputs.apply((k + 1) * scene.dt, scene.dt)
        s = world.step()
        records.append({key: float(s[key]) for key in s})
    digest = hashlib.sha256()
    bodies = len(others) + 1
    for b in range(bodies):
        kind, n_nodes, n_surface = world.body_kind(b)
        arrays = list(world.nodes(b)) if kind in (native_world.HAND, native_world.SOFT) else []
        if n_surface:
            arrays.append(world.surface(b))
        for a in arrays:
            digest.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    print(json.dumps({"records": records, "state": digest.hexdigest()}))


def dump(case: str, frames: int, path: str) -> None:
    """Writes the case's collision surfaces and their points before each of the first frames
    (as the engine sees them when it detects) for native/tests/test_contact_detection.cpp,
    which checks and times the detection alone on them. Little-endian binary: int32 bodies;
    per body int32 vertices, triangles, points, dynamic, self_collision, then int32 nodes[v][4],
    float64 weights[v][4], int32 triangles[t][3]; int32 thickness-free frame count, per frame
    float64 reach and per body float64 points[p][3]. Frame 0 is the rest configuration."""
    from haptic_hand.engine import native_world

    surfaces = []  # (body index, nodes, weights, faces, dynamic, self_collision) in the order added
    W = native_world.World
    add_hand, add_soft, add_mesh = W.add_hand, W.add_soft_body, W.add_mesh_body

    def hand_(self, model, sn, sw, faces, friction=0.5, self_collision=True):
        i = add_hand(self, model, sn, sw, faces, friction, self_collision)
        surfaces.append((i, np.asarray(sn), np.asarray(sw), np.asarray(faces), 1, int(self_collision)))
        return i

    def soft_(self, nodes, tets, sn, sw, faces, **kw):
        i = add_soft(self, nodes, tets, sn, sw, faces, **kw)
        surfaces.append((i, np.asarray(sn), np.asarray(sw), np.asarray(faces), 1, 0))
        return i

    def mesh_(self, kind, vertices, faces, **kw):
        i = add_mesh(self, kind, vertices, faces, **kw)
        n = len(vertices)
        nodes = np.zeros((n, 4), np.int32)
        nodes[:, 0] = np.arange(n)
        weights = np.zeros((n, 4))
        weights[:, 0] = 1
        surfaces.append((i, nodes, weights, np.asarray(faces), int(kind == native_world.RIGID), 0))
        return i

    W.add_hand, W.add_soft_body, W.add_mesh_body = hand_, soft_, mesh_
    scene, world, hand_id, others, inputs = build_case(case)
    thickness = float(scene.data["contact"]["thickness"])

    def points():
        out, speed = [], 0.0
        for i, *_ in surfaces:
            kind = world.body_kind(i)[0]
            if kind in (native_world.HAND, native_world.SOFT):
                x, v = world.nodes(i)
                speed = max(speed, float(np.abs(v).max()))
            else:
                x = world.surface(i)
                _, _, v, w = world.pose(i)
                speed = max(speed, float(np.linalg.norm(v) + 0.5 * np.linalg.norm(w)))
            out.append(np.ascontiguousarray(x, dtype=np.float64))
        return out, 1.5 * thickness + min(speed * scene.dt, 2 * thickness)

    snaps = [(2 * thickness, points()[0])]  # the rest configuration, with the rest reach
    for k in range(min(frames, scene.frames)):
        inputs.apply((k + 1) * scene.dt, scene.dt)
        x, reach = points()
        snaps.append((reach, x))
        world.step()
    with open(path, "wb") as f:
        f.write(np.int32(len(surfaces)).tobytes())
        for (i, sn, sw, faces, dynamic, self_collision), x in zip(surfaces, snaps[0][1]):
            f.write(np.array([len(sn), len(faces), len(x), dynamic, self_collision], np.int32).tobytes())
            f.write(np.ascontiguousarray(sn, np.int32).tobytes())
            f.write(np.ascontiguousarray(sw, np.float64).tobytes())
            f.write(np.ascontiguousarray(faces, np.int32).tobytes())
        f.write(np.int32(len(snaps)).tobytes())
        for reach, xs in snaps:
            f.write(np.float64(reach).tobytes())
            for x in xs:
                f.write(x.tobytes())
    print(f"wrote {path}: {len(surfaces)} surfaces, {len(snaps)} frames")


def compare_samples(old: str, new: str, names: list[str]) -> bool:
    """The stored sample scenes through `python -m haptic_hand simulate` with both libraries:
    every recorded array (hand and body positions, handle and device poses, coupling wrench,
    contact statistics, iterations) must be bit-identical; only timings and the haptic thread's
    log (real time) may differ."""
    import tempfile

    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            out = {}
            for which, lib in (("old", old), ("new", new)):
                path = Path(tmp) / f"{which}_{name}.npz"
                env = dict(os.environ, HAPTIC_HAND_LIB=str(Path(lib).resolve()))
                res = subprocess.run([sys.executable, "-m", "haptic_hand", "simulate", str(SCENES / f"{name}.json"),
                                      "--out", str(path), "--quiet"], env=env, capture_output=True, text=True)
                if res.returncode != 0:
                    sys.exit(f"{name} with {lib} failed:\n{res.stderr}")
                out[which] = np.load(path)
            a, b = out["old"], out["new"]
            keys = [k for k in a.files if a[k].dtype.kind in "fiub" and not k.startswith("haptic")
                    and "timing" not in k]
            differ = [k for k in keys if k not in b.files or a[k].shape != b[k].shape
                      or not np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f")]
            stats = a["contact_stats"]
            fields = list(a["contact_fields"])
            print(f"{name:15} {len(keys):3d} arrays compared, {len(a['time']) - 1} frames, up to "
                  f"{int(stats[:, fields.index('contacts')].max())} contacts "
                  f"({int(stats[:, fields.index('self_contacts')].max())} self): "
                  f"{'identical' if not differ else 'DIFFERENT: ' + ', '.join(differ)}", flush=True)
            ok = ok and not differ
    return ok


def run(lib: str, case: str, frames: int) -> dict:
    env = dict(os.environ, HAPTIC_HAND_LIB=str(Path(lib).resolve()))
    res = subprocess.run([sys.executable, __file__, "--child", case, "--frames", str(frames)], env=env,
                         capture_output=True, text=True)
    if res.returncode != 0:
        sys.exit(f"{case} with {lib} failed:\n{res.stderr}")
    return json.loads(res.stdout.strip().splitlines()[-1])


SAME = ("contacts", "self_contacts", "max_penetration", "min_distance")


def same_physics(a: dict, b: dict) -> list[str]:
    """What differs between two runs of a case (nothing if detection is unchanged)."""
    diffs = []
    for k, (ra, rb) in enumerate(zip(a["records"], b["records"])):
        for key in SAME:
            if key in ra and ra[key] != rb.get(key):
                diffs.append(f"frame {k} {key}: {ra[key]!r} vs {rb.get(key)!r}")
    if a["state"] != b["state"]:
        diffs.append("final node positions / velocities differ")
    return diffs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--old", default=str(REPO / "build" / "h_detect_old" / "libhaptic_hand.so"))
    ap.add_argument("--new", default=str(REPO / "build" / "h_detect" / "libhaptic_hand.so"))
    ap.add_argument("--cases", default=DEFAULT_CASES)
    ap.add_argument("--frames", type=int, default=0, help="frames per run (default: 150 paper, 20 at 10x)")
    ap.add_argument("--rounds", type=int, default=2, help="old/new alternations per case")
    ap.add_argument("--out", default=str(REPO / "build" / "bench" / "bench_detection.json"))
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--dump", default=None, metavar="FILE",
                    help="only write the first case's surfaces and points for native/tests/test_contact_detection")
    ap.add_argument("--samples", nargs="?", const="bunny_press,finger_squeeze,hand_wave,letters_push", default=None,
                    help="only compare the stored sample scenes run by `haptic_hand simulate` with both libraries "
                         "(default: all four)")
    args = ap.parse_args()
    if args.samples:
        sys.exit(0 if compare_samples(args.old, args.new, args.samples.split(",")) else 1)
    if args.dump:
        dump(args.cases.split(",")[0], args.frames or DEFAULT_FRAMES[parse_case(args.cases.split(",")[0])[1]],
             args.dump)
        return
    if args.child:
        child(args.child, args.frames)
        return

    sys.path.insert(0, str(Path(__file__).parent))
    from machine import machine_info, print_machine

    print_machine(machine_info())
    print(f"old: {args.old}\nnew: {args.new}\n")
    print(f"{'case':20} {'frames':>6} {'old mean/med/p95 ms':>22} {'new mean/med/p95 ms':>22} {'old/new':>7}  same")
    results = {}
    for case in args.cases.split(","):
        frames = args.frames or DEFAULT_FRAMES[parse_case(case)[1]]
        runs = {"old": [], "new": []}
        for _ in range(args.rounds):
            for which in ("old", "new"):
                runs[which].append(run(getattr(args, which), case, frames))
        stats = {}
        for which, rs in runs.items():
            # per frame, the best of the rounds: the load of a shared machine only adds time
            t = np.min([[r["t_detection"] for r in run_["records"][WARMUP:]] for run_ in rs], axis=0)
            stats[which] = {"mean": t.mean(), "median": np.median(t), "p95": np.percentile(t, 95)}
        diffs = [d for r in runs["old"] + runs["new"][1:] for d in same_physics(runs["new"][0], r)]
        frames = len(runs["new"][0]["records"])
        results[case] = {"frames": frames, "stats": stats, "diffs": diffs[:20],
                         "contacts_mean": float(np.mean([r["contacts"] for r in runs["new"][0]["records"]]))}
        fmt = lambda s: f"{1e3 * s['mean']:6.2f}/{1e3 * s['median']:6.2f}/{1e3 * s['p95']:6.2f}"  # noqa: E731
        print(f"{case:20} {frames:6d} {fmt(stats['old']):>22} {fmt(stats['new']):>22} "
              f"{stats['old']['mean'] / stats['new']['mean']:7.2f}  {'yes' if not diffs else 'NO'}", flush=True)
        for d in diffs[:5]:
            print(f"    {d}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"old": args.old, "new": args.new, "results": results}, indent=1,
                                         default=float))
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
