"""Hand-tracking streams that drive a skeleton's bones (issue 40; docs/skeleton.md, Section 8).

- Joint layouts: OpenXR's 26 hand joints (XrHandJointEXT order) and MANO's 16, as named joint
  lists with parents, and their maps onto the rigged procedural hand's bones.
- The stream format `haptic_hand.tracking/1` (CSV or JSON of world-frame joint poses over
  time) and its reader, which refuses a bad file with the file, line or frame, joint and fix.
- Retargeting: bone target poses from a stream, keeping the rig's own bone lengths.

Positions in metres, quaternions (x, y, z, w) as everywhere in the project. Pure numpy.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import quaternion as quat
from .skeleton import Skeleton, pose_bones
from .trajectory import Trajectory

FORMAT = "haptic_hand.tracking/1"
CSV_HEADER = ("t", "joint", "x", "y", "z", "qx", "qy", "qz", "qw")
# A quaternion whose norm is off 1 by more than this is refused; within it, it is normalized.
UNIT_TOLERANCE = 1e-3


class TrackingError(ValueError):
    """A tracking stream or joint map that cannot be used; the message says where and the fix."""


@dataclass(frozen=True)
class JointLayout:
    name: str
    joints: tuple[str, ...]
    parents: tuple[int, ...]  # index of each joint's parent, -1 for the root

    def index(self, joint: str) -> int:
        return self.joints.index(joint)


def _openxr() -> JointLayout:
    joints, parents = ["palm", "wrist"], [1, -1]  # OpenXR has no hierarchy: the wrist is our root
    for digit in ("thumb", "index", "middle", "ring", "little"):
        chain = ("metacarpal", "proximal", "distal", "tip") if digit == "thumb" else \
            ("metacarpal", "proximal", "intermediate", "distal", "tip")
        for k, part in enumerate(chain):
            parents.append(1 if k == 0 else len(joints) - 1)
            joints.append(f"{digit}_{part}")
    return JointLayout("openxr", tuple(joints), tuple(parents))


def _mano() -> JointLayout:
    joints, parents = ["wrist"], [-1]
    for digit in ("index", "middle", "pinky", "ring", "thumb"):  # MANO's own order
        for k in range(1, 4):
            parents.append(0 if k == 1 else len(joints) - 1)
            joints.append(f"{digit}{k}")
    return JointLayout("mano", tuple(joints), tuple(parents))


OPENXR = _openxr()
MANO = _mano()
LAYOUTS = {layout.name: layout for layout in (OPENXR, MANO)}


def _procedural_maps() -> dict[str, dict[str, str]]:
    mano = {"wrist": "palm"}
    for digit, bone in (("index", "index"), ("middle", "middle"), ("pinky", "little"), ("ring", "ring"),
                        ("thumb", "thumb")):
        mano.update({f"{digit}{k}": f"{bone}_{k}" for k in range(1, 4)})
    openxr = {"wrist": "palm", "thumb_metacarpal": "thumb_1", "thumb_proximal": "thumb_2",
              "thumb_distal": "thumb_3"}
    for digit in ("index", "middle", "ring", "little"):
        openxr.update({f"{digit}_proximal": f"{digit}_1", f"{digit}_intermediate": f"{digit}_2",
                       f"{digit}_distal": f"{digit}_3"})
    return {"mano": mano, "openxr": openxr}


#: {layout: {joint: bone}} for skeleton.procedural_hand_skeleton(); joints not listed (OpenXR's
#: palm, finger metacarpals and tips) drive no bone.
PROCEDURAL_MAPS = _procedural_maps()


@dataclass
class TrackingStream:
    """World-frame joint poses over time: times (T,), positions (T, J, 3), quaternions
    (T, J, 4), in the layout's joint order; rest_positions (J, 3), rest_quaternions (J, 4)."""

    layout: JointLayout
    times: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray
    rest_positions: np.ndarray
    rest_quaternions: np.ndarray

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Every joint's pose at t: linear in position, slerp in orientation, held at the ends."""
        poses = [Trajectory(self.times, self.positions[:, j], self.quaternions[:, j]).pose(t)
                 for j in range(len(self.layout.joints))]
        return np.array([p for p, _ in poses]), np.array([q for _, q in poses])


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def read(path) -> TrackingStream:
    """A stream from a .csv or .json file (docs/skeleton.md, Section 8)."""
    path = Path(path)
    if path.suffix.lower() not in (".csv", ".json"):
        raise TrackingError(f"{path}: a tracking stream is a .csv or .json file (docs/skeleton.md)")
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise TrackingError(f"{path}: no such file: check the tracking stream's path") from None
    except (OSError, UnicodeDecodeError) as error:
        raise TrackingError(f"{path}: cannot be read as UTF-8 text ({error}): give a CSV or JSON stream") from None
    return (_parse_csv if path.suffix.lower() == ".csv" else _parse_json)(text, str(path))


class _Samples:
    """Collects one layout's samples, one time at a time, with the checks of the format."""

    def __init__(self, layout: JointLayout, where: str):
        self.layout, self.where = layout, where
        self.times, self.frames = [], []
        self.rest = None

    def add(self, t, poses: dict[str, np.ndarray], at: str, rest: bool = False) -> None:
        missing = [j for j in self.layout.joints if j not in poses]
        if missing:
            raise TrackingError(f"{self.where}: {at} lacks joint(s) {', '.join(missing)} of the "
                                f"{self.layout.name} layout: give every joint at every time")
        frame = np.array([poses[j] for j in self.layout.joints])
        if rest:
            self.rest = frame
            return
        if not math.isfinite(t):
            raise TrackingError(f"{self.where}: {at} has time {t}: times must be finite seconds")
        if self.times and not t > self.times[-1]:
            raise TrackingError(f"{self.where}: {at} has time {t} s after {self.times[-1]} s: times must "
                                f"strictly increase (rows of one time kept together)")
        self.times.append(float(t))
        self.frames.append(frame)

    def stream(self) -> TrackingStream:
        if not self.frames:
            raise TrackingError(f"{self.where}: the stream has no samples: give at least one time")
        poses = np.array(self.frames)
        rest = poses[0] if self.rest is None else self.rest
        return TrackingStream(self.layout, np.array(self.times), poses[..., :3], poses[..., 3:], rest[:, :3],
                              rest[:, 3:])


def _pose(values, where: str, joint: str) -> np.ndarray:
    try:
        pose = np.array([float(v) for v in values], dtype=float)
    except (TypeError, ValueError):
        raise TrackingError(f"{where}: joint '{joint}' has a pose {values!r} that is not 7 numbers "
                            f"(x, y, z, qx, qy, qz, qw)") from None
    if pose.shape != (7,):
        raise TrackingError(f"{where}: joint '{joint}' has {pose.size} numbers; a pose is 7 (x, y, z, qx, qy, qz, qw)")
    if not np.isfinite(pose).all():
        raise TrackingError(f"{where}: joint '{joint}' has a non-finite value: give finite metres and quaternions")
    norm = float(np.linalg.norm(pose[3:]))
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise TrackingError(f"{where}: joint '{joint}' has a quaternion of norm {norm:.6g}: give unit quaternions "
                            f"(x, y, z, w)")
    pose[3:] /= norm
    return pose


def _layout(name, where: str) -> JointLayout:
    if name not in LAYOUTS:
        raise TrackingError(f"{where}: layout {name!r} is unknown: use one of {', '.join(LAYOUTS)}")
    return LAYOUTS[name]


def _parse_csv(text: str, where: str) -> TrackingStream:
    lines = text.splitlines()
    if len(lines) < 2 or lines[0].strip() != f"# {FORMAT}":
        raise TrackingError(f"{where}:1: a CSV tracking stream starts with the line '# {FORMAT}'")
    head = lines[1].strip()
    if not head.startswith("# layout:"):
        raise TrackingError(f"{where}:2: the second line must name the layout, e.g. '# layout: openxr'")
    samples = _Samples(_layout(head[len("# layout:"):].strip(), f"{where}:2"), where)
    header_seen, block, block_t, in_rest = False, {}, None, False

    def flush(at):
        if block:
            samples.add(block_t, block, at, rest=in_rest)

    for number, line in enumerate(lines[2:], start=3):
        stripped = line.strip()
        if stripped == "# rest":
            if header_seen and (block or samples.times):
                raise TrackingError(f"{where}:{number}: the rest block must come before the first time")
            in_rest = True
            continue
        if not stripped or stripped.startswith("#"):
            continue
        row = next(csv.reader(io.StringIO(stripped)))
        if not header_seen:
            if tuple(c.strip() for c in row) != CSV_HEADER:
                raise TrackingError(f"{where}:{number}: the header must be '{','.join(CSV_HEADER)}'")
            header_seen = True
            continue
        if len(row) != len(CSV_HEADER):
            raise TrackingError(f"{where}:{number}: {len(row)} fields; a row is {','.join(CSV_HEADER)}")
        try:
            t = float(row[0])
        except ValueError:
            raise TrackingError(f"{where}:{number}: time {row[0]!r} is not a number (seconds)") from None
        joint = row[1].strip()
        if joint not in samples.layout.joints:
            raise TrackingError(f"{where}:{number}: joint '{joint}' is not in the {samples.layout.name} layout "
                                f"(its joints: {', '.join(samples.layout.joints)})")
        if block and (in_rest and joint in block or not in_rest and t != block_t):
            flush(f"line {number - 1}")
            block, in_rest = {}, False
        if joint in block:
            raise TrackingError(f"{where}:{number}: joint '{joint}' appears twice at t = {t}: give each joint once a time")
        block_t = t
        block[joint] = _pose(row[2:], f"{where}:{number}", joint)
    if not header_seen:
        raise TrackingError(f"{where}: no header line '{','.join(CSV_HEADER)}'")
    flush("the end of the file")
    return samples.stream()


def _parse_json(text: str, where: str) -> TrackingStream:
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as error:
        raise TrackingError(f"{where}:{error.lineno}: not valid JSON ({error.msg})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise TrackingError(f"{where}: a JSON tracking stream is an object with \"format\": \"{FORMAT}\"")
    samples = _Samples(_layout(doc.get("layout"), where), where)
    frames = doc.get("frames")
    if not isinstance(frames, list):
        raise TrackingError(f"{where}: \"frames\" must be a list of {{\"t\": seconds, \"poses\": {{joint: pose}}}}")

    def poses_of(entry, at) -> dict:
        if not isinstance(entry, dict):
            raise TrackingError(f"{where}: {at} must be an object {{joint: [x, y, z, qx, qy, qz, qw]}}")
        unknown = [j for j in entry if j not in samples.layout.joints]
        if unknown:
            raise TrackingError(f"{where}: {at} has joint '{unknown[0]}', not in the {samples.layout.name} layout "
                                f"(its joints: {', '.join(samples.layout.joints)})")
        return {j: _pose(p, f"{where}: {at}", j) for j, p in entry.items()}

    if doc.get("rest") is not None:
        samples.add(0.0, poses_of(doc["rest"], "rest"), "rest", rest=True)
    for k, frame in enumerate(frames):
        at = f"frames[{k}]"
        if not isinstance(frame, dict) or not isinstance(frame.get("t"), (int, float)) or isinstance(frame.get("t"), bool):
            raise TrackingError(f"{where}: {at} must be an object with a number \"t\" (seconds) and \"poses\"")
        samples.add(float(frame["t"]), poses_of(frame.get("poses"), f"{at}.poses"), at)
    return samples.stream()


# --------------------------------------------------------------------------------------------
# Writing (for tests and for converting other recordings)
# --------------------------------------------------------------------------------------------


def write(path, stream: TrackingStream, with_rest: bool = True) -> None:
    """Writes a stream as .csv or .json (the reader's format)."""
    path = Path(path)
    joints = stream.layout.joints

    def pose(p, q):
        return [float(v) for v in p] + [float(v) for v in q]

    if path.suffix.lower() == ".json":
        doc = {"format": FORMAT, "layout": stream.layout.name,
               "frames": [{"t": float(t), "poses": {j: pose(p, q) for j, p, q in zip(joints, ps, qs)}}
                          for t, ps, qs in zip(stream.times, stream.positions, stream.quaternions)]}
        if with_rest:
            doc["rest"] = {j: pose(p, q) for j, p, q in zip(joints, stream.rest_positions, stream.rest_quaternions)}
        path.write_text(json.dumps(doc), encoding="utf-8")
        return
    rows = [f"# {FORMAT}", f"# layout: {stream.layout.name}", ",".join(CSV_HEADER)]
    if with_rest:
        rows.append("# rest")
        rows += [",".join(["0", j] + [repr(v) for v in pose(p, q)])
                 for j, p, q in zip(joints, stream.rest_positions, stream.rest_quaternions)]
    for t, ps, qs in zip(stream.times, stream.positions, stream.quaternions):
        rows += [",".join([repr(float(t)), j] + [repr(v) for v in pose(p, q)]) for j, p, q in zip(joints, ps, qs)]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")


# --------------------------------------------------------------------------------------------
# Retargeting: bone targets from a stream
# --------------------------------------------------------------------------------------------


def check_map(layout: JointLayout, skeleton: Skeleton, joint_map: dict[str, str]) -> dict[int, int]:
    """{bone index: joint index}; every bone driven by one joint at most, names checked."""
    out = {}
    for joint, bone in joint_map.items():
        if joint not in layout.joints:
            raise TrackingError(f"joint map: '{joint}' is not a joint of the {layout.name} layout")
        b = skeleton.index(bone) if bone in skeleton.names else None
        if b is None:
            raise TrackingError(f"joint map: joint '{joint}' drives '{bone}', which is not a bone of the skeleton "
                                f"(its bones: {', '.join(skeleton.names)})")
        if b in out:
            raise TrackingError(f"joint map: bone '{bone}' is driven by two joints; map one joint to each bone")
        out[b] = layout.index(joint)
    return out


def bone_targets(stream: TrackingStream, skeleton: Skeleton, coms: np.ndarray, joint_map: dict[str, str], t: float):
    """Each bone's handle target (positions (B, 3) of its centre of mass, quaternions (B, 4)) at
    time t (docs/skeleton.md, Section 4). A root bone follows its joint's rigid motion from the
    stream's rest pose; any other bone turns by its joint's rotation from rest and rides on its
    parent at its head, so the rig keeps its own bone lengths. A bone with no joint moves with
    its parent (a root with no joint stays at rest). coms: the bones' rest centres of mass."""
    driven = check_map(stream.layout, skeleton, joint_map)
    p_now, q_now = stream.pose(t)
    turns, heads = [None] * len(skeleton), [None] * len(skeleton)
    for b, j in driven.items():
        turns[b] = quat.multiply(q_now[j], quat.conjugate(stream.rest_quaternions[j]))
        if skeleton.parents[b] < 0:  # the joint's rigid motion carries the root's head
            heads[b] = p_now[j] + quat.to_matrix(turns[b]) @ (np.asarray(skeleton.bones[b].head, dtype=float)
                                                               - stream.rest_positions[j])
    return pose_bones(skeleton, np.asarray(coms, dtype=float), turns, heads)
