"""Authoring the rig: tetrahedralize from the operator, the captured-node count, bad input."""

import time

import pytest

bpy = pytest.importorskip("bpy")
import numpy as np

from haptic_hand.blender import meshdata, ops_rig, runtime, scene_export
from haptic_hand.engine import mesh as meshing
from haptic_hand.engine import native

from blender_helpers import SAMPLES


def add_mesh(context, name, vertices, faces, location=(0.0, 0.0, 0.0)):
    obj = bpy.data.objects.new(name, meshdata.new_mesh(name, vertices, faces))
    context.scene.collection.objects.link(obj)
    obj.location = location
    context.view_layer.objects.active = obj
    obj.select_set(True)
    context.view_layer.update()
    return obj


def test_tetrahedralize_procedural_hand_encloses_render_mesh(addon):
    context = addon
    s = context.scene.haptic_hand
    v, f = meshing.procedural_hand()
    # an object away from the origin: tets must come back in its own coordinates
    hand = add_mesh(context, "Hand", v, f, location=(0.3, -0.2, 0.1))
    o = hand.haptic_hand  # each mesh keeps its own tetrahedralize settings
    o.edge_length_fac, o.coarsen, o.epsilon = 0.2, True, 0.004
    assert bpy.ops.haptic_hand.use_as_hand() == {"FINISHED"}
    assert bpy.ops.haptic_hand.tetrahedralize() == {"FINISHED"}

    tet_obj = hand.haptic_hand.tet_object
    assert tet_obj is not None and tet_obj.parent == hand and tet_obj.haptic_hand.is_tet_mesh
    nodes, tets = scene_export.hand_tets_world(context.scene)
    render = meshdata.world_vertices(hand, context.scene)
    assert meshing.tet_signed_volumes(nodes, tets).min() > 0.0, "every tet positively oriented"
    assert len(np.unique(tets)) == len(nodes), "every node belongs to a tet"

    # The tet boundary encloses the render surface up to fTetWild's envelope (epsilon times
    # the bounding-box diagonal): points 2 envelopes inside the surface are inside the tets,
    # points 2 envelopes outside are outside.
    envelope = o.epsilon * np.linalg.norm(render.max(0) - render.min(0))
    normals = np.empty(len(render) * 3, dtype=np.float32)
    hand.data.vertex_normals.foreach_get("vector", normals)
    normals = normals.reshape(-1, 3).astype(float)
    boundary = meshing.tet_boundary_faces(tets)
    inner = meshing.winding_numbers(nodes, boundary, render - 2 * envelope * normals)
    outer = meshing.winding_numbers(nodes, boundary, render + 2 * envelope * normals)
    assert (inner > 0.5).mean() > 0.995, f"{(inner <= 0.5).sum()} points just inside the skin are outside the tets"
    assert (outer < 0.5).mean() > 0.995, f"{(outer >= 0.5).sum()} points just outside the skin are inside the tets"
    # the tets fill the same volume as the render surface, to the envelope's share
    volume = meshing.tet_signed_volumes(nodes, tets).sum()
    area = 0.5 * np.linalg.norm(np.cross(render[f[:, 1]] - render[f[:, 0]], render[f[:, 2]] - render[f[:, 0]]),
                                axis=1).sum()
    assert abs(volume - meshing.surface_volume(render, f)) < area * envelope

    # the render mesh is embedded in the tets: the weights give back every vertex
    tet_index, weights = meshing.embed_points(nodes, tets, render)
    assert np.abs(meshing.interpolate_embedded(nodes, tets, tet_index, weights) - render).max() < 1e-9


def test_captured_count_follows_radius(addon):
    from haptic_hand.blender import scene_import

    context = addon
    scene_import.build(context, SAMPLES / "hand_wave.json")
    s = context.scene.haptic_hand
    stored = np.load(SAMPLES / "procedural_hand_tets.npz")["nodes"]
    seed = meshing.procedural_hand_palm_seed()
    counts = []
    for radius in (0.015, 0.025, 0.035, 0.045):
        s.handle_radius = radius  # the property's update callback recounts
        # independent count: nodes within the radius, by distance (Blender keeps float32)
        expected = int((np.linalg.norm(stored.astype(np.float32) - seed, axis=1) <= radius).sum())
        assert s.captured_nodes == expected
        assert s.seed.empty_display_size == pytest.approx(radius)  # the drawn sphere follows
        counts.append(s.captured_nodes)
    assert all(a < b for a, b in zip(counts, counts[1:])), counts
    # and the handle the engine builds captures exactly those nodes
    s.handle_radius = 0.035
    export = scene_export.export(context)
    try:
        model = native.HandModel(export.scene.nodes, export.scene.tets, **export.scene.engine_params())
        assert model.info()["n_handle_nodes"] == counts[2]
    finally:
        export.cleanup()


def _state(context):
    """What an operator that fails must leave unchanged."""
    return (sorted(o.name for o in bpy.data.objects), sorted(m.name for m in bpy.data.meshes),
            sorted(a.name for a in bpy.data.actions), context.scene.frame_current,
            {o.name: tuple(o.matrix_world.translation) for o in bpy.data.objects},
            {o.name: (o.data.shape_keys is not None) for o in bpy.data.objects if o.type == "MESH"})


def test_non_manifold_mesh_is_refused_and_scene_untouched(addon):
    context = addon
    # two closed tetrahedra sharing one edge: no hole, but that edge has four faces
    v = np.array([[0, 0, 0], [0.05, 0, 0], [0.02, 0.05, 0], [0.02, 0.02, 0.05],
                  [0.02, -0.05, 0], [0.02, -0.02, -0.05]], dtype=float)
    f = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2],
                  [0, 1, 4], [0, 5, 1], [1, 5, 4], [0, 4, 5]])
    add_mesh(context, "Bowtie", v, f)
    before = _state(context)
    with pytest.raises(RuntimeError) as info:
        bpy.ops.haptic_hand.tetrahedralize()
    message = str(info.value)
    assert "non-manifold" in message and "Bowtie" in message
    assert "Select All by Trait" in message  # says how to fix it in Blender
    assert _state(context) == before


def test_seed_outside_hand_is_refused_and_scene_untouched(addon, built_scenes, tmp_path):
    from blender_helpers import open_copy

    context = open_copy(built_scenes("hand_wave"), tmp_path)
    s = context.scene.haptic_hand
    s.bake_frame_end = s.bake_frame_start + 3
    s.seed.matrix_world.translation = (0.5, 0.5, 0.5)  # far outside the hand
    context.view_layer.update()
    before = _state(context)
    with pytest.raises(RuntimeError) as info:
        bpy.ops.haptic_hand.bake()
    assert "palm seed" in str(info.value) and "outside the hand" in str(info.value)
    assert "Place Seed" in str(info.value)
    assert _state(context) == before and not s.baked
    assert not (tmp_path / "hand_wave_haptic").exists()

    # Place Seed snaps a seed from outside back into the hand's tets
    context.scene.cursor.location = (0.5, 0.5, 0.5)
    assert bpy.ops.haptic_hand.place_seed() == {"FINISHED"}
    nodes, tets = scene_export.hand_tets_world(context.scene)
    seed = np.array(s.seed.matrix_world.translation)
    assert meshing.embed_points(nodes, tets, seed[None])[1].min() >= -1e-9
    assert s.captured_nodes == native.count_captured(nodes, seed, s.handle_radius)


def hull_surface(v):
    """The convex hull of points around the origin as outward triangles."""
    import scipy.spatial

    f = scipy.spatial.ConvexHull(v).simplices
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    f[np.einsum("ij,ij->i", n, v[f[:, 0]]) < 0] = f[np.einsum("ij,ij->i", n, v[f[:, 0]]) < 0][:, ::-1]
    return v, f


def box_surface(half):
    """A closed box surface (8 corners, 12 outward triangles) of half-extents `half`."""
    return hull_surface(np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float) * half)


def sphere_surface(radius, n=200):
    """A closed sphere surface of n vertices (a Fibonacci lattice), centred on the origin."""
    i = np.arange(n) + 0.5
    polar, azimuth = np.arccos(1 - 2 * i / n), np.pi * (1 + 5**0.5) * i
    return hull_surface(radius * np.c_[np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)])


def two_cubes(offset, merged=False):
    """Two 3 cm cubes, the second moved by offset; merged: one vertex where two coincide."""
    v, f = box_surface(np.full(3, 0.015))
    v, f = np.vstack([v, v + offset]), np.vstack([f, f + 8])
    if merged:
        v, inverse = np.unique(v.round(9), axis=0, return_inverse=True)
        f = inverse.reshape(-1)[f]
    return v, f


def refusal(context, obj) -> str:
    """Tetrahedralize obj: the refusal Blender reports (its ERROR report), with the scene as it was."""
    context.view_layer.objects.active = obj
    before = _state(context)
    with pytest.raises(RuntimeError) as info:
        bpy.ops.haptic_hand.tetrahedralize()
    message = str(info.value)
    assert message.startswith("Error: Cannot tetrahedralize") and "Traceback" not in message, message
    assert f"'{obj.name}'" in message and "Mesh > Clean Up" in message, message
    assert _state(context) == before
    return message


def named(message: str, after: str) -> list[int]:
    """The numbers listed after `after` in a message ("triangles 3, 7, 12" -> [3, 7, 12])."""
    import re

    return [int(x) for x in re.search(re.escape(after) + r" ([\d, and]+)", message).group(1).replace(" and ", ", ")
            .split(", ") if x.strip()]


def test_overlapping_shells_are_refused_with_the_crossing_triangles_named(addon):
    v, f = two_cubes([0.015, 0.008, 0.005])  # the second cube half inside the first
    message = refusal(addon, add_mesh(addon, "Shells", v, f))
    assert "intersects itself" in message
    pairs = np.array(named(message, "first: triangles")).reshape(-1, 2)
    assert len(pairs) and np.all(pairs[:, 0] < 12) and np.all(pairs[:, 1] >= 12), "one triangle of each cube"


def test_two_cubes_along_an_edge_are_refused_with_the_faces_there_named(addon):
    """Sharing the edge's two vertices, the edge has four faces (non-manifold); with a vertex
    each, the cubes' vertices coincide there. Either way the faces at the edge are named."""
    v, f = two_cubes([0.03, 0.03, 0.0], merged=True)
    message = refusal(addon, add_mesh(addon, "Shared", v, f))
    edge = np.flatnonzero(np.all(np.isclose(v[:, :2], 0.015), axis=1))  # the vertices on x = y = 1.5 cm
    assert len(edge) == 2 and "non-manifold" in message
    at_edge = np.flatnonzero(np.isin(f, edge).sum(axis=1) == 2)
    assert len(at_edge) == 4 and named(message, "triangles") == at_edge.tolist()

    v, f = two_cubes([0.03, 0.03, 0.0])
    message = refusal(addon, add_mesh(addon, "Touching", v, f))
    assert "same position as another" in message
    repeated = np.flatnonzero(np.all(np.isclose(v[:, :2], 0.015), axis=1))  # two of each cube
    faces = named(message, "in triangles")
    assert len(repeated) == 4 and faces and np.all(np.isin(f[faces], repeated).any(axis=1))
    assert min(faces) < 12 <= max(faces), "faces of both cubes"


def test_a_spike_from_a_nan_coordinate_is_refused_with_its_faces_named(addon, tmp_path):
    """Blender's OBJ importer reads a vertex of `nan` coordinates as the origin: a spike far from
    the sphere it belongs to, refused with the vertex and its triangles named."""
    v, f = sphere_surface(0.03)
    lines = [f"v {x + 0.2!r} {y!r} {z!r}" for x, y, z in v]
    lines[57] = "v nan nan nan"
    (tmp_path / "spiked.obj").write_text("\n".join(lines + [f"f {a} {b} {c}" for a, b, c in f + 1]) + "\n")
    bpy.ops.wm.obj_import(filepath=str(tmp_path / "spiked.obj"))
    obj = addon.view_layer.objects.active
    assert obj.name == "spiked"
    imported = meshdata.world_vertices(obj, addon.scene)
    spike = np.flatnonzero(np.all(imported == 0.0, axis=1))
    assert len(spike) == 1, "the importer turned nan into 0"
    message = refusal(addon, obj)
    assert f"spike vertices" in message and f"vertex {spike[0]} at [0.0, 0.0, 0.0] m" in message
    tri = meshdata.triangles(obj.data)
    assert named(message, "in triangles") == np.flatnonzero((tri == spike[0]).any(axis=1)).tolist()


def test_surface_gap_is_the_distance_outside_the_tets():
    """The gap Tetrahedralize reports: a render surface a little larger than its tets lies
    outside them by exactly how much larger it is; points inside have no gap."""
    from haptic_hand.engine import child

    nodes, tets = meshing.structured_box((0.1, 0.06, 0.04), (4, 3, 2), origin=(-0.05, -0.03, -0.02))
    corners, _ = box_surface(np.array([0.05, 0.03, 0.02]) + [0.001, 0.0005, 0.002])
    mid_faces = np.array([[0.0501, 0.0, 0.0], [0.0, 0.0, -0.0203], [0.01, 0.01, 0.0]])
    gap = child.surface_gap(nodes, tets, np.vstack([corners, mid_faces]))
    np.testing.assert_allclose(gap[:8], np.linalg.norm([0.001, 0.0005, 0.002]), rtol=1e-9)
    np.testing.assert_allclose(gap[8:], [0.0001, 0.0003, 0.0], atol=1e-12)
    assert "up to 2.29 mm outside" in ops_rig.gap_message(gap)
    assert ops_rig.gap_message(np.zeros(5)) == "the render surface lies inside the tets"


def test_tetrahedralize_in_a_child_streams_progress_and_cancels(addon):
    """The child's stages reach the panel as they happen (fTetWild's log read by the host);
    Cancel kills it and the mesh keeps the tets it had; the message gives the real gap."""
    context = addon
    v, f = meshing.procedural_hand()
    hand = add_mesh(context, "Hand", v, f)
    o = hand.haptic_hand
    o.edge_length_fac, o.coarsen, o.epsilon = 0.2, True, 0.004
    assert bpy.ops.haptic_hand.use_as_hand() == {"FINISHED"}
    job = ops_rig.start_tetrahedralize(context, hand)
    runtime.state.tetrahedralize = job
    from blender_helpers import draw_panels, operators

    assert "haptic_hand.tetrahedralize_cancel" in operators(draw_panels(context))
    seen = []
    while (state := ops_rig.poll_tetrahedralize(context, job)) == "RUNNING":
        if not seen or seen[-1] != (job.progress, job.message):
            seen.append((job.progress, job.message))
        time.sleep(0.005)
    assert state == "FINISHED", job.error
    assert runtime.state.tetrahedralize is None
    from pathlib import Path

    assert not Path(job.child.workdir).exists(), "fTetWild's debug files went with the child's folder"
    messages = [m for _, m in seen]
    progress = [p for p, _ in seen]
    assert progress == sorted(progress) and progress[-1] > 0.8
    for stage in ("simplifying the surface", "inserting the surface", "optimizing (pass"):
        assert any(m.startswith(stage) for m in messages), (stage, messages)
    # the message: the real gap (in mm) of the render surface outside the tets
    nodes, tets = scene_export.hand_tets_world(context.scene)
    from haptic_hand.engine import child

    gap = child.surface_gap(nodes, tets, meshdata.world_vertices(hand, context.scene))
    assert gap.max() > 0 and f"up to {gap.max() * 1000:.2f} mm outside the tets" in job.summary, job.summary
    first = nodes.copy()

    # a finer run, cancelled part-way: the process is killed, the hand keeps its tets
    o.edge_length_fac, o.coarsen = 0.03, False
    job = ops_rig.start_tetrahedralize(context, hand)
    while ops_rig.poll_tetrahedralize(context, job) == "RUNNING" and job.progress < 0.2:
        time.sleep(0.005)
    job.cancel()
    assert ops_rig.poll_tetrahedralize(context, job) == "CANCELLED"
    assert job.child.process.returncode < 0 and not job.folder.exists()
    np.testing.assert_array_equal(scene_export.hand_tets_world(context.scene)[0], first)


def test_tet_count_estimate_asks_above_the_limit(addon):
    """The estimate is near what fTetWild makes, and above Confirm above Tetrahedralize asks
    (from a script: refuses unless confirmed=True) before starting anything."""
    from haptic_hand.engine import child

    context = addon
    v, f = meshing.procedural_hand()
    hand = add_mesh(context, "Hand", v, f)
    o = hand.haptic_hand
    o.edge_length_fac, o.coarsen, o.epsilon = 0.2, True, 0.004
    s = context.scene.haptic_hand
    estimate = ops_rig.tet_estimate(hand, context.scene)
    s.tet_confirm_limit = estimate - 1
    before = _state(context)
    with pytest.raises(RuntimeError, match=f"about {estimate} tets, more than Rig > Confirm above"):
        bpy.ops.haptic_hand.tetrahedralize()
    assert _state(context) == before
    assert bpy.ops.haptic_hand.tetrahedralize(confirmed=True) == {"FINISHED"}
    made = len(hand.haptic_hand.tet_object.data[meshdata.TETS_KEY]) // 4
    assert estimate / 2 < made < estimate * 2, (estimate, made)
    # a ten times smaller edge length: the volume's share grows a thousandfold
    coarse = child.estimate_tets(v, f, 0.1, 1.0) - child.estimate_tets(v, f, 1.0, 1.0)
    fine = child.estimate_tets(v, f, 0.01, 1.0) - child.estimate_tets(v, f, 1.0, 1.0)
    assert fine / coarse == pytest.approx(1000, rel=0.02)


def test_check_rig_in_blender_reports_the_droop_and_refuses_a_soft_rig(addon, built_scenes, tmp_path, monkeypatch):
    """Check Rig runs the engine's static settle on the exported scene. With the sample's springs
    the hand is ready; with springs of 20 N/m the hand's weight M g hangs on the handle's n
    springs, which stretch about M g / (n k) (11 mm for the sample's 301 g on 13 nodes): the rig is
    refused, in Blender's report, with the droop and the fix."""
    from blender_helpers import open_copy

    from haptic_hand.engine import rig_check

    context = open_copy(built_scenes("hand_wave"), tmp_path)
    seen = []
    real = rig_check.format_report
    monkeypatch.setattr(rig_check, "format_report", lambda report: seen.append(report) or real(report))
    assert bpy.ops.haptic_hand.check_rig() == {"FINISHED"}
    checks = {c["name"]: c for c in seen[-1]["checks"]}
    assert checks["droop"]["ok"] and checks["droop"]["droop"] < rig_check.DROOP_LIMIT
    context.scene.haptic_hand.spring_stiffness = 20.0
    with pytest.raises(RuntimeError, match=r"mm under gravity.*try stiffer springs"):  # the ERROR report
        bpy.ops.haptic_hand.check_rig()
    checks = {c["name"]: c for c in seen[-1]["checks"]}
    droop, handle = checks["droop"], checks["handle"]
    assert not droop["ok"] and droop["droop"] > rig_check.DROOP_LIMIT
    hand_mass = float(handle["detail"].split(" of ")[-1].split()[0]) * 1e-3  # "... mass 55.8 g of 301.3 g"
    nodes = int(handle["detail"].split()[0])
    expected = hand_mass * 9.81 / (nodes * 20.0)
    assert 0.8 * expected < droop["spring_stretch"] < 1.3 * expected, (droop["spring_stretch"], expected)


def test_tetrahedralize_warns_of_a_hand_modelled_in_millimetres(addon, capfd):
    """The procedural hand (19 cm) modelled in millimetres and read as metres is 190 m long: a
    WARNING report names the unit it looks modelled in and the factor; a hand of human size
    gets none, and neither does a soft body of any size."""
    context = addon
    v, f = meshing.procedural_hand()
    length = float(np.ptp(v, axis=0).max())
    hand = add_mesh(context, "Hand", v * 1000, f)
    o = hand.haptic_hand
    o.edge_length_fac, o.coarsen, o.epsilon = 0.2, True, 0.004
    assert bpy.ops.haptic_hand.use_as_hand() == {"FINISHED"}
    capfd.readouterr()
    assert bpy.ops.haptic_hand.tetrahedralize() == {"FINISHED"}
    out = capfd.readouterr().out
    expected = (f"Warning: 'Hand': the hand is {length * 1000:.4g} m long, far from a human hand's 5-50 cm: it looks "
                f"modelled in millimetres ({length * 1000:.4g} millimetres = {length * 100:.3g} cm): scale it by 0.001")
    assert expected in out, out
    assert out.index(expected) < out.index("Info: 'Hand':"), "warned when it starts, before the tets are made"

    human = add_mesh(context, "Human", v, f)
    context.scene.haptic_hand.hand = human
    job = ops_rig.start_tetrahedralize(context, human)
    job.cancel(), job.child.wait(), job.release()
    assert job.warnings == []
    giant = add_mesh(context, "Giant", v * 1000, f)  # not the hand: a soft body has no human size
    job = ops_rig.start_tetrahedralize(context, giant)
    job.cancel(), job.child.wait(), job.release()
    assert job.warnings == []


def test_bake_warns_of_a_hand_modelled_in_millimetres(addon, built_scenes, tmp_path, capfd):
    """The sample hand scaled by 1000 (a hand in millimetres read as metres): Bake warns when it
    starts, Check Rig lists the warning; with the handle radius left in centimetres the bake is
    refused, and the refusal says why."""
    from blender_helpers import open_copy

    context = open_copy(built_scenes("hand_wave"), tmp_path)
    s = context.scene.haptic_hand
    s.bake_frame_end = s.bake_frame_start + 2
    length = float(np.ptp(meshdata.world_vertices(s.hand, context.scene), axis=0).max())
    s.hand.scale = (1000.0,) * 3
    context.view_layer.update()
    with pytest.raises(RuntimeError, match=r"captures 0 node.*it looks modelled in millimetres.*scale it by 0.001"):
        bpy.ops.haptic_hand.bake()
    assert not s.baked

    s.handle_radius *= 1000  # the handle now catches the nodes it caught before; no gravity to hang on it
    context.scene.use_gravity = False
    capfd.readouterr()
    bpy.ops.haptic_hand.bake()
    out = capfd.readouterr().out
    expected = f"Warning: the hand is {length * 1000:.4g} m long, far from a human hand's 5-50 cm: it looks modelled in " \
               "millimetres"
    assert expected in out and out.index(expected) < out.index("Info:"), out
    capfd.readouterr()
    bpy.ops.haptic_hand.check_rig()  # and Check Rig lists it with its report
    assert f"warning: the hand is {length * 1000:.4g} m long" in capfd.readouterr().out
