"""An independent numpy/scipy reference of ONE implicit step of the hand driven by B rigid bones
(docs/skeleton.md): co-rotational FEM (Mueller & Gross 2004) with lumped masses (Eq. 2), each
bone a rigid body with the mass and inertia of its nodes (Eq. 3), zero-rest-length damped
springs per bone (Eqs. 4-5), each bone's virtual coupling to its target, and the
semi-implicit (linearized backward) Euler step of Eq. 7 assembled as ONE sparse matrix and
solved monolithically. With one bone it is today's native step (test_skeleton.py checks it);
with B bones it is what the native Schur solve must reproduce.

Written from the paper and docs/maths.md, not from the native code: the polar rotation by
SVD, the element force as -R K_e (R^T x - X) with K_e rotated block by block, the rotation
derivatives as -[R r]x (Eq. 14 times G for a unit quaternion), every bone's unknowns
(v_b, omega_b) in world axes. Conventions it shares with the native step on purpose (they are
the model, not the implementation): handle derivatives in (x_b, theta_b) with theta a
world-frame rotation increment; A = M - dt D - dt^2 K with D, K the force Jacobians at the
start of the step and b = M v + dt (F(x, v) - D v), which drops every force linear in the
velocities (Rayleigh and spring damping) from b; Rayleigh damping (alpha M + beta K) with
K = R K_e R^T; gravity on the flesh only (a bone's mass is its nodes' counted again, for
inertia); the gyroscopic torque -omega x (I omega) explicit; the coupling to the target taken
at the end of the step, implicit in the bone's own state only; the rotation advanced by the
exponential map q <- exp(dt omega) q. docs/skeleton.md lists them with what the tests found.

Ball joints (docs/skeleton.md Section 5), when the rig has joint_k or joint_d: per joint a
zero-rest-length damped spring between the child's rest head as a point of the parent and of the
child, written here with each point's velocity Jacobian J = [I, -[R r]x] (v_point = J (v, omega)):
F = -k e - d de/dt on the child, wrench J^T F on the child and -J^T F on the parent, implicit in
both bones (their diagonal blocks of A_h and the blocks between them).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

FREE, COUPLED, PRESCRIBED = 0, 1, 2


# --------------------------------------------------------------------------------------------
# Small rotation helpers (quaternions (x, y, z, s), as everywhere in the project)
# --------------------------------------------------------------------------------------------


def skew(a: np.ndarray) -> np.ndarray:
    """[a]x for a (..., 3): (..., 3, 3)."""
    a = np.asarray(a, dtype=float)
    out = np.zeros(a.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -a[..., 2], a[..., 1]
    out[..., 1, 0], out[..., 1, 2] = a[..., 2], -a[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -a[..., 1], a[..., 0]
    return out


def quat_matrix(q: np.ndarray) -> np.ndarray:
    x, y, z, s = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - s * z), 2 * (x * z + s * y)],
                     [2 * (x * y + s * z), 1 - 2 * (x * x + z * z), 2 * (y * z - s * x)],
                     [2 * (x * z - s * y), 2 * (y * z + s * x), 1 - 2 * (x * x + y * y)]])


def quat_multiply(a, b) -> np.ndarray:
    av, aw, bv, bw = np.asarray(a[:3]), a[3], np.asarray(b[:3]), b[3]
    return np.concatenate([aw * bv + bw * av + np.cross(av, bv), [aw * bw - av @ bv]])


def quat_exp(theta) -> np.ndarray:
    """The unit quaternion of the rotation vector theta."""
    angle = float(np.linalg.norm(theta))
    k = 0.5 - angle * angle / 48.0 if angle < 1e-8 else np.sin(0.5 * angle) / angle
    return np.concatenate([k * np.asarray(theta, float), [np.cos(0.5 * angle)]])


def quat_log(q) -> np.ndarray:
    """Rotation vector of q, the shorter way round."""
    q = np.asarray(q, dtype=float)
    q = q if q[3] >= 0 else -q
    vn = np.linalg.norm(q[:3])
    return 2.0 * q[:3] if vn < 1e-12 else 2.0 * np.arctan2(vn, q[3]) / vn * q[:3]


def conjugate(q) -> np.ndarray:
    return np.array([-q[0], -q[1], -q[2], q[3]])


# --------------------------------------------------------------------------------------------
# The rig (static) and the state
# --------------------------------------------------------------------------------------------


@dataclass
class Bone:
    """A rigid bone: its nodes, mass, rest centre of mass, inertia about it in world axes at
    rest (Eq. 3) and each node's r_B = X_i - com (the body frame is the world frame at rest)."""

    nodes: np.ndarray
    mass: float
    com: np.ndarray
    inertia: np.ndarray
    r_body: np.ndarray


def make_bone(rest: np.ndarray, masses: np.ndarray, nodes) -> Bone:
    nodes = np.asarray(nodes, dtype=np.int64)
    m = masses[nodes]
    com = m @ rest[nodes] / m.sum()
    r = rest[nodes] - com
    inertia = sum(mi * (ri @ ri * np.eye(3) - np.outer(ri, ri)) for mi, ri in zip(m, r))
    return Bone(nodes, float(m.sum()), com, inertia, r)


@dataclass
class Rig:
    rest: np.ndarray   # (n, 3)
    tets: np.ndarray   # (m, 4), positively oriented
    young: float = 5e4
    poisson: float = 0.3
    density: float = 1000.0
    alpha: float = 0.0     # Rayleigh, mass
    beta: float = 0.01     # Rayleigh, stiffness
    k: float = 1e4         # springs (Eq. 4)
    d: float = 10.0
    dt: float = 1.0 / 30.0
    gravity: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    bone_nodes: list = field(default_factory=list)  # one node index list per bone
    joint_k: float = 0.0   # ball joints (docs/skeleton.md Section 5): 0 and 0, none
    joint_d: float = 0.0
    joint_heads: list = field(default_factory=list)  # (parent, child, the child's rest head) per joint
    bones: list = field(default_factory=list, init=False)
    joints: list = field(default_factory=list, init=False)  # (parent, child, r on parent, r on child)

    def __post_init__(self):
        self.rest = np.asarray(self.rest, dtype=float)
        self.tets = np.asarray(self.tets, dtype=np.int64)
        self.n = len(self.rest)
        lam = self.young * self.poisson / ((1 + self.poisson) * (1 - 2 * self.poisson))
        mu = self.young / (2 * (1 + self.poisson))
        x = self.rest[self.tets]                                    # (m, 4, 3)
        dm = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)
        self.volume = np.linalg.det(dm) / 6.0
        assert (self.volume > 0).all(), "the reference needs positively oriented tets"
        self.bm = np.linalg.inv(dm)
        g = np.empty((len(self.tets), 4, 3))
        g[:, 1:] = self.bm                                          # rows of Bm: nodes 1..3
        g[:, 0] = -self.bm.sum(axis=1)
        self.grad = g
        # K_e: K_ab = V (lambda g_a g_b^T + mu g_b g_a^T + mu (g_a . g_b) I)
        ke = (lam * np.einsum("eai,ebj->eaibj", g, g) + mu * np.einsum("ebi,eaj->eaibj", g, g)
              + mu * np.einsum("eak,ebk,ij->eaibj", g, g, np.eye(3)))
        self.ke = self.volume[:, None, None] * ke.reshape(-1, 12, 12)
        self.masses = np.zeros(self.n)
        np.add.at(self.masses, self.tets.ravel(), np.repeat(0.25 * self.density * self.volume, 4))  # Eq. 2
        self.bones = [make_bone(self.rest, self.masses, nodes) for nodes in self.bone_nodes]
        self.joints = [(p, c, np.asarray(head, float) - self.bones[p].com, np.asarray(head, float) - self.bones[c].com)
                       for p, c, head in self.joint_heads]


@dataclass
class State:
    x: np.ndarray   # (n, 3) flesh
    v: np.ndarray
    bx: np.ndarray  # (B, 3) bones' centres of mass
    bq: np.ndarray  # (B, 4)
    bv: np.ndarray  # (B, 3)
    bw: np.ndarray  # (B, 3) world-frame angular velocities


def rest_state(rig: Rig) -> State:
    b = len(rig.bones)
    return State(rig.rest.copy(), np.zeros_like(rig.rest), np.array([bone.com for bone in rig.bones]),
                 np.tile([0.0, 0.0, 0.0, 1.0], (b, 1)), np.zeros((b, 3)), np.zeros((b, 3)))


@dataclass
class Drive:
    """Each bone's target at the end of the step and its virtual coupling (docs/skeleton.md,
    Section 4): mode FREE, COUPLED or PRESCRIBED; gains (k, d, k_r, d_r)."""

    mode: np.ndarray        # (B,)
    position: np.ndarray    # (B, 3)
    quaternion: np.ndarray  # (B, 4)
    velocity: np.ndarray    # (B, 3)
    angular_velocity: np.ndarray
    gains: np.ndarray       # (B, 4)


def free_drive(b: int) -> Drive:
    return Drive(np.zeros(b, int), np.zeros((b, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (b, 1)), np.zeros((b, 3)),
                 np.zeros((b, 3)), np.zeros((b, 4)))


# --------------------------------------------------------------------------------------------
# Forces and their Jacobians
# --------------------------------------------------------------------------------------------


def polar_rotations(rig: Rig, x: np.ndarray) -> np.ndarray:
    """R of the polar decomposition of F = Ds Bm per element, by SVD (proper rotations)."""
    p = x[rig.tets]
    ds = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)
    u, _, vt = np.linalg.svd(ds @ rig.bm)
    sign = np.sign(np.linalg.det(u @ vt))
    u[:, :, 2] *= sign[:, None]
    return u @ vt


def elastic(rig: Rig, x: np.ndarray):
    """Elastic forces (n, 3) and the warped element stiffnesses R K_e R^T (m, 12, 12)."""
    r = polar_rotations(rig, x)
    big = np.zeros((len(rig.tets), 12, 12))
    for a in range(4):
        big[:, 3 * a:3 * a + 3, 3 * a:3 * a + 3] = r
    rest_rel = (rig.rest[rig.tets] - rig.rest[rig.tets][:, :1]).reshape(-1, 12)
    cur_rel = (x[rig.tets] - x[rig.tets][:, :1]).reshape(-1, 12)
    u = np.einsum("eji,ej->ei", big, cur_rel) - rest_rel        # R^T (x - x0) - (X - X0)
    fe = -np.einsum("eij,ejk,ek->ei", big, rig.ke, u)            # -R K_e u
    f = np.zeros_like(x)
    np.add.at(f, rig.tets.ravel(), fe.reshape(-1, 3))
    return f, big @ rig.ke @ big.transpose(0, 2, 1)


@dataclass
class Springs:
    """Eqs. 4-5 for every spring of one bone, and their Jacobians (Eq. 11), per spring."""

    f_node: np.ndarray     # (s, 3) F_A
    wrench: np.ndarray     # (6,) sum of (F_B, T_B) about the bone's centre
    dfa_dxa: np.ndarray    # scalars times I: -k, -d
    dfa_dxh: np.ndarray    # (s, 3, 6)
    dfa_dvh: np.ndarray    # (s, 3, 6)
    dfh_dxa: np.ndarray    # (s, 6, 3)
    dfh_dva: np.ndarray    # (s, 6, 3)
    dfh_dxh: np.ndarray    # (6, 6) summed
    dfh_dvh: np.ndarray    # (6, 6)


def springs(k: float, d: float, xa, va, r_body, bx, bq, bv, bw) -> Springs:
    rr = r_body @ quat_matrix(bq).T                     # R r_B
    f_a = -k * (xa - bx - rr) - d * (va - bv - np.cross(bw, rr))
    f_b = -f_a
    rx, wx, fx = skew(rr), skew(bw), skew(f_b)
    eye = np.broadcast_to(np.eye(3), rx.shape)
    # d(R r_B)/dtheta = -[R r_B]x; d(omega x R r_B)/dtheta = -[omega]x [R r_B]x
    dfa_dtheta = -k * rx - d * wx @ rx
    dfa_dxh = np.concatenate([k * eye, dfa_dtheta], axis=2)
    dfa_dvh = np.concatenate([d * eye, -d * rx], axis=2)
    dfb_dtheta = -dfa_dtheta
    dfh_dxa = np.concatenate([k * eye, k * rx], axis=1)
    dfh_dva = np.concatenate([d * eye, d * rx], axis=1)
    # T_B = rr x F_B = -[F_B]x rr: dT = [rr]x dF_B - [F_B]x d(rr)
    dfh_dxh = np.block([[(-k * eye).sum(0), dfb_dtheta.sum(0)],
                        [(-k * rx).sum(0), (fx @ rx + rx @ dfb_dtheta).sum(0)]])
    dfh_dvh = np.block([[(-d * eye).sum(0), (d * rx).sum(0)], [(-d * rx).sum(0), (d * rx @ rx).sum(0)]])
    wrench = np.concatenate([f_b.sum(0), np.cross(rr, f_b).sum(0)])
    return Springs(f_a, wrench, np.array([-k, -d]), dfa_dxh, dfa_dvh, dfh_dxa, dfh_dva, dfh_dxh, dfh_dvh)


# --------------------------------------------------------------------------------------------
# Eq. 7 for B bones, monolithic
# --------------------------------------------------------------------------------------------


def _bone_block(rig: Rig, state: State, drive: Drive, b: int, s: Springs, s_rest: Springs):
    """A_h,b and b_h,b (docs/skeleton.md, Sections 3-4)."""
    dt = rig.dt
    bone = rig.bones[b]
    r = quat_matrix(state.bq[b])
    inertia = r @ bone.inertia @ r.T
    ah = np.zeros((6, 6))
    ah[:3, :3] = bone.mass * np.eye(3)
    ah[3:, 3:] = inertia
    ah += -dt * s.dfh_dvh - dt * dt * s.dfh_dxh
    w = state.bw[b]
    bh = np.concatenate([bone.mass * state.bv[b], inertia @ w - dt * np.cross(w, inertia @ w)])
    bh += dt * s_rest.wrench  # the springs' elastic wrench: damping is linear in v, so it leaves b
    mode = drive.mode[b]
    if mode == COUPLED:
        kc, dc, kr, dr = drive.gains[b]
        ah[:3, :3] += (dt * dc + dt * dt * kc) * np.eye(3)
        ah[3:, 3:] += (dt * dr + dt * dt * kr) * np.eye(3)
        turn = quat_log(quat_multiply(drive.quaternion[b], conjugate(state.bq[b])))
        bh[:3] += dt * (kc * (drive.position[b] - state.bx[b]) + dc * drive.velocity[b])
        bh[3:] += dt * (kr * turn + dr * drive.angular_velocity[b])
    return ah, bh


def assemble(rig: Rig, state: State, drive: Drive, still_jacobians: bool = False):
    """The matrix (sparse, (6B + 3n)^2) and right-hand side of Eq. 7, unknowns (v_h, v_t) with
    v_h = (v_1, omega_1, ..., v_B, omega_B).

    still_jacobians: the springs' Jacobians taken at zero velocities (every x, omega at the
    state's positions, every v and omega zero) instead of the state's. The two differ only in the
    velocity-dependent parts of dF/dx (the damping's turn d [omega]x [R r]x and the [F_B]x term's
    damping force). The native step linearizes about the velocities of its rigid frame (the whole
    hand's turn, docs/maths.md "Rotation-consistent integration"), which are zero when the hand
    does not turn as a whole: then, with this flag, the two steps are the same step."""
    dt, n, nb = rig.dt, rig.n, len(rig.bones)
    off = 6 * nb
    f_el, kel = elastic(rig, state.x)
    rows, cols, vals = [], [], []

    def add(r0, c0, block):
        rr, cc = np.meshgrid(np.arange(block.shape[0]), np.arange(block.shape[1]), indexing="ij")
        rows.append((r0 + rr).ravel())
        cols.append((c0 + cc).ravel())
        vals.append(block.ravel())

    # A_t: M (1 + dt alpha) + (dt beta + dt^2) R K R^T, per element block
    for a in range(4):
        for c in range(4):
            blocks = (dt * rig.beta + dt * dt) * kel[:, 3 * a:3 * a + 3, 3 * c:3 * c + 3]
            ii, jj = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
            rows.append((off + 3 * rig.tets[:, a, None, None] + ii).ravel())
            cols.append((off + 3 * rig.tets[:, c, None, None] + jj).ravel())
            vals.append(blocks.ravel())
    diag = off + np.arange(3 * n)
    rows.append(diag), cols.append(diag), vals.append(np.repeat(rig.masses * (1 + dt * rig.alpha), 3))
    bt = (rig.masses[:, None] * state.v + dt * (f_el + rig.masses[:, None] * rig.gravity)).ravel()
    bh = np.zeros(off)
    for b, bone in enumerate(rig.bones):
        nodes = bone.nodes
        args = (bone.r_body, state.bx[b], state.bq[b], state.bv[b], state.bw[b])
        if still_jacobians:
            s = springs(rig.k, rig.d, state.x[nodes], np.zeros((len(nodes), 3)), bone.r_body, state.bx[b],
                        state.bq[b], np.zeros(3), np.zeros(3))
        else:
            s = springs(rig.k, rig.d, state.x[nodes], state.v[nodes], *args)
        s_rest = springs(rig.k, rig.d, state.x[nodes], np.zeros((len(nodes), 3)), bone.r_body, state.bx[b],
                         state.bq[b], np.zeros(3), np.zeros(3))
        ah, bh[6 * b:6 * b + 6] = _bone_block(rig, state, drive, b, s, s_rest)
        aht = -dt * s.dfh_dva - dt * dt * s.dfh_dxa          # Eq. 8, one 6x3 block per node (Eq. 9)
        ath = -dt * s.dfa_dvh - dt * dt * s.dfa_dxh          # Eq. 10
        if drive.mode[b] == PRESCRIBED:                       # v_b = target: identity rows
            ah, aht = np.eye(6), np.zeros_like(aht)
            bh[6 * b:6 * b + 3] = (drive.position[b] - state.bx[b]) / dt
            bh[6 * b + 3:6 * b + 6] = quat_log(quat_multiply(drive.quaternion[b], conjugate(state.bq[b]))) / dt
        add(6 * b, 6 * b, ah)
        for j, i in enumerate(nodes):
            add(6 * b, off + 3 * i, aht[j])
            add(off + 3 * i, 6 * b, ath[j])
            add(off + 3 * i, off + 3 * i, (dt * rig.d + dt * dt * rig.k) * np.eye(3))
        bt.reshape(n, 3)[nodes] += dt * s_rest.f_node
    if rig.joint_k or rig.joint_d:
        _joint_blocks(rig, state, drive, still_jacobians, add, bh)
    a = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(off + 3 * n,) * 2)
    return a, np.concatenate([bh, bt])


def point_jacobian(q, r) -> np.ndarray:
    """J (3 x 6) of the material point R r of a bone: its velocity is J (v, omega) = v + omega x R r."""
    return np.hstack([np.eye(3), -skew(quat_matrix(q) @ r)])


def joint(k: float, d: float, parent: tuple, child: tuple):
    """A ball joint between two bones, each end (x, q, v, omega, r): its wrenches on (parent,
    child) about their centres (2, 6), and the blocks dW_s/d(x_t, theta_t), dW_s/d(v_t, omega_t)
    (2, 2, 6, 6). With e = p_child - p_parent, de = sum_t sign_t J_t d(x_t, theta_t) and
    d(de/dt) = sum_t sign_t (J_t d(v_t, omega_t) + [0 | -[omega_t]x [R_t r_t]x] d(x_t, theta_t))."""
    ends = (parent, child)
    sign = (-1.0, 1.0)
    jac = [point_jacobian(q, r) for _, q, _, _, r in ends]
    point = [x + quat_matrix(q) @ r for x, q, _, _, r in ends]
    velocity = [j @ np.concatenate([v, w]) for j, (_, _, v, w, _) in zip(jac, ends)]
    force = -k * (point[1] - point[0]) - d * (velocity[1] - velocity[0])   # on the child
    wrench = np.array([sign[s] * jac[s].T @ force for s in range(2)])
    dx, dv = np.zeros((2, 2, 6, 6)), np.zeros((2, 2, 6, 6))
    for t in range(2):
        _, q, _, w, r = ends[t]
        turn = np.hstack([np.zeros((3, 3)), -skew(w) @ skew(quat_matrix(q) @ r)])
        df_dx = -sign[t] * (k * jac[t] + d * turn)
        df_dv = -sign[t] * d * jac[t]
        for s in range(2):
            dx[s, t] = sign[s] * jac[s].T @ df_dx
            dv[s, t] = sign[s] * jac[s].T @ df_dv
    for s in range(2):  # J_s^T F's torque [R r]x F turns with the bone: d/dtheta = [F]x [R r]x
        _, q, _, _, r = ends[s]
        dx[s, s, 3:, 3:] += skew(sign[s] * force) @ skew(quat_matrix(q) @ r)
    return wrench, dx, dv


def _joint_blocks(rig: Rig, state: State, drive: Drive, still_jacobians: bool, add, bh: np.ndarray) -> None:
    """Every joint's blocks of Eq. 7 and its elastic wrench in b_h, in the rows of the bones that
    are not prescribed (a prescribed bone's rows are v_b = target)."""
    dt = rig.dt
    for p, c, rp, rc in rig.joints:
        def end(b, r, moving):
            v, w = (state.bv[b], state.bw[b]) if moving else (np.zeros(3), np.zeros(3))
            return state.bx[b], state.bq[b], v, w, r
        _, dx, dv = joint(rig.joint_k, rig.joint_d, end(p, rp, not still_jacobians), end(c, rc, not still_jacobians))
        elastic_wrench, _, _ = joint(rig.joint_k, rig.joint_d, end(p, rp, False), end(c, rc, False))
        bones = (p, c)
        for s in range(2):
            if drive.mode[bones[s]] == PRESCRIBED:
                continue
            bh[6 * bones[s]:6 * bones[s] + 6] += dt * elastic_wrench[s]
            for t in range(2):
                add(6 * bones[s], 6 * bones[t], -dt * dv[s, t] - dt * dt * dx[s, t])


def solve_monolithic(a: sp.spmatrix, rhs: np.ndarray, refinements: int = 2) -> np.ndarray:
    """Sparse LU of the whole Eq. 7, with iterative refinement (residuals in float64)."""
    lu = spla.splu(a.tocsc())
    s = lu.solve(rhs)
    for _ in range(refinements):
        s += lu.solve(rhs - a @ s)
    return s


def solve_schur(a: sp.spmatrix, rhs: np.ndarray, nb: int) -> np.ndarray:
    """docs/skeleton.md's sparse path in dense form: A_t = L L^T, P = L^-1 A_th, Q = L^-1 A_ht^T,
    y = L^-1 b_t (forward passes only), S = A_h - Q^T P, S v_h = b_h - Q^T y,
    v_t = L^-T (y - P v_h) (one backward pass). For checking the algebra on small rigs."""
    a = a.tocsr()
    off = 6 * nb
    ah = a[:off, :off].toarray()
    aht = a[:off, off:].toarray()
    ath = a[off:, :off].toarray()
    at = a[off:, off:].toarray()
    low = scipy.linalg.cholesky(at, lower=True)
    forward = lambda m: scipy.linalg.solve_triangular(low, m, lower=True)  # noqa: E731
    p, q, y = forward(ath), forward(aht.T), forward(rhs[off:])
    vh = np.linalg.solve(ah - q.T @ p, rhs[:off] - q.T @ y)
    vt = scipy.linalg.solve_triangular(low.T, y - p @ vh, lower=False)
    return np.concatenate([vh, vt])


def integrate(rig: Rig, state: State, s: np.ndarray) -> State:
    nb = len(rig.bones)
    vh = s[:6 * nb].reshape(nb, 6)
    v = s[6 * nb:].reshape(-1, 3)
    dt = rig.dt
    bq = np.array([quat_multiply(quat_exp(dt * w), q) for w, q in zip(vh[:, 3:], state.bq)])
    bq /= np.linalg.norm(bq, axis=1, keepdims=True)
    return replace(state, x=state.x + dt * v, v=v, bx=state.bx + dt * vh[:, :3], bq=bq, bv=vh[:, :3].copy(),
                   bw=vh[:, 3:].copy())


def step(rig: Rig, state: State, drive: Drive, solver: str = "monolithic", still_jacobians: bool = False) -> State:
    """One implicit step of Eq. 7 from state under drive."""
    a, rhs = assemble(rig, state, drive, still_jacobians)
    s = solve_monolithic(a, rhs) if solver == "monolithic" else solve_schur(a, rhs, len(rig.bones))
    return integrate(rig, state, s)
