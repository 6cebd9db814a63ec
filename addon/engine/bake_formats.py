"""Files a bake leaves on disk (pure numpy, no bpy): PC2 point caches, played by Blender's
Mesh Cache modifier, and the haptic log.

PC2 (the point-cache format of 3ds Max, read by Blender): a 32-byte little-endian header
    char[12] "POINTCACHE2\\0", int32 version (1), int32 points, float32 start frame,
    float32 sample rate (frames between samples), int32 samples,
then samples x points x 3 float32 positions, in the mesh's own coordinates.

Both writers are atomic: a file is written under a temporary name and renamed, so a failed
or cancelled bake never leaves a half-written file where the previous one was.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

PC2_SIGNATURE = b"POINTCACHE2\0"
PC2_HEADER = np.dtype([("signature", "S12"), ("version", "<i4"), ("points", "<i4"), ("start", "<f4"),
                       ("rate", "<f4"), ("samples", "<i4")])
# per-frame result arrays every log keeps (docs/scene_format.md); the haptic rows come on top
LOG_KEYS = ("time", "device_pose", "handle_pose", "coupling_wrench", "contact_stats", "contact_fields")


class BakeFormatError(ValueError):
    """A cache file that cannot be written or read; the message says why and what to do."""


def write_pc2(path, frames, start_frame: float = 0.0, sample_rate: float = 1.0) -> Path:
    """Write frames (samples, points, 3) as a PC2 file; returns its path."""
    frames = np.asarray(frames, dtype="<f4")
    if frames.ndim != 3 or frames.shape[2] != 3 or frames.shape[0] < 1:
        raise BakeFormatError(f"PC2 frames must have shape (samples, points, 3), got {frames.shape}")
    if not np.all(np.isfinite(frames)):
        raise BakeFormatError("PC2 frames contain NaN or infinite positions: the simulation diverged; bake again "
                              "with a smaller time step or stiffer coupling")
    header = np.array([(PC2_SIGNATURE, 1, frames.shape[1], start_frame, sample_rate, frames.shape[0])],
                      dtype=PC2_HEADER)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial")
    with open(tmp, "wb") as f:
        f.write(header.tobytes())
        f.write(np.ascontiguousarray(frames).tobytes())
    tmp.replace(path)
    return path


def read_pc2(path) -> tuple[np.ndarray, float, float]:
    """(frames float32 (samples, points, 3), start frame, sample rate) of a PC2 file."""
    raw = Path(path).read_bytes()
    if len(raw) < PC2_HEADER.itemsize:
        raise BakeFormatError(f"{path} is too short to be a PC2 file: bake again")
    header = np.frombuffer(raw[:PC2_HEADER.itemsize], dtype=PC2_HEADER)[0]
    if header["signature"] != PC2_SIGNATURE.rstrip(b"\0") or header["version"] != 1:
        raise BakeFormatError(f"{path} is not a version-1 PC2 file: bake again")
    n, samples = int(header["points"]), int(header["samples"])
    body = np.frombuffer(raw[PC2_HEADER.itemsize:], dtype="<f4")
    if body.size != samples * n * 3:
        raise BakeFormatError(f"{path} holds {body.size} floats, its header promises {samples * n * 3}: the file "
                              "is truncated; bake again")
    return body.reshape(samples, n, 3).copy(), float(header["start"]), float(header["rate"])


def haptic_log(result: dict) -> dict:
    """The log a bake saves: the haptic loop's rows (result["haptic"], one per haptic step)
    when the engine gives them, with the per-frame coupling log either way."""
    log = {k: np.asarray(result[k]) for k in LOG_KEYS if k in result}
    haptic = result.get("haptic")
    if isinstance(haptic, dict):
        for k, v in haptic.items():
            log[f"haptic_{k}"] = np.asarray(v)
    return log


def write_log(path, log: dict) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial.npz")
    np.savez_compressed(tmp, **log)
    tmp.replace(path)
    return path
