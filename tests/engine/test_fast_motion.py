"""Fast motion does not tunnel (issue 39): cubes, spheres and a fingertip at 1, 5 and 20 m/s
against a plane, a thin static box and a soft pad, and a kinematic pusher into a soft body.
At 20 m/s a 1/30 s step moves 67 cm, 670 contact thicknesses and 170 times the thin box's
thickness. After every step the overlap of the two surfaces is measured here, independently
of the engine's contacts: analytically against planes, boxes and spheres, and by a winding
number and point-triangle distances against deforming surfaces. It must stay within the
contact thickness, and nothing may end on the far side."""

import numpy as np
import pytest

from haptic_hand.engine import mesh
from haptic_hand.engine import native_world as W
from test_contact import cube_surface
from test_hand_contact import add_hand, box_surface

DT, THICKNESS = 1 / 30, 1e-3


@pytest.fixture(scope="module")
def hand_surface():
    return mesh.procedural_hand()
SPEEDS = (1.0, 5.0, 20.0)
PAD = 0.06  # soft pad: a 6 cm cube, its bottom fixed, its top face at z = 0
THIN = 0.004  # thin static box: 4 mm, its top face at z = 0
AIM = np.array([0.003, 0.002, 0.0])  # where projectiles land: off the pad's grid lines


# --- independent geometry ---------------------------------------------------------------------

def icosphere(radius: float, subdivisions: int = 2):
    t = (1 + 5 ** 0.5) / 2
    v = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
         [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
         [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11],
         [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    v = [np.array(p, float) / np.linalg.norm(p) for p in v]
    for _ in range(subdivisions):
        mid, out = {}, []

        def middle(a, b):
            key = (min(a, b), max(a, b))
            if key not in mid:
                m = v[a] + v[b]
                v.append(m / np.linalg.norm(m))
                mid[key] = len(v) - 1
            return mid[key]

        for a, b, c in f:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            out += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        f = out
    return radius * np.array(v), np.array(f)


def winding_number(points, v, f):
    """Generalized winding number of a closed triangle surface (Van Oosterom and Strackee's
    solid angle): 1 inside, 0 outside."""
    a, b, c = (v[f[:, k]][None, :, :] - points[:, None, :] for k in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
    det = np.einsum("ijk,ijk->ij", a, np.cross(b, c))
    den = (la * lb * lc + np.einsum("ijk,ijk->ij", a, b) * lc + np.einsum("ijk,ijk->ij", b, c) * la
           + np.einsum("ijk,ijk->ij", c, a) * lb)
    return np.arctan2(det, den).sum(axis=1) / (2 * np.pi)


def _segment_distance(p, a, b):
    ab = b - a
    s = np.clip(np.einsum("ijk,ijk->ij", p - a, ab) / np.maximum(np.einsum("ijk,ijk->ij", ab, ab), 1e-300), 0, 1)
    return np.linalg.norm(p - a - s[..., None] * ab, axis=2)


def triangle_distance(points, v, f):
    """Each point's distance to the nearest triangle: to its plane where the projection falls
    inside, else to the nearest edge."""
    p = points[:, None, :]
    a, b, c = (v[f[:, k]][None, :, :] for k in range(3))
    n = np.cross(b - a, c - a)
    n = n / np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-300)
    h = np.einsum("ijk,ijk->ij", p - a, n)
    q = p - h[..., None] * n
    inside = np.ones(h.shape, bool)
    for u, w in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ijk,ijk->ij", np.cross(w - u, q - u), n) >= 0
    edges = np.minimum(np.minimum(_segment_distance(p, a, b), _segment_distance(p, b, c)), _segment_distance(p, c, a))
    return np.where(inside, np.abs(h), edges).min(axis=1)


def depth_inside(points, v, f) -> float:
    """How deep the deepest of `points` lies inside the closed surface (v, f); 0 if none does."""
    inside = winding_number(points, v, f) > 0.5
    return float(triangle_distance(points[inside], v, f).max()) if inside.any() else 0.0


def rotate(q, p):
    x, y, z, s = q
    u = np.array([x, y, z])
    return p + 2 * np.cross(u, np.cross(u, p) + s * p)


def box_depth(points, centre, half, q=(0, 0, 0, 1)) -> float:
    """Deepest point inside a box (centre, half extents, orientation q (x, y, z, s)); 0 if none."""
    local = rotate(np.array([-q[0], -q[1], -q[2], q[3]]), points - centre)
    return float(max(0.0, np.min(half - np.abs(local), axis=1).max()))


# --- projectiles ------------------------------------------------------------------------------

class Rigid:
    """A rigid cube (2 cm) or sphere (1 cm radius) launched straight down at the target."""

    def __init__(self, world, shape: str, speed: float, bottom: float):
        self.v, self.f = cube_surface(0.01) if shape == "cube" else icosphere(0.01)
        self.world = world
        start = AIM + [0, 0, bottom + 0.01]  # both reach 1 cm below their centre
        self.body = world.add_mesh_body(W.RIGID, self.v + start, self.f, friction=0.5)
        world.set_pose(self.body, start, [0, 0, 0, 1], [0, 0, -speed], [0, 0, 0])

    def step(self):
        pass

    def centre(self):
        return self.world.pose(self.body)[0]

    def vertices(self):
        p, q = self.world.pose(self.body)[:2]
        return p + rotate(q, self.v - self.v.mean(axis=0))

    def depth_of(self, points) -> float:
        return depth_inside(points, self.vertices(), self.f)


class Fingertip:
    """The procedural hand (fingers pointing down) thrown down at `speed`: every node and the
    handle moving together, the handle prescribed to go on at that speed until the fingertips
    would touch, then to stop there. The flesh's momentum carries the tips into the target."""

    def __init__(self, world, rig, surface, speed: float, bottom: float):
        self.world, self.faces = world, surface[1]
        self.hand, com = add_hand(world, rig, surface)
        tip = surface[0][np.argmin(surface[0][:, 2])]
        shift = AIM + [0, 0, bottom] - tip  # the lowest fingertip above the aim
        x, _ = world.nodes(self.hand)
        world.set_nodes(self.hand, x + shift, np.tile([0, 0, -speed], (len(x), 1)))
        self.com = com + shift
        world.set_pose(self.hand, self.com, [0, 0, 0, 1], [0, 0, -speed], [0, 0, 0])
        self.stop, self.speed, self.t = self.com[2] - bottom, speed, 0.0

    def step(self):
        self.t += DT
        z = max(self.com[2] - self.speed * self.t, self.stop)
        moving = z > self.stop
        self.world.set_device(self.hand, [self.com[0], self.com[1], z], [0, 0, 0, 1],
                              [0, 0, -self.speed * moving], [0, 0, 0], enabled=2)

    def centre(self):
        return self.world.hand_state(self.hand)[0]

    def vertices(self):
        return self.world.surface(self.hand)

    def depth_of(self, points) -> float:
        return depth_inside(points, self.vertices(), self.faces)


# --- targets ----------------------------------------------------------------------------------

class Plane:
    def __init__(self, world):
        world.add_plane([0, 0, 0], [0, 0, 1], friction=0.5)

    def depth(self, projectile) -> float:
        return float(max(0.0, -projectile.vertices()[:, 2].min()))

    def passed(self, projectile) -> bool:
        return projectile.centre()[2] < 0


class ThinBox:
    def __init__(self, world):
        v, f = box_surface([-0.1, -0.1, -THIN], [0.1, 0.1, 0.0])
        world.add_mesh_body(W.STATIC, v, f, friction=0.5)

    def depth(self, projectile) -> float:
        return box_depth(projectile.vertices(), np.array([0, 0, -THIN / 2]), np.array([0.1, 0.1, THIN / 2]))

    def passed(self, projectile) -> bool:
        return projectile.centre()[2] < -THIN / 2 or projectile.vertices()[:, 2].min() < -THIN


class SoftPad:
    """A 6 cm soft cube (E = 1e5 Pa, like firm foam) with its bottom face fixed."""

    def __init__(self, world):
        nodes, tets = mesh.structured_box([PAD] * 3, [6] * 3, (-PAD / 2, -PAD / 2, -PAD))
        self.faces = mesh.tet_boundary_faces(tets)
        sn, sw = W.vertex_surface(len(nodes))
        fixed = np.flatnonzero(nodes[:, 2] < -PAD + 1e-9).astype(np.int32)
        self.world = world
        self.body = world.add_soft_body(nodes, tets, sn, sw, self.faces, fixed_nodes=fixed, friction=0.5,
                                        young_modulus=1e5)

    def depth(self, projectile) -> float:
        x = self.world.surface(self.body)
        return max(depth_inside(projectile.vertices(), x, self.faces), projectile.depth_of(x))

    def passed(self, projectile) -> bool:
        return projectile.centre()[2] < -PAD


TARGETS = {"plane": Plane, "thin box": ThinBox, "soft pad": SoftPad}


def throw(world, projectile, target, steps: int = 8):
    """Steps the throw; returns the deepest overlap measured and the closest approach."""
    deepest, lowest = 0.0, np.inf
    for _ in range(steps):
        projectile.step()
        world.step()
        assert not target.passed(projectile), "it went through"
        deepest = max(deepest, target.depth(projectile))
        lowest = min(lowest, projectile.vertices()[:, 2].min())
    return deepest, lowest


def launch_height(speed: float) -> float:
    # half a step's travel above the target: the surfaces meet in the middle of the first step
    return 0.5 * speed * DT + 2 * THICKNESS


@pytest.mark.parametrize("speed", SPEEDS)
@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("shape", ["cube", "sphere"])
def test_a_fast_rigid_body_does_not_tunnel(shape, target, speed):
    world = W.World(dt=DT, gravity=[0, 0, 0], contact_thickness=THICKNESS)
    goal = TARGETS[target](world)
    body = Rigid(world, shape, speed, launch_height(speed))
    deepest, lowest = throw(world, body, goal)
    assert lowest < 0.5 * speed * DT  # it did reach the target within the run
    assert deepest <= THICKNESS


@pytest.mark.parametrize("speed", SPEEDS)
@pytest.mark.parametrize("target", TARGETS)
def test_a_fast_fingertip_does_not_tunnel(procedural_rig, hand_surface, target, speed):
    world = W.World(dt=DT, gravity=[0, 0, 0], contact_thickness=THICKNESS)
    goal = TARGETS[target](world)
    hand = Fingertip(world, procedural_rig, hand_surface, speed, launch_height(speed))
    deepest, lowest = throw(world, hand, goal, steps=6)
    assert lowest < 2 * THICKNESS + 1e-3  # the tips did reach the target
    assert deepest <= THICKNESS


@pytest.mark.parametrize("speed", SPEEDS)
def test_a_fast_kinematic_pusher_does_not_tunnel_into_a_soft_body(speed):
    """A scripted 2 cm box driven down into the soft pad: it cannot be stopped, so the pad must
    give way in front of it."""
    world = W.World(dt=DT, gravity=[0, 0, 0], contact_thickness=THICKNESS)
    pad = SoftPad(world)
    v, f = cube_surface(0.01)
    start = launch_height(speed) + 0.01
    travel = 0.02  # it stops 2 cm deep in the pad's rest volume
    body = world.add_mesh_body(W.KINEMATIC, v + AIM + [0, 0, start], f, friction=0.5)
    times = [0.0, (start - 0.01 + travel) / speed, 10.0]
    end = AIM + [0, 0, 0.01 - travel]
    world.set_script(body, times, [AIM + [0, 0, start], end, end])
    pusher = Rigid.__new__(Rigid)
    pusher.v, pusher.f, pusher.world, pusher.body = v, f, world, body
    deepest, lowest = throw(world, pusher, pad, steps=8)
    assert lowest < -0.5 * travel
    assert deepest <= THICKNESS


@pytest.mark.parametrize("target", TARGETS)
def test_a_fast_spinning_cube_thrown_at_a_slant_does_not_tunnel(target):
    """20 m/s at 45 degrees with a 60 rad/s spin: its corners sweep 20 mm more per step than
    its centre, and the hit is on an edge or a corner."""
    world = W.World(dt=DT, gravity=[0, 0, 0], contact_thickness=THICKNESS)
    goal = TARGETS[target](world)
    speed = 20.0
    body = Rigid(world, "cube", speed, launch_height(speed) * 2 ** -0.5)
    start = world.pose(body.body)[0] - [0.5 * speed * DT * 0.5 ** 0.5, 0, 0]
    world.set_pose(body.body, start, [0, 0, 0, 1], speed * np.array([0.5 ** 0.5, 0, -0.5 ** 0.5]), [20.0, 50.0, 30.0])
    deepest, lowest = throw(world, body, goal)
    assert lowest < 0.01
    assert deepest <= THICKNESS


# --- pairs moving together: the reach follows their motion relative to each other ----------------

SIDEWAYS = np.array([20.0, 0.0, 0.0])  # m/s: the frame both bodies move with


class DriftingPad(SoftPad):
    """The soft pad free (nothing fixed) and carried sideways at 20 m/s with every node."""

    def __init__(self, world):
        nodes, tets = mesh.structured_box([PAD] * 3, [6] * 3, (-PAD / 2, -PAD / 2, -PAD))
        self.faces = mesh.tet_boundary_faces(tets)
        sn, sw = W.vertex_surface(len(nodes))
        self.world = world
        self.body = world.add_soft_body(nodes, tets, sn, sw, self.faces, friction=0.5, young_modulus=1e5)
        world.set_nodes(self.body, velocities=np.tile(SIDEWAYS, (len(nodes), 1)))

    def passed(self, projectile) -> bool:
        pad_top = self.world.nodes(self.body)[0][:, 2].max()
        return projectile.centre()[2] < pad_top - PAD


@pytest.mark.parametrize("speed", SPEEDS)
def test_a_body_thrown_at_a_pad_both_carried_sideways_does_not_tunnel(speed):
    """Both move at 20 m/s sideways, the cube also down at `speed`: seen from their common
    frame this is the soft-pad throw, and the pair's search must see the closing speed in it
    (the sideways motion, 67 cm a step, cancels; the downward one does not)."""
    world = W.World(dt=DT, gravity=[0, 0, 0], contact_thickness=THICKNESS)
    pad = DriftingPad(world)
    body = Rigid(world, "cube", speed, launch_height(speed))
    world.set_pose(body.body, world.pose(body.body)[0], [0, 0, 0, 1], SIDEWAYS + [0, 0, -speed], [0, 0, 0])
    deepest, lowest = throw(world, body, pad)
    assert lowest < 0.5 * speed * DT
    assert deepest <= THICKNESS


def stacked_blocks(velocity) -> tuple:
    """Two free 3 cm soft blocks, one above the other with a gap of one contact thickness (where
    resting contacts settle), every node moving at `velocity`; returns the world and bodies."""
    world = W.World(dt=DT, gravity=[0, 0, 0], contact_thickness=THICKNESS)
    bodies = []
    for bottom in (-0.03, THICKNESS):
        nodes, tets = mesh.structured_box([0.03] * 3, [3] * 3, (-0.015, -0.015, bottom))
        sn, sw = W.vertex_surface(len(nodes))
        body = world.add_soft_body(nodes, tets, sn, sw, mesh.tet_boundary_faces(tets), friction=0.5,
                                   young_modulus=1e5)
        world.set_nodes(body, velocities=np.tile(velocity, (len(nodes), 1)))
        bodies.append(body)
    return world, bodies


def test_two_blocks_carried_together_find_the_contacts_they_find_at_rest():
    """Carried at 20 m/s, 67 cm a step, the pair is searched by its motion relative to itself
    (none): each step finds the contacts the same blocks find at rest where they are, not every
    vertex within 67 cm. And nothing pushes: they keep their velocity and their gap."""
    world, (lower, upper) = stacked_blocks(SIDEWAYS)
    for _ in range(3):
        still, _ = stacked_blocks(np.zeros(3))
        for body in (lower, upper):
            still.set_nodes(body, positions=world.nodes(body)[0])
        at_rest = still.step()["contacts"]
        assert at_rest > 0
        assert world.step()["contacts"] == at_rest
    for body in (lower, upper):
        assert np.abs(world.nodes(body)[1] - SIDEWAYS).max() < 1e-9
    gap = world.nodes(upper)[0][:, 2].min() - world.nodes(lower)[0][:, 2].max()
    assert abs(gap - THICKNESS) < 1e-9


# --- a skeleton hand: each contact at the reach of the bones its points move with --------------

def gripper_world():
    """The 3-bone gripper (palm, left and right fingers, every bone prescribed) in zero gravity."""
    from haptic_hand.engine import gripper as gr
    world = W.World(dt=DT, gravity=[0, 0, 0], contact_thickness=THICKNESS)
    hand, _, _ = gr.add_gripper(world, 0.03, 0.5, (0.0, 0.0, 0.0))
    return world, hand, gr


def swing_right_finger(world, hand, gr, angle: float) -> None:
    """Targets: the palm and left finger at rest, the right finger turned by `angle` about y
    at its head (negative: its tip swings out, towards +x), reached at the end of the step."""
    p, q = world.bone_states(hand)[:2]
    head = np.array([2 * gr.FINGER + 0.03 - gr.FINGER / 2, 0.0, -gr.CELL])
    c, s = np.cos(angle), np.sin(angle)
    turn = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    p, q = p.copy(), q.copy()
    p[2] = head + turn @ (p[2] - head)
    q[2] = [0.0, np.sin(angle / 2), 0.0, np.cos(angle / 2)]
    world.set_bone_targets(hand, np.full(3, 2, dtype=np.int32), p, q)


def test_a_finger_swinging_fast_leaves_its_resting_neighbours_contacts_as_they_are():
    """The left fingertip rests one thickness above a static block; the right finger swings
    out at 0.5 rad a step (its tip 2.2 cm a step). The block's contacts are the left finger's:
    at its own reach, the ones it finds with the right finger still, not every vertex within
    the right tip's travel."""
    counts = {}
    for angle in (0.0, -0.5):
        world, hand, gr = gripper_world()
        v, f = box_surface([-0.005, -0.02, -gr.LENGTH - THICKNESS - 0.004], [0.012, 0.02, -gr.LENGTH - THICKNESS])
        world.add_mesh_body(W.STATIC, v, f, friction=0.5)
        swing_right_finger(world, hand, gr, angle)
        counts[angle] = world.step()["contacts"]
    assert counts[0.0] > 0
    assert counts[-0.5] == counts[0.0]


def test_a_finger_swung_fast_into_a_thin_wall_does_not_tunnel():
    """The right finger swings out at 0.5 rad a step into a 4 mm static wall 5 mm beside it.
    Its bone is prescribed and goes through; its flesh must stay out: no surface vertex deeper
    in the wall than the thickness, and none beyond it."""
    world, hand, gr = gripper_world()
    outer = 2 * gr.FINGER + 0.03  # the right finger's outer face
    lo, hi = np.array([outer + 0.005, -0.05, -0.08]), np.array([outer + 0.009, 0.05, 0.0])
    v, f = box_surface(lo, hi)
    world.add_mesh_body(W.STATIC, v, f, friction=0.5)
    touched = False
    for k in range(1, 4):
        swing_right_finger(world, hand, gr, -0.5 * k)
        world.step()
        x = world.surface(hand)
        assert box_depth(x, (lo + hi) / 2, (hi - lo) / 2) <= THICKNESS
        assert x[:, 0].max() < hi[0]
        touched |= x[:, 0].max() > lo[0] - 2 * THICKNESS
    assert touched  # the finger did reach the wall
