// The skeleton of many handles (docs/skeleton.md): each bone's spring blocks of Eq. 7 (Eqs. 8,
// 10, 11) against central finite differences of its springs' forces (Eqs. 4-5), no bone's
// wrench depending on another bone's state, and the Schur solve for B bones against the
// monolithic reference, with and without the ball joints of Section 5 (their wrenches'
// Jacobians against central differences as well).
#include <functional>
#include <limits>
#include <random>

#include "box_mesh.h"
#include "check.h"
#include "coupling/joint_limits.h"
#include "coupling/joints.h"
#include "rigid/quaternion.h"
#include "sim/skeleton_step.h"

using namespace hh;

namespace {
constexpr double kInf = std::numeric_limits<double>::infinity();
// A 6 x 2 x 2 cm bar of 1 cm cubes with three bones on its axis (a chain), flesh between them.
Model three_bone_bar(double joint_stiffness = 0, double joint_damping = 0) {
    const BoxMesh box = make_box(6, 2, 2, 0.01);
    hh_params p;
    hh_default_params(&p);
    p.rayleigh_alpha = 0.5;
    p.joint_stiffness = joint_stiffness;
    p.joint_damping = joint_damping;
    std::vector<BoneDesc> bones(3);
    const double x[3][2] = {{0.0, 0.01}, {0.025, 0.035}, {0.05, 0.06}};
    for (int b = 0; b < 3; ++b) {
        bones[b].name = "b" + std::to_string(b);
        bones[b].parent = b - 1;
        bones[b].head = Vec3(x[b][0], 0.01, 0.01);
        bones[b].tail = Vec3(x[b][1], 0.01, 0.01);
        bones[b].radius = 0.0145;
    }
    return build_skeleton_model(box.nodes.data(), box.n_nodes(), box.tets.data(), box.n_tets(), p, bones);
}

// A deformed, moving state with every bone turned, moving and spinning, each coupled to a
// target (bone 1 prescribed)
void moving_state(const Model& m, Data& d, unsigned seed) {
    std::mt19937 rng(seed);
    std::normal_distribution<double> g(0, 1);
    auto rv = [&](double s) { return Vec3(s * g(rng), s * g(rng), s * g(rng)); };
    for (int i = 0; i < m.mesh.n_nodes; ++i) {
        d.x.segment<3>(3 * i) += rv(5e-4);
        d.v.segment<3>(3 * i) = rv(0.05);
    }
    for (int b = 0; b < m.n_bones(); ++b) {
        HandleState& h = bone_state(d, b);
        h.q = quat_from_rotation_vector(rv(0.1));
        h.v_com = rv(0.05);
        h.omega = rv(0.5);
        DeviceFrame& t = bone_target(d, b);
        t.enabled = true;
        t.prescribed = b == 1;
        t.position = h.x_com + rv(0.003);
        t.quaternion = quat_from_rotation_vector(rv(0.1));
        t.velocity = rv(0.1);
        t.angular_velocity = rv(1.0);
    }
}

using Vec9 = Eigen::Matrix<double, 9, 1>;
// (F_A, F_B, T_B) of one spring
Vec9 spring(const Model& m, const Vec3& xa, const Vec3& va, const Vec3& rb, const HandleState& h) {
    const SpringForce f = spring_force(m.params.spring_stiffness, m.params.spring_damping, xa, va, rb, h);
    Vec9 out;
    out << f.on_node, f.on_handle, f.torque;
    return out;
}

// Central differences of fn with respect to the 3 components moved by move(c, step)
Eigen::Matrix<double, 9, 3> numeric(const std::function<Vec9(int, double)>& fn, double h) {
    Eigen::Matrix<double, 9, 3> j;
    for (int c = 0; c < 3; ++c) j.col(c) = (fn(c, h) - fn(c, -h)) / (2 * h);
    return j;
}

double relative(const MatX& a, const MatX& b) { return (a - b).norm() / std::max(b.norm(), 1e-300); }
}  // namespace

TEST(each_bones_spring_blocks_match_finite_differences) {
    const Model m = three_bone_bar();
    CHECK(m.n_bones() == 3);
    Data d(m);
    moving_state(m, d, 3);
    formulate_skeleton(m, d);
    const double dt = m.params.dt;
    const StepFrame& f = d.frame;
    double worst = 0;
    for (int b = 0; b < m.n_bones(); ++b) {
        const HandleModel& bone = m.skeleton.bones[b];
        const HandleState& c = d.carried[b];  // the linearization point: the state the frame carries bone b to
        const CouplingBlocks& cb = d.bone_coupling[b];
        Mat6 ah = Mat6::Zero();
        for (size_t j = 0; j < bone.nodes.size(); ++j) {
            const Vec3 xa = f.x.segment<3>(3 * bone.nodes[j]), va = f.v.segment<3>(3 * bone.nodes[j]);
            const Vec3& rb = bone.r_body[j];
            // derivatives in the bone's (x, theta) and (v, omega), theta a world-frame turn, and in the node's x, v
            auto by_x = [&](int k, double s) { HandleState h = c; h.x_com[k] += s; return spring(m, xa, va, rb, h); };
            auto by_theta = [&](int k, double s) {
                HandleState h = c;
                Vec3 e = Vec3::Zero();
                e[k] = s;
                h.q = quat_multiply(quat_from_rotation_vector(e), c.q);
                return spring(m, xa, va, rb, h);
            };
            auto by_v = [&](int k, double s) { HandleState h = c; h.v_com[k] += s; return spring(m, xa, va, rb, h); };
            auto by_omega = [&](int k, double s) { HandleState h = c; h.omega[k] += s; return spring(m, xa, va, rb, h); };
            auto by_xa = [&](int k, double s) { Vec3 y = xa; y[k] += s; return spring(m, y, va, rb, c); };
            auto by_va = [&](int k, double s) { Vec3 y = va; y[k] += s; return spring(m, xa, y, rb, c); };
            Eigen::Matrix<double, 9, 6> dx, dv;  // with respect to (x_b, theta_b), (v_b, omega_b)
            dx << numeric(by_x, 1e-7), numeric(by_theta, 1e-7);
            dv << numeric(by_v, 1e-6), numeric(by_omega, 1e-6);
            const Eigen::Matrix<double, 9, 3> dxa = numeric(by_xa, 1e-7), dva = numeric(by_va, 1e-6);
            // Eq. 10: A_th = -dt dF_A/dv_h - dt^2 dF_A/dx_h; Eq. 8: A_ht = -dt dW/dv_A - dt^2 dW/dx_A
            const Mat36 ath = -dt * dv.topRows<3>() - dt * dt * dx.topRows<3>();
            const Mat63 aht = -dt * dva.bottomRows<6>() - dt * dt * dxa.bottomRows<6>();
            const Mat3 at = -dt * dva.topRows<3>() - dt * dt * dxa.topRows<3>();
            worst = std::max({worst, relative(cb.ath[j], ath), relative(cb.aht[j], aht), relative(cb.at_diagonal[j], at)});
            ah += -dt * dv.bottomRows<6>() - dt * dt * dx.bottomRows<6>();
        }
        worst = std::max(worst, relative(cb.ah, ah));
    }
    std::printf("spring blocks per bone against central differences: %.2g relative\n", worst);
    CHECK_LT(worst, 1e-8);
}

TEST(a_bones_wrench_depends_on_its_own_state_only) {
    // hh_bone_wrenches' W_b against finite differences in every bone's state: bone b's through
    // Eq. 11 summed over its nodes, every other bone's exactly zero
    const Model m = three_bone_bar();
    Data d(m);
    moving_state(m, d, 5);
    const std::vector<Vec6> w0 = bone_wrenches(m, d);
    double worst = 0;
    for (int b = 0; b < m.n_bones(); ++b) {
        Mat6 dx = Mat6::Zero(), dv = Mat6::Zero();  // analytic dW_b/d(x, theta), d(v, omega)
        const HandleModel& bone = m.skeleton.bones[b];
        for (size_t j = 0; j < bone.nodes.size(); ++j) {
            const SpringJacobian jac = spring_jacobian(m.params.spring_stiffness, m.params.spring_damping,
                                                       d.x.segment<3>(3 * bone.nodes[j]), d.v.segment<3>(3 * bone.nodes[j]),
                                                       bone.r_body[j], bone_state(d, b));
            dx += jac.dfh_dxh;
            dv += jac.dfh_dvh;
        }
        for (int k = 0; k < 12; ++k) {
            auto moved = [&](double s) {
                const HandleState kept = bone_state(d, b);
                HandleState& h = bone_state(d, b);
                Vec3 u = Vec3::Zero();
                u[k % 3] = s;
                if (k < 3) h.x_com += u;
                else if (k < 6) h.q = quat_multiply(quat_from_rotation_vector(u), h.q);
                else if (k < 9) h.v_com += u;
                else h.omega += u;
                const std::vector<Vec6> w = bone_wrenches(m, d);
                h = kept;
                return w;
            };
            const double step = k < 6 ? 1e-7 : 1e-6;
            const std::vector<Vec6> wp = moved(step), wm = moved(-step);
            for (int c = 0; c < m.n_bones(); ++c) {
                const Vec6 num = (wp[c] - wm[c]) / (2 * step);
                if (c != b) {
                    CHECK(wp[c] == w0[c] && wm[c] == w0[c]);
                    continue;
                }
                const Vec6 analytic = k < 6 ? Vec6(dx.col(k)) : Vec6(dv.col(k - 6));
                worst = std::max(worst, (num - analytic).norm() / std::max(dx.norm() * 1e-3, analytic.norm()));
            }
        }
    }
    std::printf("bone wrench derivatives against central differences: %.2g relative\n", worst);
    CHECK_LT(worst, 1e-7);
}

TEST(schur_for_b_bones_equals_the_monolithic_solve) {
    const Model m = three_bone_bar();
    Data d(m);
    moving_state(m, d, 9);
    formulate_skeleton(m, d);
    d.skeleton.solve();
    const VecX mono = solve_monolithic(d.skeleton, d.skeleton.r);
    std::printf("three bones, Schur against monolithic: %.2g relative\n",
                (d.skeleton.s - mono).cwiseAbs().maxCoeff() / mono.cwiseAbs().maxCoeff());
    CHECK_LT((d.skeleton.s - mono).cwiseAbs().maxCoeff() / mono.cwiseAbs().maxCoeff(), 1e-11);
    // the prescribed bone's rows: v_b is its target velocity relative to the frame
    CHECK_LT((d.skeleton.s.segment<6>(6) - d.skeleton.r.segment<6>(6)).norm(), 1e-14 * d.skeleton.r.segment<6>(6).norm());
}

// Every bone prescribed (with joints, which a prescribed bone's rows leave out): the step is one
// flesh solve, v_t = A_t^-1 (b_t - A_th v_h), and equals the monolithic solve of Eq. 7; the
// columns A_t^-1 A_th asked afterwards and the contact response (bones' rows included) equal
// a dense solve of A_t and the monolithic solve.
TEST(all_prescribed_bones_take_one_right_hand_side_and_equal_the_monolithic_solve) {
    const Model m = three_bone_bar(200.0, 0.5);
    Data d(m);
    moving_state(m, d, 11);
    for (int b = 0; b < m.n_bones(); ++b) bone_target(d, b).prescribed = true;
    formulate_skeleton(m, d);
    SkeletonSystem& sys = d.skeleton;
    sys.solve();
    CHECK(sys.solved_prescribed());
    CHECK(sys.columns == 1);
    const VecX mono = solve_monolithic(sys, sys.r);
    const double step_error = (sys.s - mono).cwiseAbs().maxCoeff() / mono.cwiseAbs().maxCoeff();
    std::printf("three prescribed bones, one flesh solve against monolithic: %.2g relative\n", step_error);
    CHECK_LT(step_error, 1e-11);
    CHECK_LT((sys.s.head(18) - sys.r.head(18)).norm(), 1e-14 * sys.r.head(18).norm());

    const Eigen::Index n3 = sys.tool.A.rows();
    MatX ath = MatX::Zero(n3, 18);
    for (int b = 0; b < 3; ++b)
        for (size_t j = 0; j < sys.nodes[b]->size(); ++j) ath.block<3, 6>(3 * (*sys.nodes[b])[j], 6 * b) = sys.Ath[b][j];
    const MatX dense = MatX(sys.tool.A).ldlt().solve(ath);
    CHECK_LT(relative(sys.flesh_response(), dense), 1e-11);

    std::mt19937 rng(5);
    std::normal_distribution<double> g(0, 1);
    VecX rhs(sys.r.size());
    for (Eigen::Index i = 0; i < rhs.size(); ++i) rhs[i] = g(rng);
    CHECK_LT(relative(sys.apply_inverse(rhs), solve_monolithic(sys, rhs)), 1e-11);
    // one bone coupled: the Schur path with all 1 + 6B columns
    bone_target(d, 2).prescribed = false;
    formulate_skeleton(m, d);
    sys.solve();
    CHECK(!sys.solved_prescribed());
    CHECK(sys.columns == 19);
}

TEST(joint_jacobians_match_finite_differences) {
    // A ball joint between two turned, moving, spinning bones whose joint points are apart:
    // dW_s/d(x_t, theta_t) and dW_s/d(v_t, omega_t) for both ends s, t (Eq. 11's with the
    // rotation terms on both sides) against central differences of the joint's wrenches.
    std::mt19937 rng(21);
    std::normal_distribution<double> g(0, 1);
    auto rv = [&](double s) { return Vec3(s * g(rng), s * g(rng), s * g(rng)); };
    const double k = 3e3, d = 7.0;
    HandleState state[2];
    for (HandleState& h : state) {
        h.x_com = rv(0.02);
        h.q = quat_from_rotation_vector(rv(0.5));
        h.v_com = rv(0.1);
        h.omega = rv(2.0);
    }
    const Vec3 r_parent = rv(0.02), r_child = rv(0.01);
    auto wrenches = [&](const HandleState* h) {
        const JointForce f = joint_force(k, d, h[kParent], r_parent, h[kChild], r_child);
        Eigen::Matrix<double, 12, 1> w;
        w << f.wrench[kParent], f.wrench[kChild];
        return w;
    };
    const JointJacobian j = joint_jacobian(k, d, state[kParent], r_parent, state[kChild], r_child);
    double worst = 0;
    for (int t = 0; t < 2; ++t)
        for (int c = 0; c < 12; ++c) {
            const double step = c < 6 ? 1e-7 : 1e-6;
            auto moved = [&](double sgn) {
                HandleState h[2] = {state[0], state[1]};
                Vec3 u = Vec3::Zero();
                u[c % 3] = sgn * step;
                if (c < 3) h[t].x_com += u;
                else if (c < 6) h[t].q = quat_multiply(quat_from_rotation_vector(u), h[t].q);  // a world-frame turn
                else if (c < 9) h[t].v_com += u;
                else h[t].omega += u;
                return wrenches(h);
            };
            const Eigen::Matrix<double, 12, 1> num = (moved(1) - moved(-1)) / (2 * step);
            for (int s = 0; s < 2; ++s) {
                const Vec6 analytic = c < 6 ? Vec6(j.dw_dx[s][t].col(c)) : Vec6(j.dw_dv[s][t].col(c - 6));
                const double scale = c < 6 ? j.dw_dx[s][t].norm() : j.dw_dv[s][t].norm();
                worst = std::max(worst, (num.segment<6>(6 * s) - analytic).norm() / scale);
            }
        }
    // the wrenches are equal and opposite forces at the joint points, and F = -k e - d de/dt
    const JointForce f = joint_force(k, d, state[kParent], r_parent, state[kChild], r_child);
    CHECK((f.wrench[kParent].head<3>() + f.wrench[kChild].head<3>()).norm() == 0);
    const Vec3 lp = quat_to_matrix(state[kParent].q) * r_parent, lc = quat_to_matrix(state[kChild].q) * r_child;
    const Vec3 gap = state[kChild].x_com + lc - state[kParent].x_com - lp;
    const Vec3 rate = state[kChild].v_com + state[kChild].omega.cross(lc) - state[kParent].v_com -
                      state[kParent].omega.cross(lp);
    CHECK_LT((f.on_child - (-k * gap - d * rate)).norm(), 1e-12 * f.on_child.norm());
    CHECK_LT(std::abs(f.energy - 0.5 * k * gap.squaredNorm()), 1e-15 * f.energy);
    std::printf("joint wrench Jacobians against central differences: %.2g relative\n", worst);
    CHECK_LT(worst, 1e-7);
}

TEST(joint_limit_torque_is_its_energy_gradient_and_its_jacobian_the_gauss_newton_one) {
    // A limited bone turned beyond its ranges on two axes, relative to a turned parent: the
    // torque on each end is minus the energy's gradient in that end's world-frame turn (central
    // differences of E, to 1e-7), equal and opposite, with no force; the damping opposes the
    // relative spin on the axes beyond range only; and at the edge of the range (overshoot ->
    // 0) the Gauss-Newton stiffness k M Pi M^T is the torque's full Jacobian (the left-out terms
    // scale with the overshoot).
    std::mt19937 rng(5);
    std::normal_distribution<double> g(0, 1);
    auto rv = [&](double s) { return Vec3(s * g(rng), s * g(rng), s * g(rng)); };
    const double k = 2.5, d = 0.03;
    const Mat3 axes = quat_to_matrix(quat_from_rotation_vector(Vec3(0.3, -0.7, 0.2)));
    const Vec3 lo(-0.1, -0.2, -kInf), hi(0.05, 0.3, kInf);
    HandleState parent, child;
    parent.q = quat_from_rotation_vector(rv(0.6));
    parent.omega = rv(1.0);
    child.omega = rv(1.0);
    // the child turned from the parent by psi = (0.4, -0.5, 0.2) in the bone's axes: x over its
    // maximum, y under its minimum, z free
    const Vec3 psi(0.4, -0.5, 0.2);
    child.q = quat_multiply(parent.q, quat_from_rotation_vector(axes * psi));
    const JointLimit limit = joint_limit(k, d, parent, child, axes, lo, hi);
    CHECK(limit.active);
    CHECK_LT((limit.psi - psi).norm(), 1e-12);
    const Vec3 over(0.4 - 0.05, -0.5 + 0.2, 0.0);
    CHECK_LT(std::abs(limit.energy - 0.5 * k * over.squaredNorm()), 1e-14);
    auto energy = [&](const HandleState& p, const HandleState& c) { return joint_limit(k, 0, p, c, axes, lo, hi).energy; };
    const double h = 1e-6;
    Vec3 grad_child, grad_parent;
    for (int i = 0; i < 3; ++i) {
        auto turned = [&](HandleState s, double sgn) {
            Vec3 u = Vec3::Zero();
            u[i] = sgn * h;
            s.q = quat_multiply(quat_from_rotation_vector(u), s.q);
            return s;
        };
        grad_child[i] = (energy(parent, turned(child, 1)) - energy(parent, turned(child, -1))) / (2 * h);
        grad_parent[i] = (energy(turned(parent, 1), child) - energy(turned(parent, -1), child)) / (2 * h);
    }
    const JointLimit still = joint_limit(k, 0, parent, child, axes, lo, hi);  // (no damping)
    CHECK_LT((still.on_child + grad_child).norm(), 1e-7 * grad_child.norm());
    CHECK_LT((grad_parent + grad_child).norm(), 1e-7 * grad_child.norm());  // tau_p = -tau_c
    // the damping: -D (omega_c - omega_p), D symmetric, zero along the free axis's direction
    const Vec3 damping_torque = limit.on_child - still.on_child;
    CHECK_LT((damping_torque + limit.damping * (child.omega - parent.omega)).norm(), 1e-14);
    CHECK_LT((limit.damping - limit.damping.transpose()).norm(), 1e-15);
    const JointBlocks jb = joint_limit_blocks(limit, 0.01);
    CHECK(jb.bh[kChild].head<3>().norm() == 0 && jb.bh[kParent].head<3>().norm() == 0);  // no force
    CHECK_LT((jb.bh[kChild].tail<3>() - 0.01 * limit.on_child).norm(), 1e-16);
    // just beyond the edge of the range (1e-5 rad on both limited axes) the torque's Jacobian in
    // the child's turn is -k M Pi M^T: central differences with steps within that overshoot
    HandleState edge = child;
    edge.q = quat_multiply(parent.q, quat_from_rotation_vector(axes * Vec3(0.05 + 1e-5, -0.2 - 1e-5, 0.2)));
    const JointLimit at_edge = joint_limit(k, 0, parent, edge, axes, lo, hi);
    double worst = 0;
    for (int i = 0; i < 3; ++i) {
        auto torque = [&](double sgn) {
            Vec3 u = Vec3::Zero();
            u[i] = sgn * 1e-7;
            HandleState c = edge;
            c.q = quat_multiply(quat_from_rotation_vector(u), c.q);
            return joint_limit(k, 0, parent, c, axes, lo, hi).on_child;
        };
        const Vec3 num = (torque(1) - torque(-1)) / 2e-7;
        worst = std::max(worst, (num + at_edge.stiffness.col(i)).norm() / at_edge.stiffness.norm());
    }
    std::printf("joint limit stiffness beyond the edge of its range against differences: %.2g relative\n", worst);
    CHECK_LT(worst, 1e-4);
    // there, with both bones spinning alike (the damping's left-out term scales with their
    // relative spin), the blocks of Eq. 7, -dt dW_s/dv_t - dt^2 dW_s/dx_t, against differences of
    // each end's wrench in each end's turn and spin; no force rows or columns
    edge.omega = parent.omega;
    const double dt = 0.01;
    const JointBlocks blocks = joint_limit_blocks(joint_limit(k, d, parent, edge, axes, lo, hi), dt);
    auto wrench = [&](const HandleState* h, int s) {
        const Vec3 tau = joint_limit(k, d, h[kParent], h[kChild], axes, lo, hi).on_child;
        return Vec3(s == kChild ? tau : Vec3(-tau));
    };
    double worst_block = 0, scale = 0;
    for (int s = 0; s < 2; ++s)
        for (int t = 0; t < 2; ++t) {
            Mat3 expected;
            for (int i = 0; i < 3; ++i) {
                auto moved = [&](double sgn, bool spin) {
                    HandleState h[2] = {parent, edge};
                    Vec3 u = Vec3::Zero();
                    u[i] = sgn * 1e-7;
                    if (spin) h[t].omega += u;
                    else h[t].q = quat_multiply(quat_from_rotation_vector(u), h[t].q);
                    return wrench(h, s);
                };
                const Vec3 dx = (moved(1, false) - moved(-1, false)) / 2e-7, dv = (moved(1, true) - moved(-1, true)) / 2e-7;
                expected.col(i) = -dt * dv - dt * dt * dx;
            }
            CHECK(blocks.ah[s][t].topRows<3>().norm() == 0 && blocks.ah[s][t].leftCols<3>().norm() == 0);
            worst_block = std::max(worst_block, (blocks.ah[s][t].bottomRightCorner<3, 3>() - expected).norm());
            scale = std::max(scale, expected.norm());
        }
    std::printf("joint limit blocks against differences of the wrenches: %.2g relative\n", worst_block / scale);
    CHECK_LT(worst_block, 1e-4 * scale);
    const JointLimit spinning = joint_limit(k, d, parent, edge, axes, lo, hi);
    CHECK_LT((blocks.bh[kParent].tail<3>() + dt * spinning.on_child).norm(), 1e-16);
    // the damping takes nothing along the free axis's direction in psi (M^T's preimage of e_z)
    const Vec3 free_direction = spinning.damping.fullPivLu().kernel().col(0).normalized();
    const Mat3 m = quat_to_matrix(parent.q) * left_jacobian_inverse(quat_to_rotation_vector(
                       quat_multiply(quat_conjugate(parent.q), edge.q))).transpose() * axes;
    CHECK_LT(std::abs((m.transpose() * free_direction).head<2>().norm()), 1e-9);
}

TEST(joint_blocks_enter_the_step_between_parent_and_child) {
    // The three-bone chain with joints, bone 1 prescribed: the step's A_h gains, per joint, the
    // joint's blocks in the non-prescribed bones' rows (diagonal into Ah, the other end as a link),
    // and nothing else changes against the same step without joints; Schur = monolithic.
    const double k = 5e3, d = 4.0;
    const Model on = three_bone_bar(k, d), off = three_bone_bar();
    Data a(on), b(off);
    moving_state(on, a, 13);
    moving_state(off, b, 13);
    formulate_skeleton(on, a);
    formulate_skeleton(off, b);
    const SkeletonSystem &sa = a.skeleton, &sb = b.skeleton;
    // bone 1 (prescribed) sits between its parent 0 and its child 2: each joint has one free end
    CHECK(sa.links.size() == 2 && sb.links.empty());
    Mat6 expected_ah[3] = {sb.Ah[0], sb.Ah[1], sb.Ah[2]};
    VecX expected_r = sb.r;
    for (int c = 1; c < 3; ++c) {
        const int p = c - 1;
        const JointBlocks jb = joint_blocks(k, d, on.params.dt, a.carried[p], on.skeleton.joint_on_parent[c],
                                            a.carried[c], on.skeleton.joint_on_child[c]);
        const int free_end = p == 1 ? kChild : kParent, bone = free_end == kChild ? c : p;
        expected_ah[bone] += jb.ah[free_end][free_end];
        expected_r.segment<6>(6 * bone) += jb.bh[free_end];
        bool found = false;
        for (const SkeletonSystem::Link& l : sa.links)
            if (l.row == bone && l.col == (bone == c ? p : c)) found = l.block == jb.ah[free_end][1 - free_end];
        CHECK(found);
    }
    for (int bone = 0; bone < 3; ++bone) CHECK(sa.Ah[bone] == expected_ah[bone]);
    CHECK(sa.r == expected_r);
    // the joint offsets are the child's rest head from each centre of mass
    CHECK((on.skeleton.joint_on_parent[1] - (Vec3(0.025, 0.01, 0.01) - on.skeleton.bones[0].rest_com)).norm() < 1e-15);
    CHECK((on.skeleton.joint_on_child[1] - (Vec3(0.025, 0.01, 0.01) - on.skeleton.bones[1].rest_com)).norm() < 1e-15);
    a.skeleton.solve();
    const VecX mono = solve_monolithic(a.skeleton, a.skeleton.r);
    const double rel = (a.skeleton.s - mono).cwiseAbs().maxCoeff() / mono.cwiseAbs().maxCoeff();
    std::printf("three bones with joints, Schur against monolithic: %.2g relative\n", rel);
    CHECK_LT(rel, 1e-11);
}

TEST(the_b_bone_step_with_one_bone_is_the_palm_handle_step) {
    // The B-bone formulation (skeleton frame, per-bone blocks, SkeletonSystem) run on a one-bone
    // model against today's single-handle step (which step() takes for one bone): the same
    // equations, so the same step to round-off, from a deformed state spinning about a turned
    // handle, free (the free frame's momentum correction), coupled and prescribed.
    const BoxMesh box = make_box(6, 3, 3, 0.01);
    hh_params p;
    hh_default_params(&p);
    p.rayleigh_alpha = 0.5;
    p.palm_seed[0] = 0.03;
    p.palm_seed[1] = p.palm_seed[2] = 0.015;
    p.handle_radius = 0.012;
    const Model m = build_model(box.nodes.data(), box.n_nodes(), box.tets.data(), box.n_tets(), p);
    CHECK(m.n_bones() == 1);
    double worst = 0;
    // the handle's starting spin and velocity: the scale of its velocities' round-off (the
    // prescribed handle ends at rest on its target, where a relative difference is of ~1e-15)
    const Vec3 spin0(0.8, -1.5, 2.0), v_com0(0.02, -0.01, 0.03);
    for (int mode = 0; mode < 3; ++mode) {
        Data today(m), general(m);
        for (Data* d : {&today, &general}) {
            std::mt19937 rng(17);
            std::normal_distribution<double> g(0, 1);
            const Vec3 omega = spin0;
            d->h.q = quat_from_rotation_vector(Vec3(0.2, 0.4, -0.3));
            const Mat3 r = quat_to_matrix(d->h.q);
            for (int i = 0; i < m.mesh.n_nodes; ++i) {
                const Vec3 x = m.handle.rest_com + r * (m.mesh.rest.segment<3>(3 * i) - m.handle.rest_com);
                d->x.segment<3>(3 * i) = x + 3e-4 * Vec3(g(rng), g(rng), g(rng));
                d->v.segment<3>(3 * i) = omega.cross(x - m.handle.rest_com) + 0.02 * Vec3(g(rng), g(rng), g(rng));
            }
            d->h.v_com = v_com0;
            d->h.omega = omega;
            d->device.enabled = mode > 0;
            d->device.prescribed = mode == 2;
            d->device.position = m.handle.rest_com + Vec3(0.002, 0, 0);
            d->device.quaternion = quat_from_rotation_vector(Vec3(0.25, 0.35, -0.2));
            d->device.velocity = Vec3(0.05, 0, 0);
            d->device.angular_velocity = Vec3(0, 0.5, 0);
        }
        for (int k = 0; k < 8; ++k) {
            step(m, today, false);
            step_skeleton(m, general, false);
        }
        auto rel = [](const VecX& a, const VecX& b) { return (a - b).cwiseAbs().maxCoeff() / b.cwiseAbs().maxCoeff(); };
        const double here = std::max({rel(general.v, today.v), rel(general.x - m.mesh.rest, today.x - m.mesh.rest),
                          (general.h.omega - today.h.omega).norm() / std::max(today.h.omega.norm(), spin0.norm()),
                          (general.h.v_com - today.h.v_com).norm() / std::max(today.h.v_com.norm(), v_com0.norm()),
                          (general.h.q - today.h.q).norm()});
        std::printf("  mode %d: %.2g\n", mode, here);
        worst = std::max(worst, here);
    }
    std::printf("one bone, B-bone step against today's: %.2g relative\n", worst);
    CHECK_LT(worst, 1e-10);
}
