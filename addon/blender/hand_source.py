"""Where the hand comes from in a Blender scene: the mesh chosen as the hand, its tet mesh and
the palm seed, in world metres, or ExportError naming what is missing and the fix. Below
scene_export (which exports the whole scene) and armature (which reads the skeleton against the
hand's tets)."""

from __future__ import annotations

import numpy as np

from . import meshdata


class ExportError(ValueError):
    """The Blender scene cannot be simulated; the message names the problem and the fix."""


def check_hand(scene, need_seed: bool = True):
    """The hand, its tet object and the seed, or ExportError naming what is missing."""
    s = scene.haptic_hand
    hand = s.hand
    if hand is None:
        raise ExportError("No hand mesh is chosen: pick the hand's mesh in Haptic Hand > Rig > Hand")
    if hand.type != "MESH":
        raise ExportError(f"The hand '{hand.name}' is not a mesh object: pick a mesh in Haptic Hand > Rig > Hand")
    tet_obj = hand.haptic_hand.tet_object
    if not meshdata.has_tets(tet_obj):
        raise ExportError(f"The hand '{hand.name}' has no tet mesh: press Tetrahedralize in Haptic Hand > Rig")
    if need_seed and s.seed is None:
        raise ExportError("No palm seed: press Place Seed in Haptic Hand > Rig (it snaps an empty into the palm)")
    return hand, tet_obj, s.seed


def hand_tets_world(scene):
    """(nodes m, tets) of the hand's tet mesh, world space."""
    _, tet_obj, _ = check_hand(scene, need_seed=False)
    nodes, tets = meshdata.read_tets(tet_obj)
    return meshdata.transform(meshdata.matrix(tet_obj), nodes) * meshdata.unit_scale(scene), tets


def seed_world(scene) -> np.ndarray:
    s = scene.haptic_hand
    return np.array(s.seed.matrix_world.translation, dtype=np.float64) * meshdata.unit_scale(scene)
