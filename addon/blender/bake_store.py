"""A bake in the .blend and its folder: writing a new one over the previous one, and removing
one (Free Bake).

What a bake stores, from the engine's result (haptic_hand.engine.simulate.run):
- the hand and each soft body that moves: one shape key per frame that differs from the rest
  mesh, its value keyed 1 on its frame and 0 on its neighbours (the last key stays at 1, so
  the last frame holds, as a point cache does); or, in PC2 format, a .pc2 file in
  <blend name>_haptic/<scene name>/ played by a Mesh Cache modifier with a relative path;
  a skinned hand plays either without its Armature modifier deforming it again: the Mesh
  Cache comes after the Armature modifiers (it overwrites what they did), shape keys (which
  come before every modifier) turn them off until Free Bake; a hand that moves with its
  armature gets each frame's positions in that frame's object space;
- each rigid body that moves: keyed location and rotation;
- the hand: the force and torque on the handle, and (with the haptic loop) the force felt at
  the device, as keyed custom properties (the Graph Editor shows them);
- the haptic log, <blend name>_haptic/<scene name>/haptic_log.npz, for analysis.
Each scene has its own folder, so two scenes of one .blend never share a file, and the scene
keeps the list of its bake's files (Scene.haptic_hand.baked_files): the next bake and Free
Bake remove them, the caches of objects deleted or unmarked since included, but not a file
another scene's bake uses (a scene copied with its bake shares its files).

A new bake is written aside and swapped in whole, so a failure at any point leaves the
previous bake, and the report "the previous bake is unchanged", true:
1. stage: every file in a staging folder inside the bake folder, every shape key under a
   temporary name, every action unassigned; the scene still shows the previous bake;
2. commit the files: each staged file replaces its namesake (the previous one is kept aside
   until all are in place, and put back if one cannot be);
3. swap in Blender: the previous bake's keys, caches and actions make way for the new ones
   (removals, renames and assignments only); then the previous bake's files the new one does
   not use are deleted (a point cache after a switch to shape keys, ...).
A failure in 1 or 2 undoes what was done so far and raises BakeWriteError.
"""

from __future__ import annotations

import os
import shutil
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import bpy
import numpy as np

from ..engine import bake_formats
from . import armature, meshdata, scene_export
from .actions import assign_action, fcurve, new_action

KEY_PREFIX = "hh_f"
STAGED_KEY_PREFIX = "hh_new_f"
ACTION_PREFIX = "HH bake "
MODIFIER_NAME = "Haptic Hand bake"
LOG_NAME = "haptic_log.npz"
STAGING_PREFIX = ".staging-"
# the keyed custom properties on the hand: name -> (result key, columns, description)
FORCE_PROPERTIES = {
    "hh_force": "Spring force on the handle (N), from the bake",
    "hh_torque": "Spring torque on the handle (N m, about its centre), from the bake",
    "hh_felt_force": "Force felt at the device (N), from the bake's haptic loop",
}
# an object whose every vertex stays within this of its rest place (m) never moves: no keys
STILL = 1e-6
# what one shape key costs in an uncompressed .blend beyond its vertices (12 bytes each): the
# key block and its value's F-curve of 2-3 keyframes (about 1460 bytes on Blender 5.0; a
# compressed .blend, the default, takes about 0.9 of it all; tests/blender/test_bake.py)
KEY_OVERHEAD = 1500


class BakeWriteError(OSError):
    """The new bake could not be written; the previous one is unchanged."""


class BakeSwapError(RuntimeError):
    """The new bake was written but could not be swapped in whole (never expected: the swap
    only removes, renames and assigns); the message says what to do."""


def bake_root() -> Path:
    """<blend folder>/<blend name>_haptic: the .blend's bakes (copy it along with the .blend)."""
    blend = Path(bpy.data.filepath)
    return blend.parent / f"{blend.stem}_haptic"


def cache_dir(scene=None) -> Path:
    """bake_root()/<scene name>: where a scene's haptic log and point caches go."""
    return bake_root() / scene_export._safe((scene or bpy.context.scene).name)


# --------------------------------------------------------------------------------------------
# What the new bake holds (numpy only, nothing in Blender changes)
# --------------------------------------------------------------------------------------------


@dataclass
class Deformed:
    obj: object
    name: str               # engine name
    local: np.ndarray       # (frames, vertices, 3) float32, the mesh's own coordinates
    keyed: np.ndarray       # (frames,) bool: the frames that differ from the rest mesh


@dataclass
class Rigid:
    obj: object
    rest: np.ndarray        # 4x4 world matrix at rest (scene units)
    poses: np.ndarray       # (frames, 7) centre (m) and quaternion (x, y, z, s)


@dataclass
class Plan:
    fmt: str
    frames: np.ndarray
    deformed: list = field(default_factory=list)
    rigid: list = field(default_factory=list)
    curves: dict = field(default_factory=dict)   # custom property -> (frames, 3)
    log: dict = field(default_factory=dict)
    scale: float = 1.0
    still: list = field(default_factory=list)    # names of the objects that never move


def _surface_frames(result: dict, prefix: str) -> np.ndarray:
    """(frames, vertices, 3) render-surface positions in world metres, from the tet nodes."""
    if prefix == "hand":
        positions, tets = result["positions"], result["tets"]
        index, weights = result["surface_tet_index"], result["surface_weights"]
    else:
        key = f"body_{prefix}"
        positions, tets = result[f"{key}_positions"], result[f"{key}_tets"]
        index, weights = result[f"{key}_surface_tet_index"], result[f"{key}_surface_weights"]
    corners = np.asarray(tets)[index]  # (v, 4)
    return np.einsum("vj,fvjk->fvk", weights, positions[:, corners])


def deformed_objects(export: scene_export.Export):
    """(object, engine name, rest matrix) of the meshes a bake deforms: the hand, soft bodies."""
    out = [(export.hand, "hand", export.hand_rest_matrix)]
    out += [(b.obj, b.name, b.rest_matrix) for b in export.bodies if b.role == "SOFT"]
    return out


def plan(export: scene_export.Export, result: dict, fmt: str) -> Plan:
    """The new bake from the engine's result; BakeWriteError if a mesh changed meanwhile."""
    frames = np.arange(export.frame_start, export.frame_end + 1)
    p = Plan(fmt, frames, scale=export.scale, log=bake_formats.haptic_log(result))
    for obj, name, rest in deformed_objects(export):
        world = _surface_frames(result, name)
        if len(obj.data.vertices) != world.shape[1]:
            raise BakeWriteError(f"'{obj.name}' has {len(obj.data.vertices)} vertices now and {world.shape[1]} when "
                                 "the bake started: the mesh changed during the bake; bake again")
        rest_world = meshdata.transform(rest, meshdata.local_vertices(obj.data)) * export.scale
        frames_m = export.hand_matrices if name == "hand" and export.hand_matrices is not None else [rest] * len(world)
        local = np.array([meshdata.transform(np.linalg.inv(m), w / export.scale) for m, w in zip(frames_m, world)])
        # what differs from the rest mesh, in the object's own space (where a key or cache acts)
        moved = np.abs(meshdata.transform(rest, local) * export.scale - rest_world[None]).max(axis=(1, 2))
        if moved.max() <= STILL:
            p.still.append(obj.name)
            continue
        p.deformed.append(Deformed(obj, name, local.astype(np.float32), moved > STILL))
    for b in export.bodies:
        if b.role != "RIGID":
            continue
        poses = np.asarray(result[f"body_{b.name}_pose"], dtype=np.float64)
        if _pose_still(poses):
            p.still.append(b.obj.name)
            continue
        p.rigid.append(Rigid(b.obj, b.rest_matrix, poses))
    wrench = np.asarray(result["coupling_wrench"], dtype=np.float64)
    p.curves = {"hh_force": wrench[:, :3], "hh_torque": wrench[:, 3:6]}
    haptic = result.get("haptic")
    if isinstance(haptic, dict) and len(haptic.get("t", ())):
        # the feedback of the last haptic step by each frame's time (none before the first)
        t, felt = np.asarray(haptic["t"]), np.asarray(haptic["force"])
        last = np.searchsorted(t, np.asarray(result["time"]) + 1e-9, side="right") - 1
        p.curves["hh_felt_force"] = np.where(last[:, None] >= 0, felt[np.maximum(last, 0)], 0.0)
    return p


def _pose_still(poses: np.ndarray) -> bool:
    moved = np.linalg.norm(poses[:, :3] - poses[0, :3], axis=1).max()
    turned = 2 * np.arccos(np.clip(np.abs(poses[:, 3:] @ poses[0, 3:]), 0.0, 1.0)).max()
    return moved <= STILL and turned <= STILL


def keys_size(objects, frames: int) -> int:
    """Bytes a shape-key bake of `frames` frames adds to the .blend for these meshes (at most:
    still objects and frames equal to the rest mesh get no key)."""
    return sum(frames * (12 * len(obj.data.vertices) + KEY_OVERHEAD) for obj in objects)


def pc2_size(objects, frames: int) -> int:
    return sum(32 + frames * 12 * len(obj.data.vertices) for obj in objects)


# --------------------------------------------------------------------------------------------
# Blender data helpers
# --------------------------------------------------------------------------------------------


def _key_curve(frames: np.ndarray, k: int) -> tuple[list, list]:
    """The value curve of frame k's key: 1 on its frame, 0 on the neighbouring frames; the last
    frame's key stays at 1 after it, so the bake holds its last frame."""
    f = float(frames[k])
    if k == len(frames) - 1:
        return [f - 1, f], [0.0, 1.0]
    return [f - 1, f, f + 1], [0.0, 1.0, 0.0]


def fill_key(block, co: np.ndarray) -> None:
    """A shape key's vertex positions (its one write, kept apart so tests can fail it)."""
    block.data.foreach_set("co", np.ascontiguousarray(co, dtype=np.float32).reshape(-1))


def _rigid_curves(obj, rest: np.ndarray, poses: np.ndarray, scale: float):
    """Location and quaternion values per frame of a rigid body's keyed transform."""
    import mathutils

    locations, quats, last = [], [], None
    centre = poses[0, :3]
    for pose in poses:
        m = mathutils.Matrix(meshdata.rigid_matrix(rest, centre, pose, scale).tolist())
        loc, rot, _ = (obj.parent.matrix_world.inverted() @ m if obj.parent else m).decompose()
        if last is not None:
            rot.make_compatible(last)
        last = rot
        locations.append(loc)
        quats.append(rot)
    return np.array(locations), np.array(quats)


# --------------------------------------------------------------------------------------------
# Files: staged, then swapped in
# --------------------------------------------------------------------------------------------


def move(src: Path, dst: Path) -> None:
    """Rename (one call, kept apart so tests can fail it)."""
    os.replace(src, dst)


class StagedFiles:
    """Files written into a staging folder, then moved over their final names together."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.staging = folder / f"{STAGING_PREFIX}{uuid.uuid4().hex[:8]}"
        self.files = {}  # final path -> staged path

    def path(self, name: str) -> tuple[Path, Path]:
        """(staged, final) paths of a file of the bake."""
        self.staging.mkdir(parents=True, exist_ok=True)
        final = self.folder / name
        self.files[final] = self.staging / name
        return self.files[final], final

    def commit(self) -> None:
        """Moves every staged file over its final path; on failure puts everything back."""
        backup = self.staging / "previous"
        backup.mkdir(parents=True, exist_ok=True)
        kept, placed = [], []
        try:
            for final, staged in self.files.items():
                if final.exists():
                    move(final, backup / final.name)
                    kept.append(final)
                move(staged, final)
                placed.append(final)
        except OSError as e:
            for final in placed:
                final.unlink(missing_ok=True)
            for final in kept:
                try:
                    move(backup / final.name, final)
                except OSError:
                    pass
            raise BakeWriteError(f"could not move the new bake's files into {self.folder} ({e})") from None

    def discard(self) -> None:
        shutil.rmtree(self.staging, ignore_errors=True)


def clean_stale_staging(folder: Path) -> None:
    """Staging folders an interrupted bake left behind."""
    if folder.is_dir():
        for old in folder.glob(f"{STAGING_PREFIX}*"):
            shutil.rmtree(old, ignore_errors=True)


# --------------------------------------------------------------------------------------------
# Writing a bake
# --------------------------------------------------------------------------------------------


@dataclass
class Staged:
    """What stage() made in Blender, to commit or to undo."""
    keys: dict = field(default_factory=dict)       # object name -> [blocks]
    made_basis: list = field(default_factory=list)  # objects whose Basis the new bake added
    actions: list = field(default_factory=list)    # (object, action, slot, kind)
    caches: dict = field(default_factory=dict)     # object name -> final .pc2 path
    log_path: Path = None


def write(context, export: scene_export.Export, result: dict, fmt: str) -> str:
    """Replaces the previous bake by the engine's result; returns a summary for the report.
    BakeWriteError (the previous bake unchanged) when anything cannot be written."""
    p = plan(export, result, fmt)
    folder = cache_dir(context.scene)
    clean_stale_staging(folder)
    files = StagedFiles(folder)
    staged = Staged()
    try:
        try:
            stage(p, files, staged, export)
            files.commit()
        except BakeWriteError:
            raise
        except Exception as e:  # keys or actions that cannot be made, a full disk, ...
            raise BakeWriteError(f"{type(e).__name__}: {e}" if not isinstance(e, OSError) else str(e)) from None
    except BakeWriteError:
        _undo(staged)
        files.discard()
        raise
    previous_files = bake_files(context.scene)
    try:
        swap(context, p, staged, export)
    except Exception as e:
        raise BakeSwapError(f"the new bake was only partly swapped in ({type(e).__name__}: {e}): press Free Bake, "
                            "then bake again") from None
    for path in unused(context.scene, previous_files - set(files.files)):
        path.unlink(missing_ok=True)
    files.discard()
    context.view_layer.update()
    kept = f"; nothing stored for {', '.join(p.still)} (never moves)" if p.still else ""
    return (f"Baked frames {export.frame_start}-{export.frame_end} as "
            f"{'point caches' if fmt == 'PC2' else 'shape keys'}{kept}; haptic log: {staged.log_path}")


def stage(p: Plan, files: StagedFiles, staged: Staged, export: scene_export.Export) -> None:
    """Everything of the new bake, aside: files in the staging folder, keys under temporary
    names, actions unassigned."""
    tmp, staged.log_path = files.path(LOG_NAME)
    bake_formats.write_log(tmp, p.log)
    for d in p.deformed:
        if p.fmt == "PC2":
            tmp, final = files.path(f"{scene_export._safe(d.obj.name)}.pc2")
            bake_formats.write_pc2(tmp, d.local, start_frame=float(p.frames[0]))
            staged.caches[d.obj.name] = final
        else:
            _stage_keys(d, p.frames, staged)
    for r in p.rigid:
        locations, quats = _rigid_curves(r.obj, r.rest, r.poses, p.scale)
        action, slot, fcurves = new_action(r.obj, ACTION_PREFIX + r.obj.name)
        staged.actions.append((r.obj, action, slot, "RIGID"))
        for i in range(3):
            fcurve(fcurves, "location", i, p.frames, locations[:, i])
        for i in range(4):
            fcurve(fcurves, "rotation_quaternion", i, p.frames, quats[:, i])
    hand = export.hand
    action, slot, fcurves = new_action(hand, ACTION_PREFIX + hand.name)
    staged.actions.append((hand, action, slot, "FORCES"))
    for name, values in p.curves.items():
        for i in range(3):
            fcurve(fcurves, f'["{name}"]', i, p.frames, values[:, i])


def _stage_keys(d: Deformed, frames: np.ndarray, staged: Staged) -> None:
    obj = d.obj
    blocks = staged.keys.setdefault(obj.name, [])
    if obj.data.shape_keys is None:
        obj.shape_key_add(name="Basis", from_mix=False)
        staged.made_basis.append(obj)
    key = obj.data.shape_keys
    action, slot, fcurves = new_action(key, ACTION_PREFIX + obj.name)
    staged.actions.append((obj, action, slot, "KEYS"))
    for k in np.flatnonzero(d.keyed):
        frame = int(frames[k])
        block = obj.shape_key_add(name=f"{STAGED_KEY_PREFIX}{frame:05d}", from_mix=False)
        blocks.append(block)
        block.value = 0.0
        fill_key(block, d.local[k])
        fcurve(fcurves, f'key_blocks["{KEY_PREFIX}{frame:05d}"].value', 0, *_key_curve(frames, k))


def _undo(staged: Staged) -> None:
    """Removes what stage() made in Blender (never raises)."""
    for _, action, _, _ in staged.actions:
        try:
            bpy.data.actions.remove(action)
        except (ReferenceError, RuntimeError):
            pass
    for name, blocks in staged.keys.items():
        obj = bpy.data.objects.get(name)
        if obj is None or obj.data.shape_keys is None:
            continue
        for block in [b for b in obj.data.shape_keys.key_blocks if b.name.startswith(STAGED_KEY_PREFIX)]:
            obj.shape_key_remove(block)
    for obj in staged.made_basis:
        if obj.data.shape_keys is not None and len(obj.data.shape_keys.key_blocks) <= 1:
            obj.shape_key_clear()


def swap(context, p: Plan, staged: Staged, export: scene_export.Export) -> None:
    """The previous bake makes way for the staged one: removals, renames, assignments."""
    s = context.scene.haptic_hand
    made_basis = {o.name for o in staged.made_basis}
    made_basis |= {o.name for o in context.scene.objects if o.haptic_hand.baked and o.haptic_hand.bake_made_basis}
    free(context, keep_files=True, keep_staged=True)
    for name, blocks in staged.keys.items():
        for block in bpy.data.objects[name].data.shape_keys.key_blocks:
            if block.name.startswith(STAGED_KEY_PREFIX):
                block.name = KEY_PREFIX + block.name[len(STAGED_KEY_PREFIX):]
    for id_data, action, slot, kind in staged.actions:
        if kind == "KEYS":
            id_data.haptic_hand.previous_key_action = assign_action(id_data.data.shape_keys, action, slot)
        elif kind == "RIGID":
            o = id_data.haptic_hand
            link = next(b for b in export.bodies if b.obj == id_data)
            o.rest_matrix = link.rest_matrix.T.reshape(-1).tolist()  # column-major, as Blender's
            o.rest_rotation_mode = id_data.rotation_mode
            o.bake_keyed_transform = True
            o.previous_action = assign_action(id_data, action, slot)
            id_data.rotation_mode = "QUATERNION"
            o.baked = True
        else:  # the forces on the hand
            for name in p.curves:
                id_data[name] = [0.0, 0.0, 0.0]
                id_data.id_properties_ui(name).update(description=FORCE_PROPERTIES[name])
            id_data.haptic_hand.previous_action = assign_action(id_data, action, slot)
            id_data.haptic_hand.baked = True
    for d in p.deformed:
        o = d.obj.haptic_hand
        if d.obj.name in staged.caches:
            _add_mesh_cache(d.obj, staged.caches[d.obj.name], int(p.frames[0]))
        else:  # shape keys act before the modifiers: the Armature modifier would turn them again
            o.bake_muted_modifiers = "\n".join(armature.mute_skinning(d.obj))
        o.baked = True
        o.bake_made_basis = d.obj.name in made_basis
    s.baked, s.baked_format, s.baked_range = True, p.fmt, f"{export.frame_start}-{export.frame_end}"
    s.bake_log = bpy.path.relpath(str(staged.log_path))
    s.baked_files = "\n".join(bpy.path.relpath(str(path)) for path in [staged.log_path, *staged.caches.values()])


def _add_mesh_cache(obj, path: Path, frame_start: int) -> None:
    mod = obj.modifiers.new(MODIFIER_NAME, "MESH_CACHE")
    mod.cache_format = "PC2"
    mod.filepath = bpy.path.relpath(str(path))
    mod.play_mode = "SCENE"
    mod.time_mode = "FRAME"
    mod.frame_start = float(frame_start)
    mod.interpolation = "LINEAR"
    mod.deform_mode = "OVERWRITE"
    mod.forward_axis, mod.up_axis = "POS_Y", "POS_Z"
    armatures = armature.skinning(obj)  # first, or right after the Armature modifiers: it overwrites them
    obj.modifiers.move(len(obj.modifiers) - 1, obj.modifiers.find(armatures[-1].name) + 1 if armatures else 0)


# --------------------------------------------------------------------------------------------
# The stored bake: its files, what is missing, removing it
# --------------------------------------------------------------------------------------------


def bake_files(scene) -> set[Path]:
    """The files the stored bake wrote (its haptic log and point caches, even those of objects
    deleted since), and those its objects' Mesh Cache modifiers play."""
    s = scene.haptic_hand
    out = {Path(bpy.path.abspath(line)) for line in s.baked_files.splitlines() if line}
    if s.bake_log:
        out.add(Path(bpy.path.abspath(s.bake_log)))
    for obj in scene.objects:
        mod = obj.modifiers.get(MODIFIER_NAME) if obj.haptic_hand.baked else None
        if mod is not None and mod.filepath:
            out.add(Path(bpy.path.abspath(mod.filepath)))
    return out


def unused(scene, paths: set[Path]) -> set[Path]:
    """The paths no other scene's bake uses (a scene copied with its bake shares its files)."""
    for other in bpy.data.scenes:
        if other != scene and getattr(other, "haptic_hand", None) is not None:
            paths = paths - bake_files(other)
    return paths


def missing_caches(scene) -> list[tuple[str, str]]:
    """(object, path) of the stored bake's point caches that are not on disk (a .blend copied
    without its _haptic folder)."""
    out = []
    for obj in scene.objects:
        mod = obj.modifiers.get(MODIFIER_NAME) if obj.haptic_hand.baked else None
        if mod is not None and not Path(bpy.path.abspath(mod.filepath)).is_file():
            out.append((obj.name, mod.filepath))
    return out


def _restore_action(id_data, previous) -> bool:
    """Puts back the action id_data had before the bake; True if it had a bake action."""
    ad = id_data.animation_data
    if ad is None or ad.action is None or not ad.action.name.startswith(ACTION_PREFIX):
        return False
    old = ad.action
    ad.action = previous
    bpy.data.actions.remove(old)
    return True


def free(context, keep_files: bool = False, keep_staged: bool = False) -> int:
    """Removes the bake from every object (and its files unless keep_files); returns how many
    objects had one. keep_staged leaves a new bake's staged keys alone."""
    import mathutils

    scene = context.scene
    files = set() if keep_files else unused(scene, bake_files(scene))
    count = 0
    for obj in scene.objects:
        o = obj.haptic_hand
        if not o.baked:
            continue
        count += 1
        key = obj.data.shape_keys if obj.type == "MESH" else None
        if key is not None:
            _restore_action(key, o.previous_key_action)
            for block in [b for b in key.key_blocks if b.name.startswith(KEY_PREFIX)]:
                obj.shape_key_remove(block)
            staged = keep_staged and any(b.name.startswith(STAGED_KEY_PREFIX) for b in key.key_blocks)
            if o.bake_made_basis and not staged and len(key.key_blocks) <= 1:
                obj.shape_key_clear()
        mod = obj.modifiers.get(MODIFIER_NAME)
        if mod is not None:
            obj.modifiers.remove(mod)
        armature.unmute_skinning(obj, o.bake_muted_modifiers.splitlines())
        o.bake_muted_modifiers = ""
        if _restore_action(obj, o.previous_action) and o.bake_keyed_transform:
            obj.rotation_mode = o.rest_rotation_mode or "XYZ"
            obj.matrix_world = mathutils.Matrix(np.array(o.rest_matrix).reshape(4, 4).T.tolist())
        for name in FORCE_PROPERTIES:
            if name in obj.keys():
                del obj[name]
        o.baked, o.bake_made_basis, o.bake_keyed_transform = False, False, False
        o.previous_action = o.previous_key_action = None
    s = scene.haptic_hand
    s.baked, s.baked_format, s.baked_range, s.bake_log, s.baked_files = False, "", "", "", ""
    for path in files:
        path.unlink(missing_ok=True)
    if not keep_files:
        for folder in sorted({path.parent for path in files} | {cache_dir(scene)}) + [bake_root()]:
            clean_stale_staging(folder)
            try:
                folder.rmdir()  # only when empty: other scenes' bakes and the user's files stay
            except OSError:
                pass
    return count
