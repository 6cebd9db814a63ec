"""Pictures people would rather look at than read: forces over time, step-time breakdown."""

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
    ax_f.set_ylabel("spring force on handle (N)")
    ax_f.legend(loc="upper right", ncol=4)
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
