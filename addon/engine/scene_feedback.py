"""A skeleton hand's haptic feedback in a scene (docs/skeleton.md, Section 8; docs/haptics.md, "A
skeleton hand"): what the haptic loop renders (`haptics.feedback`: the palm's wrench, one per
bone, or one per group of bones), the groups (`haptics.groups`), and which devices a skeleton
hand's session takes (a glove of one frame per bone; with skeleton.root_device one frame on the
wrist, rendering the palm's wrench), checked against the hand's skeleton with messages that name the field and
the fix."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from . import skeleton as sk
from .scene_fields import SceneError
from .scene_skeleton import SKELETON_FIELD, SceneSkeleton

PALM, BONES, GROUPS = "palm", "bones", "groups"
#: The devices of one frame per bone: the simulated glove user and a glove whose frames a host pushes
#: (with skeleton.root_device every device is one frame on the wrist, the fingers posed on it).
GLOVES = ("simulated", "external")
ROOT_DEVICE = "skeleton.root_device"


@dataclass
class Feedback:
    mode: str = PALM
    group_of_bone: np.ndarray | None = None  # (B,) each bone's group, -1 for none (mode "groups")
    group_names: list = field(default_factory=list)


def parse(data: dict, rig: SceneSkeleton | None) -> Feedback:
    """The scene's feedback; SceneError for settings the hand cannot render."""
    h = data["haptics"]
    mode, groups = h["feedback"], h["groups"]
    if groups is not None and mode != GROUPS:
        raise SceneError(f'haptics.groups is given but haptics.feedback is "{mode}": set haptics.feedback to '
                         f'"{GROUPS}", or remove haptics.groups')
    n_bones = 1 if rig is None else len(rig.skeleton)
    if mode != PALM and n_bones == 1:
        hand = (f"{SKELETON_FIELD} is null (the palm handle)" if rig is None
                else f"{SKELETON_FIELD} has one bone, whose session is the palm handle's")
        raise SceneError(f'haptics.feedback = "{mode}" needs a skeleton hand of several bones, and {hand}: set '
                         f'haptics.feedback to "{PALM}", or give {SKELETON_FIELD} its bones')
    if n_bones > 1 and h["enabled"]:
        check_glove_session(h["device"], rig, mode)
    if mode != GROUPS:
        return Feedback(mode)
    of_bone, names = default_groups(rig.skeleton) if groups is None else listed_groups(groups, rig.skeleton)
    return Feedback(mode, of_bone, names)


def check_glove_session(device: str, rig: SceneSkeleton, mode: str) -> None:
    """A skeleton hand's session: a device of one frame per bone, or with skeleton.root_device a
    one-frame device on the wrist rendering the palm's wrench; and every bone driven."""
    kind = device.split(":", 1)[0]
    if rig.root_device and mode != PALM:
        raise SceneError(f'haptics.feedback = "{mode}" renders a wrench per bone, but with {ROOT_DEVICE} the device '
                         f"'{device}' is one frame on the wrist, which renders the whole hand's wrench: set "
                         f'haptics.feedback to "{PALM}", or set {ROOT_DEVICE} to false for a glove of one frame '
                         "per bone ('simulated' or 'external')")
    if not rig.root_device and kind not in GLOVES:
        raise SceneError(f"haptics.device '{device}' has one frame, and a skeleton hand's session has a device frame "
                         f"per bone: set {ROOT_DEVICE} to true (the device drives the wrist and the fingers are "
                         f"posed on it), or use 'simulated' (the simulated glove user) or 'external' (a glove whose "
                         f"frames a host pushes), or set haptics.enabled to false")
    free = np.flatnonzero(rig.drive_scales == 0)
    if len(free):
        b = int(free[0])
        raise SceneError(f"{SKELETON_FIELD}[{b}] ('{rig.skeleton.names[b]}').drive_scale = 0 frees the bone, but in a "
                         "haptic session every bone follows its own device frame: set its drive_scale above 0, or "
                         "haptics.enabled to false")


def default_groups(skeleton: sk.Skeleton) -> tuple[np.ndarray, list[str]]:
    """The wrist and the digits (Skeleton.feedback_groups); refused for a skeleton with no digit."""
    if (skeleton.parents < 0).all():
        example = json.dumps({name: [name] for name in skeleton.names[:2]})
        raise SceneError(f'haptics.feedback = "{GROUPS}" with haptics.groups null groups the wrist and the digits '
                         f"(the chains of bones leaving a root), but no bone of {SKELETON_FIELD} has a parent, so it "
                         f'has no digit: list the groups in haptics.groups, e.g. {example}, or set haptics.feedback to '
                         f'"{BONES}"')
    return skeleton.feedback_groups()


def listed_groups(groups, skeleton: sk.Skeleton) -> tuple[np.ndarray, list[str]]:
    """{group name: [bone names]}: each bone's group in the object's order (-1: in none)."""
    if not isinstance(groups, dict) or not groups:
        example = json.dumps({"index": [n for n in skeleton.names if n.startswith("index")] or skeleton.names[-1:]})
        raise SceneError(f"haptics.groups = {json.dumps(groups)[:60]} is invalid: give an object {{group name: [bone "
                         f"names]}}, e.g. {example}, or null for the wrist and the digits")
    of_bone = np.full(len(skeleton), -1, dtype=np.int32)
    for g, (name, bones) in enumerate(groups.items()):
        at = f"haptics.groups.{name}"
        if not isinstance(bones, list) or not bones or not all(isinstance(b, str) for b in bones):
            raise SceneError(f"{at} = {json.dumps(bones)[:60]} is invalid: give a non-empty list of bone names")
        for bone in bones:
            _put(of_bone, list(groups), g, bone, at, skeleton)
    return of_bone, list(groups)


def _put(of_bone: np.ndarray, names: list, g: int, bone: str, at: str, skeleton: sk.Skeleton) -> None:
    if bone not in skeleton.names:
        raise SceneError(f"{at} names '{bone}', which is not a bone of {SKELETON_FIELD} (its bones: "
                         f"{', '.join(skeleton.names)})")
    b = skeleton.index(bone)
    if of_bone[b] == g:
        raise SceneError(f"{at} names bone '{bone}' twice: name it once")
    if of_bone[b] >= 0:
        raise SceneError(f"haptics.groups: bone '{bone}' is in group '{names[of_bone[b]]}' and in group '{names[g]}': "
                         "a bone's feedback goes to one group: remove it from one of them")
    of_bone[b] = g
