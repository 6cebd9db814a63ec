"""Command line: `python -m haptic_hand simulate | check-rig | demo` (no Blender needed)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .engine import mesh as meshing
from .engine import native, rig_check, simulate
from .engine import scene as scenes

SAMPLE_SCENE = Path(__file__).resolve().parent / "engine" / "sample_scenes" / "hand_wave.json"
USER_ERRORS = (scenes.SceneError, meshing.MeshError, native.NativeError, OSError)


def cmd_simulate(args) -> int:
    scene = scenes.load(args.scene)
    result = simulate.run(scene, progress=None if args.quiet else simulate.text_progress)
    out = simulate.write(result, args.out)
    print(simulate.summary(result))
    print(f"result written to {out}")
    return 0


def cmd_check_rig(args) -> int:
    scene = scenes.load(args.scene)
    report = rig_check.check(scene)
    print(json.dumps(report, indent=2) if args.json else rig_check.format_report(report))
    return 0 if report["ok"] else 1


def cmd_demo(args) -> int:
    from .engine import plots

    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    scene = scenes.load(SAMPLE_SCENE)
    print(f"demo: {SAMPLE_SCENE.name} on the procedural hand")
    result = simulate.run(scene, progress=simulate.text_progress)
    result_path = simulate.write(result, out_dir / "hand_wave.npz")
    summary = simulate.summary(result)
    (out_dir / "summary.txt").write_text(summary + "\n")
    plot_path = plots.force_plot(result, out_dir / "coupling_force.png")
    hand_path = plots.hand_plot(result, out_dir / "hand.png")
    print(summary)
    print(f"result:  {result_path}\nsummary: {out_dir / 'summary.txt'}\nforces:  {plot_path}\nhand:    {hand_path}")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="haptic_hand", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("simulate", help="run a JSON scene and write a result .npz")
    p.add_argument("scene")
    p.add_argument("--out", required=True, help="result file (.npz)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(fn=cmd_simulate)
    p = sub.add_parser("check-rig", help="check a hand rig and cross-check the Schur solve")
    p.add_argument("scene")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(fn=cmd_check_rig)
    p = sub.add_parser("demo", help="run the bundled sample scene, write result, summary and plot")
    p.add_argument("--out", default="out/demo")
    p.set_defaults(fn=cmd_demo)
    args = parser.parse_args(argv)
    try:
        return args.fn(args)
    except USER_ERRORS as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
