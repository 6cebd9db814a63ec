"""Authoring the hand rig: choose the hand, tetrahedralize a mesh (hand or soft body), place
the palm seed, count the nodes the handle captures, check the rig with the engine."""

from __future__ import annotations

import bpy
import numpy as np

from ..engine import mesh as meshing
from ..engine import native
from . import meshdata, scene_export

SEED_NAME = "Palm seed"


def _mesh_poll(context) -> bool:
    obj = context.active_object
    return obj is not None and obj.type == "MESH" and not obj.haptic_hand.is_tet_mesh and context.mode == "OBJECT"


def captured_count(scene) -> int:
    """Tet nodes of the hand within the handle radius of the seed, counted by the engine
    (native.count_captured, the rule the handle itself uses); -1 when the rig is incomplete."""
    s = scene.haptic_hand
    try:
        nodes, _ = scene_export.hand_tets_world(scene)
        if s.seed is None:
            return -1
        return native.count_captured(nodes, scene_export.seed_world(scene), s.handle_radius_si)
    except (scene_export.ExportError, native.NativeError):
        return -1


def update_captured(scene) -> None:
    """Refresh the stored count and the seed empty's sphere (drawn with the handle radius)."""
    s = scene.haptic_hand
    count = captured_count(scene)
    s.captured_nodes = max(count, 0)
    seed = s.seed
    if seed is not None:
        world_scale = max(float(np.mean(seed.matrix_world.to_scale())), 1e-12)
        seed.empty_display_size = s.handle_radius_si / meshdata.unit_scale(scene) / world_scale


class HAPTIC_HAND_OT_use_as_hand(bpy.types.Operator):
    """Use the active mesh as the hand's render mesh"""

    bl_idname = "haptic_hand.use_as_hand"
    bl_label = "Use as Hand"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return _mesh_poll(context)

    def execute(self, context):
        obj = context.active_object
        context.scene.haptic_hand.hand = obj
        obj.haptic_hand.role = "HAND"
        update_captured(context.scene)
        return {"FINISHED"}


class HAPTIC_HAND_OT_tetrahedralize(bpy.types.Operator):
    """Fill the active mesh (the hand or a soft body) with tetrahedra (pytetwild); the tets are
    kept as their own object, parented to the mesh, which is embedded in them"""

    bl_idname = "haptic_hand.tetrahedralize"
    bl_label = "Tetrahedralize"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if not _mesh_poll(context):
            cls.poll_message_set("Select a mesh object in Object Mode")
            return False
        return True

    def execute(self, context):
        scene = context.scene
        s = scene.haptic_hand
        obj = context.active_object
        o = obj.haptic_hand  # each mesh has its own tetrahedralize settings
        scale = meshdata.unit_scale(scene)
        m = meshdata.matrix(obj)
        surface = meshdata.world_vertices(obj, scene)
        faces = meshdata.triangles(obj.data)
        wm = context.window_manager
        wm.progress_begin(0.0, 1.0)
        try:
            nodes, tets = meshing.tetrahedralize(
                surface, faces, edge_length_fac=o.edge_length_fac, coarsen=o.coarsen, epsilon=o.epsilon,
                progress=lambda fraction, message: wm.progress_update(0.9 * fraction))
            tet_index, weights = meshing.embed_points(nodes, tets, surface)
        except meshing.MeshError as e:
            self.report({"ERROR"}, f"Cannot tetrahedralize '{obj.name}': {e}")
            return {"CANCELLED"}
        finally:
            wm.progress_end()
        # How far the render surface strays outside the tets (it rides along by extrapolation).
        embedded = meshing.interpolate_embedded(nodes, tets, tet_index, weights)
        outside = int((weights.min(axis=1) < -1e-9).sum())
        error = float(np.abs(embedded - surface).max())
        tet_obj = make_tet_object(context, obj, meshdata.transform(np.linalg.inv(m), nodes / scale), tets)
        if obj == s.hand:
            update_captured(scene)
        self.report({"INFO"}, f"'{obj.name}': {len(tets)} tets, {len(nodes)} nodes in '{tet_obj.name}'; "
                              f"{outside} of {len(surface)} surface vertices ride just outside the tets "
                              f"(embedding error {error:.1e} m)")
        return {"FINISHED"}


def make_tet_object(context, obj, nodes_local: np.ndarray, tets: np.ndarray):
    """Store a tet mesh for obj as a child object '<obj>.tets' (replacing an older one), shown
    as wire, not rendered. nodes_local are in obj's coordinates."""
    old = obj.haptic_hand.tet_object
    me = meshdata.new_tet_mesh(f"{obj.name}.tets", nodes_local, tets)
    tet_obj = bpy.data.objects.new(f"{obj.name}.tets", me)
    for collection in obj.users_collection:
        collection.objects.link(tet_obj)
    tet_obj.parent = obj
    tet_obj.matrix_parent_inverse.identity()
    tet_obj.matrix_basis.identity()
    tet_obj.display_type = "WIRE"
    tet_obj.hide_render = True
    tet_obj.hide_select = True
    tet_obj.haptic_hand.is_tet_mesh = True
    obj.haptic_hand.tet_object = tet_obj
    if old is not None and old != tet_obj:
        old_mesh = old.data
        bpy.data.objects.remove(old)
        if old_mesh.users == 0:
            bpy.data.meshes.remove(old_mesh)
    return tet_obj


class HAPTIC_HAND_OT_place_seed(bpy.types.Operator):
    """Place the palm seed at the 3D cursor, snapped into the hand's tet mesh (the rigid handle
    captures the nodes within the handle radius of it)"""

    bl_idname = "haptic_hand.place_seed"
    bl_label = "Place Seed"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        s = context.scene.haptic_hand
        if s.hand is None or not meshdata.has_tets(s.hand.haptic_hand.tet_object):
            cls.poll_message_set("Choose the hand and tetrahedralize it first")
            return False
        return context.mode == "OBJECT"

    def execute(self, context):
        scene = context.scene
        s = scene.haptic_hand
        scale = meshdata.unit_scale(scene)
        nodes, tets = scene_export.hand_tets_world(scene)
        cursor = np.array(scene.cursor.location, dtype=np.float64) * scale
        point = snap_into_tets(nodes, tets, cursor)
        seed = s.seed
        if seed is None:
            seed = bpy.data.objects.new(SEED_NAME, None)
            seed.empty_display_type = "SPHERE"
            for collection in s.hand.users_collection:
                collection.objects.link(seed)
            seed.parent = s.hand
            s.seed = seed
        seed.matrix_world.translation = tuple(point / scale)
        context.view_layer.update()
        update_captured(scene)
        moved = np.linalg.norm(point - cursor)
        where = "at the 3D cursor" if moved < 1e-12 else f"snapped {moved * 1000:.1f} mm from the 3D cursor into the hand"
        self.report({"INFO"}, f"Palm seed {where}: the handle captures {s.captured_nodes} nodes")
        return {"FINISHED"}


def snap_into_tets(nodes: np.ndarray, tets: np.ndarray, point: np.ndarray) -> np.ndarray:
    """point itself if a tet contains it, else the centroid of the tet nearest to it."""
    tet_index, weights = meshing.embed_points(nodes, tets, point[None])
    if weights.min() >= -1e-9:
        return point
    return nodes[tets[tet_index[0]]].mean(axis=0)


class HAPTIC_HAND_OT_check_rig(bpy.types.Operator):
    """Check the rig with the engine: surface, tets, handle, and one step solved two ways"""

    bl_idname = "haptic_hand.check_rig"
    bl_label = "Check Rig"

    @classmethod
    def poll(cls, context):
        return context.scene.haptic_hand.hand is not None

    def execute(self, context):
        from ..engine import rig_check

        scene = context.scene
        try:
            export = scene_export.export(context, scene.frame_current, scene.frame_current + 1)
        except (scene_export.ExportError, meshing.MeshError, native.NativeError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        try:
            report = rig_check.check(export.scene)
        finally:
            export.cleanup()
        text = rig_check.format_report(report)
        for line in text.splitlines():
            self.report({"INFO"} if report["ok"] else {"WARNING"}, line)
        if not report["ok"]:
            self.report({"ERROR"}, "The rig has problems: " + "; ".join(
                c["detail"] for c in report["checks"] if not c["ok"]))
            return {"CANCELLED"}
        return {"FINISHED"}


classes = (HAPTIC_HAND_OT_use_as_hand, HAPTIC_HAND_OT_tetrahedralize, HAPTIC_HAND_OT_place_seed,
           HAPTIC_HAND_OT_check_rig)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
