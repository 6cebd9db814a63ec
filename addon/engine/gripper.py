"""A two-finger soft gripper, the smallest skeleton hand that grasps (issue 40): a palm block and
two fingers hanging from it, cut from one structured tet grid (so the flesh joins them), with one
bone for the palm and one per finger; and the soft objects it holds, a voxel ball and a soft
letter. Used by tests/engine/test_grasp.py and bench/bench_grasp.py."""

import numpy as np

from haptic_hand.engine import mesh
from haptic_hand.engine import native_skeleton as ns
from haptic_hand.engine import native_world as nw
from haptic_hand.engine import shapes
from haptic_hand.engine import skeleton as sk

CELL = 0.005   # m, the grid's spacing
FINGER = 0.015  # m, each finger's width along x
LENGTH = 0.05  # m, the fingers' length below the palm (z < 0)
DEPTH = 0.02   # m, along y
HAND = dict(young_modulus=5e4, poisson_ratio=0.3, density=1000.0, rayleigh_alpha=8.0, rayleigh_beta=0.01,
            spring_stiffness=1e4, spring_damping=10.0)


def keep_tets(nodes, tets, keep):
    """The tets where keep, with the nodes they use renumbered in order."""
    tets = tets[keep]
    used = np.unique(tets)
    number = np.full(len(nodes), -1)
    number[used] = np.arange(len(used))
    return nodes[used], number[tets].astype(np.int32)


def gripper(gap: float):
    """(nodes, tets, skeleton): fingers FINGER wide with `gap` between them (a multiple of CELL),
    the palm 2 cells thick above z = 0, bones on the palm's and each finger's axis."""
    width = 2 * FINGER + gap
    cells = np.rint(np.array([width, DEPTH, LENGTH + 2 * CELL]) / CELL).astype(int)
    nodes, tets = mesh.structured_box((width, DEPTH, LENGTH + 2 * CELL), cells, (0.0, -DEPTH / 2, -LENGTH))
    c = nodes[tets].mean(axis=1)
    nodes, tets = keep_tets(nodes, tets, ~((c[:, 0] > FINGER) & (c[:, 0] < FINGER + gap) & (c[:, 2] < 0)))
    left, right = FINGER / 2, width - FINGER / 2
    bones = [sk.Bone("palm", None, np.array([CELL, 0, 0.012]), np.array([width - CELL, 0, 0.012]), 0.012),
             sk.Bone("left", "palm", np.array([left, 0, -CELL]), np.array([left, 0, -LENGTH + CELL]), 0.011),
             sk.Bone("right", "palm", np.array([right, 0, -CELL]), np.array([right, 0, -LENGTH + CELL]), 0.011)]
    return nodes, tets, sk.Skeleton(bones)


def add_gripper(world: nw.World, gap: float, friction: float, gravity, solver: str = "cholesky"):
    """The gripper in the world, its flesh on `solver` (the hand's solver.name); returns (hand
    body, model, rest nodes)."""
    nodes, tets, skeleton = gripper(gap)
    model = ns.SkeletonModel(nodes, tets, skeleton, dt=world.dt, gravity=list(gravity), solver=solver, **HAND)
    surface_nodes, surface_weights = nw.vertex_surface(len(nodes))
    hand = world.add_hand(model, surface_nodes, surface_weights, mesh.tet_boundary_faces(tets), friction=friction)
    return hand, model, nodes


def voxel_ball(radius: float, centre, cell: float = 0.004):
    """A ball of the grid's cubes whose centres lie within radius: (nodes, tets)."""
    n = int(np.ceil(2 * radius / cell))
    nodes, tets = mesh.structured_box((n * cell,) * 3, (n,) * 3, np.asarray(centre) - n * cell / 2)
    cube_centres = np.floor((nodes[tets].mean(axis=1) - nodes.min(axis=0)) / cell) * cell + cell / 2 + nodes.min(axis=0)
    return keep_tets(nodes, tets, np.linalg.norm(cube_centres - centre, axis=1) <= radius)


def add_soft(world: nw.World, nodes, tets, friction: float, **material) -> int:
    surface_nodes, surface_weights = nw.vertex_surface(len(nodes))
    return world.add_soft_body(nodes, tets, surface_nodes, surface_weights, mesh.tet_boundary_faces(tets),
                               friction=friction, **material)


def letter(ch: str, centre):
    """shapes.letter_tets(ch) (4 cm tall, 12 mm deep), its bounding box centred at centre."""
    nodes, tets = shapes.letter_tets(ch)
    return nodes + (np.asarray(centre) - 0.5 * (nodes.min(axis=0) + nodes.max(axis=0))), tets


# The grasp scene: close, lift, hold 2 s, open (tests/engine/test_grasp.py, bench/bench_grasp.py)
DT = 1.0 / 30.0
GAP = 0.025       # m between the fingers: the ball (20 mm across) clears each by 2.5 mm open
SQUEEZE = 0.004   # m each finger moves in to close
LIFT = 0.03       # m the palm rises with the ball
BALL = dict(young_modulus=3e4, poisson_ratio=0.3, density=500.0)
CLOSE, LIFTED, HELD, OPEN_FOR = 10, 25, 85, 15   # steps: closed by, lifted by, held until; then open


def grasp_world(friction: float, hand_solver: str = "cholesky", **world):
    """The gripper open above a ground plane, a soft ball (8.5 mm voxel radius) resting on the
    ground between its fingers; friction on every pair; the hand's flesh on hand_solver; world:
    more hh_world_params (threads). Returns (world, hand, ball)."""
    w = nw.World(dt=DT, gravity=[0.0, 0.0, -9.81], **world)
    hand, _, _ = add_gripper(w, GAP, friction, (0.0, 0.0, -9.81), hand_solver)
    nodes, tets = voxel_ball(0.0085, np.array([FINGER + GAP / 2, 0.0, -0.035]))
    w.add_plane([0.0, 0.0, nodes[:, 2].min() - 0.001], [0.0, 0.0, 1.0], friction=friction)
    ball = add_soft(w, nodes, tets, friction, **BALL)
    return w, hand, ball


def grasp_targets(p0, k: int):
    """Bone positions at step k: the fingers close over CLOSE steps, the palm (and the fingers with
    it) rises LIFT over the next ones; from HELD on the fingers are back at their rest spread."""
    p = p0.copy()
    closed = min(1.0, k / CLOSE) if k < HELD else 0.0
    p[1, 0] += SQUEEZE * closed
    p[2, 0] -= SQUEEZE * closed
    p[:, 2] += LIFT * np.clip((k - CLOSE) / (LIFTED - CLOSE), 0.0, 1.0)
    return p
