"""Command line: `python -m haptic_hand simulate | check-rig | demo` (no Blender needed).

Bad input ends with `error: <what is wrong and the fix>` on stderr and exit code 2 (check-rig:
its report, exit code 1), never a traceback; an interrupt (Ctrl-C, SIGTERM) leaves no partial
file and exits 130."""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
from pathlib import Path

from .engine import rig_check, simulate
from .engine import scene as scenes

SAMPLES = Path(__file__).resolve().parent / "engine" / "sample_scenes"
SAMPLE_SCENE = SAMPLES / "hand_wave.json"
# the skeleton samples the demo runs, each with the title of its per-finger force plot
SKELETON_SAMPLES = {"procedural_hand_close": "The 16-bone procedural hand closing its fingers",
                    "grasp_ball": "A two-finger hand grasping a soft ball and lifting it 3 cm",
                    "pinch_letter": "A two-finger hand pinching a soft letter I (gravity off)",
                    "pinch_letter_hand": "The 16-bone grasping hand pinching a soft letter I (gravity off)",
                    "grasp_ball_hand": "The 16-bone grasping hand lifting a soft 4 cm ball by friction, then dropping it"}
USER_ERRORS = rig_check.USER_ERRORS
EXIT_BAD_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED = 2, 3, 130


def check_output(out: Path, scene_path: Path, scene: scenes.Scene) -> None:
    """Refuses a result path that is a directory or one of the run's inputs (it would be
    replaced by the result)."""
    if out.is_dir():
        raise scenes.SceneError(f"--out {out} is a directory: give a file name, e.g. {out / 'result.npz'}")
    inputs = [("the scene file", scene_path)] + scenes.input_files(scene)
    for what, path in inputs:
        same = out.resolve() == path.resolve() or (out.exists() and path.exists() and os.path.samefile(out, path))
        if same:
            raise scenes.SceneError(f"--out {out} is {what} ({path}), an input of this run: writing the result "
                                    "would replace it; give another file name")


def cmd_simulate(args) -> int:
    scene = scenes.load(args.scene)
    out = Path(args.out)
    check_output(out, Path(args.scene), scene)
    simulate.remove_partial(out)  # left by a run killed while writing
    progress = None if args.quiet else simulate.text_progress
    scenes.load_hand_geometry(scene, (lambda f, m: progress(0.2 * f, m)) if progress else None)
    for warning in scene.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    scenes.check_memory(scene, len(scene.nodes))
    result = simulate.run(scene, progress=progress)
    written = simulate.write(result, out)
    print(simulate.summary(result))
    print(f"result written to {written}")
    return 0


def failed_report(name: str, detail: str) -> dict:
    """check-rig's report of a run that never reached the rig's checks, with the keys of every
    other report."""
    return {"ok": False, "checks": [{"name": name, "ok": False, "detail": detail}], "warnings": []}


def cmd_check_rig(args) -> int:
    try:
        scene = scenes.load(args.scene)
    except USER_ERRORS as e:
        if not args.json:
            raise
        scene = None
        report = failed_report("scene", str(e))
    if scene is not None:
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
    for name, title in SKELETON_SAMPLES.items():
        print(f"\ndemo: {name}.json, a hand driven by a skeleton")
        result = simulate.run(scenes.load(SAMPLES / f"{name}.json"), progress=simulate.text_progress)
        result_path = simulate.write(result, out_dir / f"{name}.npz")
        fingers = plots.finger_force_plot(result, out_dir / f"{name}_fingers.png", title)
        print(simulate.summary(result))
        print(f"result:  {result_path}\nfingers: {fingers}")
    return 0


def _interrupt(signum, frame):
    raise KeyboardInterrupt  # so the write's clean-up runs (SIGTERM's default would skip it)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="haptic_hand", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("simulate", help="run a JSON scene and write a result .npz")
    p.add_argument("scene")
    p.add_argument("--out", required=True, help="result file (.npz)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(fn=cmd_simulate)
    p = sub.add_parser("check-rig", help="check a hand rig: surface, tets, handle, droop, the Schur solve")
    p.add_argument("scene")
    p.add_argument("--json", action="store_true", help="print the report as JSON (always, errors included)")
    p.set_defaults(fn=cmd_check_rig)
    p = sub.add_parser("demo", help="run the bundled sample scenes, write results, a summary and plots")
    p.add_argument("--out", default="out/demo")
    p.set_defaults(fn=cmd_demo)
    args = parser.parse_args(argv)
    as_json = getattr(args, "json", False)
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        return args.fn(args)
    except USER_ERRORS as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("\ninterrupted: nothing written (an earlier result file is unchanged)", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as e:  # a bug: say so plainly; HAPTIC_HAND_TRACEBACK=1 shows where
        if os.environ.get("HAPTIC_HAND_TRACEBACK"):
            raise
        message = f"internal error ({type(e).__name__}: {e}): please report it with the scene file"
        if as_json:
            print(json.dumps(failed_report("internal", message), indent=2))
        print(f"error: {message}", file=sys.stderr)
        return EXIT_INTERNAL
    finally:
        signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
