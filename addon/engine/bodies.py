"""The other bodies of a scene (soft, rigid, kinematic, static, plane): their description in
the scene file, the meshes they are made of, and how they enter a native World.

Mesh sources: "procedural:bunny", "procedural:letter:<A>", "box" (with size and cells), or
an .obj path relative to the scene file. Soft bodies get tets from a stored .npz, from the
procedural shape's own coarse tets, or from pytetwild; their surface is embedded in the tets.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import mesh as meshing
from . import native
from . import native_world as W
from . import params, shapes
from .embedding import check_embedding
from .scene_fields import SceneError, check_fields, merge, timed_poses

_DEPTH_SAMPLES = 256  # inside points whose depth is measured

TYPES = {"soft": W.SOFT, "rigid": W.RIGID, "kinematic": W.KINEMATIC, "static": W.STATIC, "plane": W.PLANE}

class BodyError(ValueError):
    """A body description that cannot be used; the message names the body, field and fix."""


@dataclass
class PreparedBody:
    spec: dict
    kind: int
    vertices: np.ndarray = field(default=None, repr=False)  # surface, world frame at rest
    faces: np.ndarray = field(default=None, repr=False)
    nodes: np.ndarray = field(default=None, repr=False)     # soft: tet nodes
    tets: np.ndarray = field(default=None, repr=False)
    tet_index: np.ndarray = field(default=None, repr=False)  # soft: surface embedding
    weights: np.ndarray = field(default=None, repr=False)
    index: int = -1  # in the World

    @property
    def name(self) -> str:
        return self.spec["name"]


def defaults() -> dict:
    """A body's defaults (a fresh copy), from the parameter table."""
    return params.defaults(body=True)


def parse(specs: list, base_dir: Path) -> list[dict]:
    example = '{"name": "cube", "type": "soft", "mesh": "box"}'
    if not isinstance(specs, list):
        raise BodyError(f"bodies = {json.dumps(specs)[:60]} is invalid: it must be a list of body objects, e.g. "
                        f"[{example}] (or [] for none)")
    out, names = [], set()
    for i, given in enumerate(specs):
        if not isinstance(given, dict):
            raise BodyError(f"bodies[{i}] = {json.dumps(given)[:60]} is invalid: each body must be an object, e.g. "
                            f"{example}")
        label = f"bodies[{i}]" + (f" ('{given['name']}')" if isinstance(given.get("name"), str) else "")
        try:
            spec = merge(defaults(), given, f"{label}.")
            if not isinstance(spec["type"], str) or spec["type"] not in TYPES:
                raise BodyError(f"{label} has type {json.dumps(spec['type'])}: use one of {', '.join(TYPES)}")
            check_fields(spec, body=True, where=lambda p: f"{label}.{p.json[len(params.BODY):]}")
        except SceneError as e:
            raise BodyError(str(e)) from None
        spec["name"] = spec["name"] or f"body{i}"
        if spec["name"] in names:
            raise BodyError(f"two bodies are named '{spec['name']}': give each a unique name")
        names.add(spec["name"])
        if spec["type"] != "plane" and spec["mesh"] is None:
            raise BodyError(f"body '{spec['name']}' needs a 'mesh' (procedural:bunny, procedural:letter:H, box, "
                            "or an .obj path)")
        _refuse_fields_of_other_types(spec, given)
        _check_fixed(spec)
        if spec["type"] != "plane" and spec["mesh"] == "box":
            try:
                native.check_box_cells(spec["cells"])
            except native.InvalidInput as e:
                raise BodyError(f"body '{spec['name']}': {e}") from None
        if spec["type"] == "kinematic" and spec["trajectory"]:
            try:
                timed_poses(spec["trajectory"], f"body '{spec['name']}': trajectory")
            except SceneError as e:
                raise BodyError(str(e)) from None
        spec["_base_dir"] = str(base_dir)
        out.append(spec)
    return out


def _refuse_fields_of_other_types(spec: dict, given: dict) -> None:
    """A field given for a body type that never reads it (a solver for a rigid body) is a mistake
    the user should hear about."""
    for p in params.table():
        if p.body and not p.applies_to(spec["type"]) and p.keys[0] in given and params.get(spec, p) != p.default:
            kinds = [t for t in TYPES if p.applies_to(t)]
            raise BodyError(f"body '{spec['name']}': only {' and '.join(kinds)} bodies take '{p.keys[0]}' "
                            f"(this one is {spec['type']}): remove it")


def _check_fixed(spec: dict) -> None:
    rule = spec["fixed"]
    if rule is None or rule == "bottom":
        return
    whole = isinstance(rule, list) and all(isinstance(i, int) and not isinstance(i, bool) for i in rule)
    if not whole:
        raise BodyError(f"body '{spec['name']}': fixed = {json.dumps(rule)[:60]} is invalid: use null, \"bottom\" "
                        "(its lowest nodes) or a list of node indices (whole numbers)")


def _surface(spec: dict) -> tuple[np.ndarray, np.ndarray]:
    source = spec["mesh"]
    if source == "procedural:bunny":
        return shapes.procedural_bunny()
    if isinstance(source, str) and source.startswith("procedural:letter:"):
        try:
            return shapes.procedural_letter(source.split(":", 2)[2])
        except ValueError as e:
            raise BodyError(f"body '{spec['name']}': mesh {source!r}: {e}") from None
    if source == "box":
        nodes, tets = meshing.structured_box(spec["size"], spec["cells"], -0.5 * np.asarray(spec["size"], float))
        faces = meshing.tet_boundary_faces(tets)
        used = np.unique(faces)
        remap = np.full(len(nodes), -1)
        remap[used] = np.arange(len(used))
        return nodes[used], remap[faces].astype(np.int32)
    path = Path(spec["_base_dir"]) / str(source)
    if not path.is_file():
        raise BodyError(f"body '{spec['name']}': mesh file {path} does not exist (paths are relative to the scene)")
    v, f = meshing.load_obj(path)
    if spec["type"] in ("soft", "rigid"):  # they need a closed solid: its volume, its inside
        try:
            meshing.check_closed_surface(v, f)
        except meshing.MeshError as e:
            raise meshing.MeshError(f"body '{spec['name']}' ({path.name}): {e}") from None
    return v, f


def _soft_tets(spec: dict, v: np.ndarray, f: np.ndarray, progress=None) -> tuple[np.ndarray, np.ndarray]:
    if spec["tets"]:
        return meshing.load_tets(Path(spec["_base_dir"]) / spec["tets"], f"body '{spec['name']}': tets")
    source = spec["mesh"]
    if source == "procedural:bunny":
        return shapes.procedural_bunny_coarse_tets()
    if isinstance(source, str) and source.startswith("procedural:letter:"):
        return shapes.letter_tets(source.split(":", 2)[2])
    if source == "box":
        return meshing.structured_box(spec["size"], spec["cells"], -0.5 * np.asarray(spec["size"], float))
    opts = spec["tetrahedralize"]
    return meshing.tetrahedralize(v, f, edge_length_fac=float(opts["edge_length_fac"]), coarsen=bool(opts["coarsen"]),
                                  epsilon=float(opts["epsilon"]), progress=progress)


def prepare(spec: dict, progress=None) -> PreparedBody:
    kind = TYPES[spec["type"]]
    body = PreparedBody(spec, kind)
    if kind == W.PLANE:
        return body
    offset = np.asarray(spec["position"], dtype=np.float64)
    v, f = _surface(spec)
    body.vertices, body.faces = v + offset, np.asarray(f, dtype=np.int32)
    if kind == W.SOFT:
        nodes, tets = _soft_tets(spec, v, f, progress)
        body.nodes, body.tets = np.asarray(nodes, float) + offset, np.asarray(tets, np.int32)
        body.tet_index, body.weights = check_embedding(body.nodes, body.tets, body.vertices,
                                                       float(spec["tetrahedralize"]["epsilon"]),
                                                       f"body '{spec['name']}'", "its tets")
    return body


def fixed_nodes(body: PreparedBody) -> np.ndarray:
    rule = body.spec["fixed"]
    if rule is None:
        return np.zeros(0, dtype=np.int32)
    if rule == "bottom":
        z = body.nodes[:, 2]
        return np.flatnonzero(z <= z.min() + 1e-6).astype(np.int32)
    ids = np.asarray(rule, dtype=np.int64).reshape(-1)  # whole numbers (parse checked)
    if ids.size and (ids.min() < 0 or ids.max() >= len(body.nodes)):
        raise BodyError(f"body '{body.name}': fixed node indices must be in 0..{len(body.nodes) - 1}")
    return ids.astype(np.int32)


def add_to_world(world: W.World, body: PreparedBody) -> int:
    spec, friction = body.spec, float(body.spec["friction"])
    if body.kind == W.PLANE:
        body.index = world.add_plane(spec["point"], spec["normal"], friction=friction)
    elif body.kind == W.SOFT:
        m = spec["material"]
        sn, sw = W.embedded_surface(body.tets, body.tet_index, body.weights)
        body.index = world.add_soft_body(body.nodes, body.tets, sn, sw, body.faces, fixed_nodes=fixed_nodes(body),
                                         friction=friction, **m)
        solver = spec["solver"]
        world.set_body_solver(body.index, solver["name"], solver["cg_tolerance"], solver["cg_max_iterations"])
    else:
        body.index = world.add_mesh_body(body.kind, body.vertices, body.faces, density=float(spec["density"]),
                                         friction=friction)
    if spec["kinetic_friction"] is not None:
        world.set_friction(body.index, friction, float(spec["kinetic_friction"]))
    return body.index


def check_overlaps(hand_vertices: np.ndarray, hand_faces: np.ndarray, prepared: list, thickness: float) -> None:
    """Refuses a scene in which two bodies (the hand among them) start inside each other deeper
    than the contact thickness, naming the pair and the depth. The contact solve would push them
    apart in one step, as hard as it can; they are refused rather than separated."""
    surfaces = [("the hand", hand_vertices, np.asarray(hand_faces), True)]
    surfaces += [(f"body '{b.name}'", b.vertices, b.faces, b.kind in (W.SOFT, W.RIGID))
                 for b in prepared if b.kind != W.PLANE]
    planes = [b for b in prepared if b.kind == W.PLANE]
    for i, (name_a, va, fa, moves_a) in enumerate(surfaces):
        for plane in planes:
            normal = np.asarray(plane.spec["normal"], float)
            depth = -((va - np.asarray(plane.spec["point"], float)) @ normal) / np.linalg.norm(normal)
            _refuse_overlap(name_a, f"plane '{plane.name}'", depth, np.argmax(depth), thickness)
        for name_b, vb, fb, moves_b in surfaces[i + 1:]:
            if not (moves_a or moves_b):
                continue  # kinematic and static bodies never push each other
            for (n1, v1, _), (n2, v2, f2) in (((name_a, va, fa), (name_b, vb, fb)), ((name_b, vb, fb), (name_a, va, fa))):
                depth = _depth_inside(v1, v2, f2)
                if len(depth):
                    _refuse_overlap(n1, n2, depth, int(np.argmax(depth)), thickness)


def _refuse_overlap(inner: str, outer: str, depth: np.ndarray, vertex: int, thickness: float) -> None:
    if len(depth) and depth[vertex] > thickness:
        raise BodyError(
            f"{inner} starts inside {outer}: {depth[vertex] * 1e3:.3g} mm deep at its vertex {vertex}, more than the "
            f"{thickness * 1e3:.3g} mm contact thickness; move them apart by at least that before the run (bodies "
            "that start inside each other are refused, not pushed apart)")


def _depth_inside(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """How deep (m) each point lies inside the closed surface (vertices, faces); 0 outside. An
    open surface has no inside: zeros."""
    depth = np.zeros(len(points))
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    closed = np.all(np.unique(edges, axis=0, return_counts=True)[1] == 2)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    near = np.flatnonzero(np.all((points >= lo) & (points <= hi), axis=1))
    if not closed or not len(near):
        return depth
    inside = near[meshing.winding_numbers(vertices, faces, points[near]) > 0.5]
    inside = inside[:: max(1, len(inside) // _DEPTH_SAMPLES)]  # a deep overlap needs no exact maximum
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    for p in inside:
        q = np.broadcast_to(points[p], a.shape)
        depth[p] = np.linalg.norm(meshing.closest_point_on_triangles(q, a, b, c) - q, axis=1).min()
    return depth
