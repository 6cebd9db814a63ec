"""Blender meshes and transforms as numpy arrays, and back: the one place that reads and
writes vertex data, so vertex order and units are handled the same way everywhere.

Engine arrays are in metres, world space; Blender stores float32 local coordinates in
scene units. metres = (matrix_world @ local) * scale_length.

Tet meshes (made by Tetrahedralize, docs/blender.md): an object whose mesh has the tet nodes
as vertices (every node, interior ones as loose vertices), the tets' boundary triangles as
faces (for display), and the tets as the integer ID property `haptic_tets` (4 node indices
per tet, flattened) on the mesh data. It is saved inside the .blend: no sidecar file.
"""

from __future__ import annotations

import numpy as np

from ..engine import quaternion

TETS_KEY = "haptic_tets"


def unit_scale(scene) -> float:
    """Metres per scene unit."""
    s = float(scene.unit_settings.scale_length)
    return s if s > 0 else 1.0


def matrix(obj) -> np.ndarray:
    return np.array(obj.matrix_world, dtype=np.float64)


def transform(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ m[:3, :3].T + m[:3, 3]


def local_vertices(mesh) -> np.ndarray:
    """(n, 3) float64 vertex positions in the mesh's own coordinates, in vertex order."""
    co = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.attributes["position"].data.foreach_get("vector", co)
    return co.reshape(-1, 3).astype(np.float64)


def triangles(mesh) -> np.ndarray:
    """(m, 3) int32 triangles of the mesh's faces (polygons fanned by Blender's own loop
    triangulation: no vertex is added or moved, so vertex order is kept)."""
    mesh.calc_loop_triangles()
    tri = np.empty(len(mesh.loop_triangles) * 3, dtype=np.int32)
    mesh.loop_triangles.foreach_get("vertices", tri)
    return tri.reshape(-1, 3)


def world_vertices(obj, scene) -> np.ndarray:
    """Vertices of obj's mesh (no modifiers, no shape keys) in metres, world space."""
    return transform(matrix(obj), local_vertices(obj.data)) * unit_scale(scene)


def write_positions(mesh, local: np.ndarray) -> None:
    """Write vertex positions (n, 3) into the mesh in one foreach_set, then update it."""
    flat = np.ascontiguousarray(local, dtype=np.float32).reshape(-1)
    if flat.size != len(mesh.vertices) * 3:
        raise ValueError(f"mesh '{mesh.name}' has {len(mesh.vertices)} vertices, got {flat.size // 3} positions")
    mesh.attributes["position"].data.foreach_set("vector", flat)
    mesh.update()


def has_tets(obj) -> bool:
    return obj is not None and obj.type == "MESH" and TETS_KEY in obj.data.keys()


def read_tets(tet_obj) -> tuple[np.ndarray, np.ndarray]:
    """(nodes local float64 (n, 3), tets int32 (m, 4)) of a tet-mesh object."""
    tets = np.asarray(tet_obj.data[TETS_KEY], dtype=np.int32).reshape(-1, 4)
    return local_vertices(tet_obj.data), tets


def new_tet_mesh(name: str, nodes_local: np.ndarray, tets: np.ndarray):
    """A mesh holding a tet mesh: nodes as vertices, boundary triangles as faces, tets as the
    `haptic_tets` ID property."""
    import bpy

    from ..engine import mesh as meshing

    faces = meshing.tet_boundary_faces(tets)
    me = bpy.data.meshes.new(name)
    me.vertices.add(len(nodes_local))
    me.vertices.foreach_set("co", np.ascontiguousarray(nodes_local, dtype=np.float32).reshape(-1))
    me.loops.add(len(faces) * 3)
    me.loops.foreach_set("vertex_index", faces.reshape(-1).astype(np.int32))
    me.polygons.add(len(faces))
    me.polygons.foreach_set("loop_start", np.arange(0, 3 * len(faces), 3, dtype=np.int32))
    me.update()
    me.validate(verbose=False, clean_customdata=False)
    me[TETS_KEY] = np.asarray(tets, dtype=np.int32).reshape(-1).tolist()
    return me


def new_mesh(name: str, vertices: np.ndarray, faces: np.ndarray):
    """A plain triangle mesh, vertex order as given."""
    import bpy

    me = bpy.data.meshes.new(name)
    me.from_pydata(np.asarray(vertices, dtype=np.float64).tolist(), [], np.asarray(faces).tolist())
    me.update()
    return me


def quaternion_xyzs(obj_matrix: np.ndarray) -> np.ndarray:
    """Rotation of a 4x4 matrix (scale removed) as (x, y, z, s)."""
    import mathutils

    q = mathutils.Matrix(obj_matrix.tolist()).to_quaternion()
    return np.array([q.x, q.y, q.z, q.w])


def rigid_matrix(rest_matrix: np.ndarray, rest_centre_m: np.ndarray, pose: np.ndarray, scale: float) -> np.ndarray:
    """World matrix of a rigid body whose centre moved from rest_centre (m) to pose[:3] (m) and
    turned by pose[3:] (x, y, z, s) from its rest orientation."""
    r = quaternion.to_matrix(pose[3:])
    move = np.eye(4)
    move[:3, :3] = r
    move[:3, 3] = (pose[:3] - r @ rest_centre_m) / scale
    return move @ rest_matrix
