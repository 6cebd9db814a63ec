"""Whether a simulated hand stayed whole: inverted tets that persist (the hand tore) and flesh
far from the handle's rigid motion (the flesh strayed from the handle). simulate writes the
verdict into the result file and its summary, with the frame it happened."""

from __future__ import annotations

import numpy as np

TEAR_PERSISTS = 0.2  # s: inverted tets for this long are a tear, not a transient of a hard contact
HANDLE_TEAR = ("The input moved the handle faster than the flesh can follow: slow the device trajectory, lower the "
               "virtual coupling stiffness or shorten dt")
SKELETON_TEAR = ("The bones bent or moved further than the tets between them can follow: bend the joints less or more "
                 "slowly (the sample hand's tets invert beyond about 25 degrees at a knuckle), or give the hand finer "
                 "tets at its joints")


def inverted_tets(positions: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Per frame, how many tets have a signed volume <= 0 (positions (F+1, n, 3))."""
    x = np.asarray(positions)
    a = x[:, tets[:, 1]] - x[:, tets[:, 0]]
    b = x[:, tets[:, 2]] - x[:, tets[:, 0]]
    c = x[:, tets[:, 3]] - x[:, tets[:, 0]]
    return (np.einsum("fti,fti->ft", np.cross(a, b), c) <= 0).sum(axis=1)


def first_persistent(flags: np.ndarray, frames_needed: int) -> int:
    """The first frame of the first run of True at least frames_needed long (-1: none)."""
    run = 0
    for k, flag in enumerate(flags):
        run = run + 1 if flag else 0
        if run >= frames_needed:
            return k - run + 1
    return -1


def check(positions: np.ndarray, rest: np.ndarray, tets: np.ndarray, handle_pose: np.ndarray, time: np.ndarray,
          distance: np.ndarray, skeleton: bool = False) -> dict:
    """The verdict: inverted tets per frame, the frame the hand tore (-1: it did not), the frame
    the flesh strayed farther from the handle's rigid motion than the hand is large (-1: never),
    and one warning line for each. distance: per frame, the largest distance of a node from where
    the handle's rigid motion carries it (simulate.flesh_deformation); skeleton: the hand is
    driven by bones (the advice names their targets)."""
    inverted = inverted_tets(positions, tets)
    dt = float(time[1] - time[0]) if len(time) > 1 else 1.0
    torn = first_persistent(inverted > 0, max(2, int(np.ceil(TEAR_PERSISTS / dt - 1e-9))))
    size = float(np.linalg.norm(rest - handle_pose[0, :3], axis=1).max())  # the hand's reach from its handle
    strayed = int(np.argmax(distance > size)) if np.any(distance > size) else -1
    warnings = []
    if torn >= 0:
        warnings.append(f"WARNING: the hand tore at frame {torn} (t = {time[torn]:.3f} s): {inverted[torn]} tets "
                        f"inverted for {TEAR_PERSISTS:.1f} s or more, up to {inverted.max()}, {inverted[-1]} at the "
                        f"end. {SKELETON_TEAR if skeleton else HANDLE_TEAR}")
    if strayed >= 0:
        warnings.append(f"WARNING: the flesh strayed from the handle at frame {strayed} (t = {time[strayed]:.3f} s): "
                        f"a node {distance[strayed]:.3f} m from where the handle's rigid motion carries it, more "
                        f"than the hand's size ({size:.3f} m); up to {distance.max():.3f} m. The input jumped: "
                        "check the device trajectory for a jump")
    return {"inverted_tets": inverted, "torn_frame": torn, "strayed_frame": strayed, "warnings": warnings}
