"""Authoring the hand rig: choose the hand, tetrahedralize a mesh (hand or soft body), place
the palm seed, count the nodes the handle captures, check the rig with the engine."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import bpy
import numpy as np

from ..engine import child as child_process
from ..engine import mesh as meshing
from ..engine import native
from . import background, meshdata, runtime, scene_export

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


class TetJob(background.ChildJob):
    """One tetrahedralization of a mesh in a child process (fTetWild holds Python's lock for
    its whole call, so a thread could neither report progress nor be stopped)."""

    def __init__(self, obj, surface: np.ndarray, faces: np.ndarray, options: dict, argv=None):
        self.obj_name = obj.name
        self.matrix = meshdata.matrix(obj)
        self.surface = surface
        self.folder = Path(tempfile.mkdtemp(prefix="haptic_hand_tets_"))
        given, self.output = self.folder / "surface.npz", self.folder / "tets.npz"
        np.savez(given, vertices=surface, faces=faces, **options)
        super().__init__(child_process.Child(["tetrahedralize", given, self.output], what="Tetrahedralize's process",
                                             parse_log=True, argv=argv))

    def release(self) -> None:
        super().release()
        shutil.rmtree(self.folder, ignore_errors=True)


def tet_estimate(obj, scene) -> int:
    """About how many tets Tetrahedralize will make of obj with its own settings."""
    o = obj.haptic_hand
    return child_process.estimate_tets(meshdata.world_vertices(obj, scene), meshdata.triangles(obj.data),
                                       o.edge_length_fac, o.epsilon)


def start_tetrahedralize(context, obj, confirmed: bool = False, argv=None) -> TetJob:
    """Checks obj's surface and starts the child; MeshError with the fix when the surface
    cannot be filled, or when the estimate passes Rig > Confirm above and not confirmed."""
    scene = context.scene
    o = obj.haptic_hand  # each mesh has its own tetrahedralize settings
    surface = meshdata.world_vertices(obj, scene)
    faces = meshdata.triangles(obj.data)
    try:
        meshing.check_closed_surface(surface, faces)
    except meshing.MeshError as e:
        raise meshing.MeshError(f"Cannot tetrahedralize '{obj.name}': {e}") from None
    limit = scene.haptic_hand.tet_confirm_limit
    estimate = child_process.estimate_tets(surface, faces, o.edge_length_fac, o.epsilon)
    if limit and estimate > limit and not confirmed:
        raise meshing.MeshError(
            f"'{obj.name}' would get about {estimate} tets, more than Rig > Confirm above ({limit}): raise Edge "
            "length, or press Tetrahedralize and confirm (from a script: confirmed=True)")
    options = dict(edge_length_fac=o.edge_length_fac, coarsen=o.coarsen, epsilon=o.epsilon)
    job = TetJob(obj, surface, faces, options, argv=argv)
    warning = meshing.scale_warning(surface, "hand") if obj == scene.haptic_hand.hand else None
    job.warnings += [f"'{obj.name}': {warning}"] if warning else []
    return job.start()


def poll_tetrahedralize(context, job: TetJob) -> str:
    """'RUNNING', or when the child is done, store the tets and return 'FINISHED', 'CANCELLED'
    or 'FAILED' (job.error says why). Never raises."""
    state = job.child.poll()
    if state == "RUNNING":
        return "RUNNING"
    try:
        if state != "FINISHED":
            if state == "FAILED":
                job.error = f"Cannot tetrahedralize '{job.obj_name}': {job.child.error}"
            return state
        obj = bpy.data.objects.get(job.obj_name)
        if obj is None:
            job.error = f"'{job.obj_name}' was deleted while it was tetrahedralized"
            return "FAILED"
        with np.load(job.output) as out:
            nodes, tets, gap = out["nodes"], out["tets"], out["gap"]
        scale = meshdata.unit_scale(context.scene)
        tet_obj = make_tet_object(context, obj, meshdata.transform(np.linalg.inv(job.matrix), nodes / scale), tets)
        if obj == context.scene.haptic_hand.hand:
            update_captured(context.scene)
        job.summary = f"'{obj.name}': {len(tets)} tets, {len(nodes)} nodes in '{tet_obj.name}'; " + gap_message(gap)
        return "FINISHED"
    except (OSError, ValueError, KeyError) as e:
        job.error = f"Cannot read the tets of '{job.obj_name}': {e}; press Tetrahedralize again"
        return "FAILED"
    finally:
        job.release()
        if runtime.state.tetrahedralize is job:
            runtime.state.tetrahedralize = None


def gap_message(gap: np.ndarray) -> str:
    """What the user needs to know of how the render surface sits in the tets: how far it lies
    outside them (it rides along by extrapolation there)."""
    outside = int((gap > 0).sum())
    if outside == 0:
        return "the render surface lies inside the tets"
    return (f"the render surface lies up to {gap.max() * 1000:.2f} mm outside the tets ({outside} of {len(gap)} "
            "vertices; they ride along by extrapolation)")


class HAPTIC_HAND_OT_tetrahedralize(background.BackgroundOperator, bpy.types.Operator):
    """Fill the active mesh (the hand or a soft body) with tetrahedra (pytetwild, in a child
    process: Esc cancels); the tets are kept as their own object, parented to the mesh"""

    bl_idname = "haptic_hand.tetrahedralize"
    bl_label = "Tetrahedralize"
    bl_options = {"REGISTER", "UNDO"}
    slot = "tetrahedralize"

    confirmed: bpy.props.BoolProperty(default=False, options={"SKIP_SAVE", "HIDDEN"},
                                      description="Go ahead even above Rig > Confirm above")
    interactive: bpy.props.BoolProperty(default=False, options={"SKIP_SAVE", "HIDDEN"},
                                        description="Run in the background (started from the UI)")

    @classmethod
    def poll(cls, context):
        if not _mesh_poll(context):
            cls.poll_message_set("Select a mesh object in Object Mode")
            return False
        busy = runtime.state.busy()
        if busy:
            cls.poll_message_set(busy)
            return False
        return True

    def invoke(self, context, event):
        self.interactive = True
        limit = context.scene.haptic_hand.tet_confirm_limit
        estimate = tet_estimate(context.active_object, context.scene)
        if limit and estimate > limit and not self.confirmed:
            self.confirmed = True
            message = (f"About {estimate} tets (more than Confirm above, {limit}): this can take minutes; Esc "
                       "cancels it")
            try:
                return context.window_manager.invoke_confirm(self, event, title="Tetrahedralize", message=message)
            except TypeError:  # an older signature
                return context.window_manager.invoke_confirm(self, event)
        return self.execute(context)

    def execute(self, context):
        try:
            job = start_tetrahedralize(context, context.active_object, confirmed=self.confirmed)
        except (meshing.MeshError, OSError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self.report_warnings(job)
        if self.interactive and context.window is not None:
            return self.start_modal(context, job)
        runtime.state.tetrahedralize = self.job = job
        job.child.wait()
        return self.finish(context, poll_tetrahedralize(context, job))

    def step(self, context, job):
        return poll_tetrahedralize(context, job)

    def status(self, job):
        return f"Haptic Hand: tetrahedralizing '{job.obj_name}' {job.progress * 100:.0f}% ({job.message}); Esc cancels"

    def finish(self, context, state):
        if state == "FINISHED":
            self.report({"INFO"}, self.job.summary)
            return {"FINISHED"}
        if state == "CANCELLED":
            self.report({"WARNING"}, f"Tetrahedralize cancelled: '{self.job.obj_name}' keeps the tets it had")
        else:
            self.report({"ERROR"}, self.job.error)
        return {"CANCELLED"}


class HAPTIC_HAND_OT_tetrahedralize_cancel(bpy.types.Operator):
    """Stop the running Tetrahedralize (its child process is killed); the mesh keeps its tets"""

    bl_idname = "haptic_hand.tetrahedralize_cancel"
    bl_label = "Cancel Tetrahedralize"

    @classmethod
    def poll(cls, context):
        return runtime.state.tetrahedralize is not None

    def execute(self, context):
        runtime.state.tetrahedralize.cancel()
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
    tet_obj.name = me.name = f"{obj.name}.tets"  # the name the old one had
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
    """Check the rig with the engine: surface, tets, handle or each bone, and one step solved two
    ways"""

    bl_idname = "haptic_hand.check_rig"
    bl_label = "Check Rig"

    @classmethod
    def poll(cls, context):
        return context.scene.haptic_hand.hand is not None

    def execute(self, context):
        from ..engine import rig_check

        from . import ops_skeleton

        scene = context.scene
        if not ops_skeleton.report_problems(self, scene):
            return {"CANCELLED"}
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


classes = (HAPTIC_HAND_OT_use_as_hand, HAPTIC_HAND_OT_tetrahedralize, HAPTIC_HAND_OT_tetrahedralize_cancel,
           HAPTIC_HAND_OT_place_seed,
           HAPTIC_HAND_OT_check_rig)


register, unregister = bpy.utils.register_classes_factory(classes)
