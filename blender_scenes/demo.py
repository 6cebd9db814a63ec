"""The Blender half of `make demo`: build the bunny scene, bake it headless, render a still of
a contact frame with Workbench and plot the feedback force over time.

    .venv/bin/python blender_scenes/demo.py --out out/demo [--frames N]

Leaves in the output folder: bunny.blend (baked, shape keys), bunny_haptic/bunny/haptic_log.npz,
bunny_contact.png (the render) and bunny_force.png (the plot).
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import common  # noqa: E402


def contact_frame(log: dict, frame_start: int) -> int:
    """The frame with the most contacts between the hand and the other bodies (self-contacts
    between fingers left out): the fullest press."""
    fields = [str(f) for f in log["contact_fields"]]
    stats = log["contact_stats"]
    others = stats[:, fields.index("contacts")] - stats[:, fields.index("self_contacts")]
    return frame_start + 1 + int(np.argmax(others))  # stats row k is the step that ends at frame k + 1


def force_plot(log: dict, path: pathlib.Path, frame: int, frame_start: int) -> pathlib.Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.6))
    if "haptic_t" in log:
        ax.plot(log["haptic_t"], np.linalg.norm(log["haptic_force"], axis=1), lw=0.8, color="tab:red",
                label="|feedback force| at the device (haptic loop)")
    t = log["time"]
    ax.plot(t, np.linalg.norm(log["coupling_wrench"][:, :3], axis=1), "k", lw=1.5,
            label="|spring force| on the handle (per frame)")
    ax.axvline(t[frame - frame_start], color="tab:blue", ls="--", lw=1, label=f"rendered frame {frame}")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("force (N)")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper center", fontsize=8)
    ax.set_title("Hand pressing the soft bunny: force over time")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="out/demo")
    parser.add_argument("--frames", type=int, default=None, help="bake this many frames (default: the scene's)")
    args = parser.parse_args(argv)
    out = pathlib.Path(args.out).resolve()
    haptic_hand = common.import_addon()
    import bpy

    haptic_hand.register()
    try:
        t0 = time.time()
        blend = out / "bunny.blend"
        common.build("bunny", blend)
        s = bpy.context.scene.haptic_hand
        if args.frames:
            s.bake_frame_end = s.bake_frame_start + args.frames
        print(f"blender demo: baking frames {s.bake_frame_start}-{s.bake_frame_end} of {blend.name} ...", flush=True)
        result = bpy.ops.haptic_hand.bake()
        if result != {"FINISHED"}:
            print("blender demo: the bake failed", file=sys.stderr)
            return 1
        bpy.ops.wm.save_mainfile()
        log_path = pathlib.Path(bpy.path.abspath(s.bake_log))
        with np.load(log_path) as f:
            log = dict(f)
        frame = contact_frame(log, s.bake_frame_start)
        scene = bpy.context.scene
        scene.frame_set(frame)
        still = out / "bunny_contact.png"
        scene.render.filepath = str(still)
        bpy.ops.render.render(write_still=True)
        plot = force_plot(log, out / "bunny_force.png", frame, s.bake_frame_start)
        print(f"blender demo done in {time.time() - t0:.0f} s\n"
              f"baked scene: {blend}\nhaptic log:  {log_path}\nrender:      {still} (frame {frame})\n"
              f"force plot:  {plot}")
    finally:
        haptic_hand.unregister()
    return 0


if __name__ == "__main__":
    sys.exit(main())
