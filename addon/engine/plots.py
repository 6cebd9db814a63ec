"""Pictures people would rather look at than read: forces over time (the handle's, a skeleton's
per finger), the hand at its most deformed frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def force_plot(result: dict, path: Path | str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = result["time"]
    w = result["coupling_wrench"]
    gap = np.linalg.norm(result["device_pose"][:, :3] - result["handle_pose"][:, :3], axis=1)
    fig, (ax_f, ax_d) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for c, name in enumerate("xyz"):
        ax_f.plot(t, w[:, c], label=f"F{name}")
    ax_f.plot(t, np.linalg.norm(w[:, :3], axis=1), "k", lw=2, label="|F|")
    haptic = result.get("haptic")
    if haptic is not None and len(haptic["t"]):
        # the feedback the device displayed, one point per haptic step (1 kHz)
        ax_f.plot(haptic["t"], np.linalg.norm(haptic["force"], axis=1), color="tab:red", lw=0.8,
                  label="|feedback| (haptic loop)")
    ax_f.set_ylabel("spring force on handle (N)")
    ax_f.legend(loc="center right", ncol=3, fontsize=8)
    ax_f.grid(alpha=0.3)
    ax_d.plot(t, gap * 1000, color="tab:purple")
    ax_d.set_ylabel("device - handle gap (mm)")
    ax_d.set_xlabel("time (s)")
    ax_d.grid(alpha=0.3)
    fig.suptitle("Coupling force between the flesh and the rigid handle")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def hand_plot(result: dict, path: Path | str, frame: int | None = None) -> Path:
    """The render surface at rest and at one frame (default: the most deformed one), with the
    handle nodes marked: a quick look without Blender."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .mesh import interpolate_embedded
    from .quaternion import to_matrix
    from .simulate import flesh_deformation

    if frame is None:
        frame = int(np.argmax(flesh_deformation(result)))
    faces = result["surface_faces"]
    fig = plt.figure(figsize=(10, 5))
    for col, (k, title) in enumerate([(0, "rest"), (frame, f"frame {frame} (t = {result['time'][frame]:.2f} s)")]):
        ax = fig.add_subplot(1, 2, col + 1, projection="3d")
        surf = interpolate_embedded(result["positions"][k], result["tets"], result["surface_tet_index"],
                                    result["surface_weights"])
        ax.plot_trisurf(surf[:, 0], surf[:, 1], surf[:, 2], triangles=faces, color="#e0b8a0",
                        edgecolor="none", alpha=0.6, shade=True)
        for name, kind in zip(result.get("body_names", []), result.get("body_types", [])):
            key = f"body_{name}"
            if kind == "soft":
                pts = interpolate_embedded(result[f"{key}_positions"][k], result[f"{key}_tets"],
                                           result[f"{key}_surface_tet_index"], result[f"{key}_surface_weights"])
            elif kind != "plane":
                pose = result[f"{key}_pose"][k]
                pts = pose[:3] + result[f"{key}_local_vertices"] @ to_matrix(pose[3:]).T
            else:
                continue
            ax.plot_trisurf(pts[:, 0], pts[:, 1], pts[:, 2], triangles=result[f"{key}_faces"], color="#9db4d8",
                            edgecolor="none", alpha=0.8, shade=True)
        handle = result["positions"][k][result["handle_nodes"]]
        ax.scatter(handle[:, 0], handle[:, 1], handle[:, 2], color="tab:green", s=12, label="handle nodes")
        d = result["device_pose"][k, :3]
        ax.scatter([d[0]], [d[1]], [d[2]], color="tab:red", s=40, marker="x", label="device")
        ax.set_title(title)
        extent = [result["rest_nodes"]] + [result[f"body_{n}_positions"][0] for n, t in
                                           zip(result.get("body_names", []), result.get("body_types", [])) if t == "soft"]
        lo, hi = np.min([e.min(0) for e in extent], axis=0) - 0.02, np.max([e.max(0) for e in extent], axis=0) + 0.02
        centre, half = (lo + hi) / 2, (hi - lo).max() / 2
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(centre[2] - half, centre[2] + half)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=20, azim=-130)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")
    fig.axes[0].legend(loc="upper left")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def finger_groups(names, parents) -> dict[str, list[int]]:
    """A skeleton's bones by finger: each root alone, and each child of a root with everything
    below it, named by its first bone without the phalanx number (index_1 -> index)."""
    parents = [int(p) for p in parents]

    def top(b):
        while parents[b] >= 0 and parents[parents[b]] >= 0:
            b = parents[b]
        return b

    groups: dict[str, list[int]] = {}
    for b in range(len(parents)):
        first = top(b)
        groups.setdefault(str(names[first]).rsplit("_", 1)[0] if parents[first] >= 0 else str(names[first]),
                          []).append(b)
    return groups


def finger_force_plot(result: dict, path: Path | str, title: str = "") -> Path:
    """A skeleton run's forces per finger over time: the contacts' push on the finger (its bones'
    regions) and its bones' springs' force, the force its drive holds the flesh with."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = result["time"]
    fig, (ax_c, ax_s) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for name, bones in finger_groups(result["bone_names"], result["bone_parents"]).items():
        contact = np.linalg.norm(result["bone_contact_force"][:, bones].sum(axis=1), axis=1)
        springs = np.linalg.norm(result["bone_wrench"][:, bones, :3].sum(axis=1), axis=1)
        line, = ax_c.plot(t, contact, label=name)
        ax_s.plot(t, springs, color=line.get_color(), label=name)
    ax_c.set_ylabel("contact force on the finger (N)")
    ax_s.set_ylabel("its bones' spring force (N)")
    ax_s.set_xlabel("time (s)")
    for ax in (ax_c, ax_s):
        ax.grid(alpha=0.3)
    ax_c.legend(loc="upper left", ncol=3, fontsize=8)
    fig.suptitle(title or "Forces per finger")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
