"""The native World of a scene: the hand with its collision surface and the other bodies,
kinematic ones given their scripts. Shared by offline runs (simulate) and live sessions."""

from __future__ import annotations

from . import bodies
from . import mesh as meshing
from . import native_world, params
from . import scene as scenes


def build_world(scene: scenes.Scene, progress=None):
    """The native World of a scene: the hand (its render surface embedded in its tets as the
    collision surface) and the other bodies. Returns (world, hand index, hand model, bodies)."""
    model = scenes.build_model(scene, progress=progress)
    world = native_world.World(**scene.struct_values(params.STRUCT_WORLD_PARAMS))
    tet_index, weights = meshing.embed_points(scene.nodes, scene.tets, scene.surface_vertices)
    sn, sw = native_world.embedded_surface(scene.tets, tet_index, weights)
    hand_spec = scene.data["hand"]
    hand = world.add_hand(model, sn, sw, scene.surface_faces, friction=hand_spec["friction"],
                          self_collision=hand_spec["self_collision"])
    if hand_spec["kinetic_friction"] is not None:
        world.set_friction(hand, hand_spec["friction"], hand_spec["kinetic_friction"])
    others = [bodies.prepare(spec) for spec in scene.bodies]
    bodies.check_overlaps(scene.surface_vertices, scene.surface_faces, others, scene.data["contact"]["thickness"])
    for b in others:
        bodies.add_to_world(world, b)
        if b.kind == native_world.KINEMATIC:  # the world moves it along its script itself
            script = scenes.body_trajectory(b.spec, world.pose(b.index)[0])
            world.set_script(b.index, script.times, script.positions, script.quaternions)
    return world, hand, model, others, (tet_index, weights)
