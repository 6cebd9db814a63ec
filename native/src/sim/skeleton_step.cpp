#include "sim/skeleton_step.h"

#include <chrono>

#include "common/clock.h"
#include "coupling/joint_limits.h"
#include "coupling/joints.h"
#include "rigid/quaternion.h"
#include "sim/skeleton_frame.h"

namespace hh {

namespace {
// Bone b's block of Eq. 7 and its rows of b_h: its inertia relative to the frame, the gyroscopic
// torque explicit, its springs (cb), its virtual coupling to its target implicit in its own
// state (Fig. 2, top; docs/skeleton.md Section 4), or its rows replaced by v_b = target when
// prescribed. The same terms as formulate_end's for the palm handle.
void bone_block(const Model& model, Data& data, int b, const CouplingBlocks& cb) {
    const double dt = model.params.dt;
    const StepFrame& f = data.frame;
    const HandleModel& bone = model.skeleton.bones[b];
    const HandleState& h = bone_state(data, b);
    const HandleState& c = data.carried[b];
    SkeletonSystem& sys = data.skeleton;
    const Mat3 rot = quat_to_matrix(c.q);
    const Mat3 inertia = rot * bone.inertia_body * rot.transpose();
    Mat6 ah = Mat6::Zero();
    ah.topLeftCorner<3, 3>() = bone.mass * Mat3::Identity();
    ah.bottomRightCorner<3, 3>() = inertia;
    Vec6 bh;
    // the flesh's remainder reaction (StepFrame::imbalance) goes to the root, as to the palm handle
    bh.head<3>() = relative_momentum(f, bone.mass, h.x_com, h.v_com) - (b == 0 ? f.imbalance : Vec3::Zero());
    bh.tail<3>() = inertia * (h.omega - f.omega) - dt * h.omega.cross(inertia * h.omega);  // gyroscopic, explicit
    const DeviceFrame& target = bone_target(data, b);
    const Vec3 rot_error = quat_to_rotation_vector(quat_multiply(target.quaternion, quat_conjugate(c.q)));
    if (target.enabled) {
        const Vec4 g = bone_drive(model, b);  // k, d, k_r, d_r
        ah.topLeftCorner<3, 3>() += (dt * g[1] + dt * dt * g[0]) * Mat3::Identity();
        ah.bottomRightCorner<3, 3>() += (dt * g[3] + dt * dt * g[2]) * Mat3::Identity();
        bh.head<3>() += dt * (g[0] * (target.position - c.x_com) + g[1] * (target.velocity - c.v_com));
        bh.tail<3>() += dt * (g[2] * rot_error + g[3] * (target.angular_velocity - c.omega));
    }
    sys.Ah[b] = ah + cb.ah;
    sys.r.segment<6>(6 * b) = bh + cb.bh;
    sys.Ath[b] = cb.ath;
    sys.Aht[b] = cb.aht;
    if (target.prescribed) {  // v_b reaches the target pose at the end of the step; the flesh feels it through A_th
        sys.Ah[b] = Mat6::Identity();
        sys.r.segment<3>(6 * b) = (target.position - c.x_com) / dt;
        sys.r.segment<3>(6 * b + 3) = rot_error / dt;
        for (Mat63& block : sys.Aht[b]) block.setZero();
    }
}

// A joint's blocks of Eq. 7 between bone b and its parent a. A prescribed bone's rows stay
// v_b = target (its velocity is known), so it gets no joint terms; the other end's rows still
// see it through their link block.
void add_joint_blocks(Data& data, int a, int b, const JointBlocks& jb) {
    SkeletonSystem& sys = data.skeleton;
    const int bone[2] = {a, b};
    for (int s = 0; s < 2; ++s) {
        if (bone_target(data, bone[s]).prescribed) continue;
        sys.Ah[bone[s]] += jb.ah[s][s];
        sys.r.segment<6>(6 * bone[s]) += jb.bh[s];
        sys.links.push_back({bone[s], bone[1 - s], jb.ah[s][1 - s]});
    }
}

// The ball joints (docs/skeleton.md Section 5): each bone with a parent is tied to it at its
// head, implicit in both bones' states.
void joint_terms(const Model& model, Data& data) {
    const hh_params& p = model.params;
    if (p.joint_stiffness == 0 && p.joint_damping == 0) return;  // no joints: the step without them, bit for bit
    const SkeletonModel& sk = model.skeleton;
    for (int b = 0; b < model.n_bones(); ++b) {
        const int a = sk.parents[b];
        if (a < 0) continue;
        add_joint_blocks(data, a, b,
                         joint_blocks(p.joint_stiffness, p.joint_damping, p.dt, data.carried[a], sk.joint_on_parent[b],
                                      data.carried[b], sk.joint_on_child[b]));
    }
}

// The angular limits (docs/skeleton.md Section 5): each limited bone beyond its range at the
// carried states turns back towards it, implicit in both bones' states (coupling/joint_limits.h).
void limit_terms(const Model& model, Data& data) {
    const hh_params& p = model.params;
    if (p.joint_limit_stiffness == 0 && p.joint_limit_damping == 0) return;  // no limits: bit for bit without
    const SkeletonModel& sk = model.skeleton;
    for (int b = 0; b < model.n_bones(); ++b) {
        if (!sk.limited[b]) continue;
        const int a = sk.parents[b];
        const JointLimit limit = joint_limit(p.joint_limit_stiffness, p.joint_limit_damping, data.carried[a],
                                             data.carried[b], sk.limit_axes[b], sk.limit_min[b], sk.limit_max[b]);
        if (limit.active) add_joint_blocks(data, a, b, joint_limit_blocks(limit, p.dt));
    }
}
}  // namespace

void formulate_skeleton_begin(const Model& model, Data& data) {
    StepFrame& f = data.frame;
    update_skeleton_frame(model, data, f, data.carried);
    begin_flesh(model, data, data.tool);
    for (Vec4& q : data.rotations.q) q = quat_multiply(f.turn, q);
}

void formulate_skeleton(const Model& model, Data& data) {
    formulate_skeleton_begin(model, data);
    formulate_skeleton_end(model, data);
}

void formulate_skeleton_end(const Model& model, Data& data) {
    const hh_params& p = model.params;
    const double dt = p.dt;
    const int n = model.mesh.n_nodes, nb = model.n_bones();
    const Vec3 g(p.gravity[0], p.gravity[1], p.gravity[2]);
    SkeletonSystem& sys = data.skeleton;
    sys.resize(nb);
    sys.r.resize(6 * nb + 3 * n);
    const StepFrame& f = data.frame;
    for (int part = 0; part < 3; ++part) flesh_pass(model, data, dt, p.rayleigh_beta, data.tool, part, &f.x);

    // A_t and b_t as formulate_end's, the springs of every bone on its own nodes (Eq. 7)
    auto bt = sys.r.tail(3 * n);
    end_flesh(model, data, dt, g, p.rayleigh_alpha, data.tool, bt);
    for (int i = 0; i < n; ++i)
        bt.segment<3>(3 * i) += relative_momentum(f, model.masses[i], data.x.segment<3>(3 * i), Vec3::Zero()) -
                                dt * p.rayleigh_alpha * model.masses[i] * f.v.segment<3>(3 * i);
    data.bone_coupling.resize(nb);
    data.bones_prescribed = true;
    for (int b = 0; b < nb; ++b) {
        data.bones_prescribed = data.bones_prescribed && bone_target(data, b).prescribed;
        const HandleModel& bone = model.skeleton.bones[b];
        CouplingBlocks& cb = data.bone_coupling[b];
        assemble_coupling(p.spring_stiffness, p.spring_damping, dt, bone.nodes, bone.r_body, f.x, f.v, data.carried[b],
                          cb);
        for (size_t j = 0; j < bone.nodes.size(); ++j) {
            add_node_block(model, bone.nodes[j], cb.at_diagonal[j], data.tool.A.valuePtr());
            bt.segment<3>(3 * bone.nodes[j]) += cb.bt[j];
        }
        sys.nodes[b] = &bone.nodes;
        bone_block(model, data, b, cb);
    }
    joint_terms(model, data);
    limit_terms(model, data);
}

void integrate_skeleton(const Model& model, Data& data, const VecX& s) {
    const double dt = model.params.dt;
    const int n = model.mesh.n_nodes, nb = model.n_bones();
    const StepFrame& f = data.frame;
    data.v = s.tail(3 * n);
    data.x = f.x + dt * (data.v - f.v);
    for (int b = 0; b < nb; ++b) {
        HandleState& h = bone_state(data, b);
        const HandleState& c = data.carried[b];
        h.v_com = s.segment<3>(6 * b);
        h.omega = s.segment<3>(6 * b + 3);
        h.x_com = c.x_com + dt * (h.v_com - c.v_com);
        // the exponential map keeps q_b a unit quaternion
        h.q = quat_multiply(quat_from_rotation_vector(dt * (h.omega - c.omega)), c.q);
        h.q.normalize();
    }
}

void step_skeleton(const Model& model, Data& data, bool monolithic) {
    using clock = std::chrono::steady_clock;
    const auto t0 = clock::now();
    formulate_skeleton(model, data);
    data.stats = hh_step_stats{};
    data.stats.t_assembly = seconds_since(t0);
    data.tool.reset_counters();
    SkeletonSystem& sys = data.skeleton;
    if (monolithic) {
        const auto t1 = clock::now();
        sys.s = solve_monolithic(sys, sys.r);
        data.stats.t_deformable = seconds_since(t1);
    } else {
        sys.solve();
        data.stats.t_deformable = sys.t_deformable;
        data.stats.t_schur = sys.t_schur;
        data.stats.cg_iterations = data.tool.iterations;
        data.stats.max_residual = data.tool.max_residual;
    }
    integrate_skeleton(model, data, skeleton_frame_velocities(model, data.frame, data.carried, sys.s));
    data.stats.t_total = seconds_since(t0);
}

std::vector<Vec6> bone_wrenches(const Model& model, const Data& data) {
    std::vector<Vec6> out(model.n_bones(), Vec6::Zero());
    for (int b = 0; b < model.n_bones(); ++b) {
        const HandleModel& bone = model.skeleton.bones[b];
        for (size_t j = 0; j < bone.nodes.size(); ++j) {
            const int i = bone.nodes[j];
            const SpringForce s = spring_force(model.params.spring_stiffness, model.params.spring_damping,
                                               data.x.segment<3>(3 * i), data.v.segment<3>(3 * i), bone.r_body[j],
                                               bone_state(data, b));
            out[b].head<3>() += s.on_handle;
            out[b].tail<3>() += s.torque;
        }
    }
    return out;
}

double joint_energy(const Model& model, const Data& data) {
    const SkeletonModel& sk = model.skeleton;
    const hh_params& p = model.params;
    double e = 0;
    for (int b = 0; b < model.n_bones(); ++b) {
        const int a = sk.parents[b];
        if (a < 0) continue;
        if (p.joint_stiffness != 0)
            e += joint_force(p.joint_stiffness, 0, bone_state(data, a), sk.joint_on_parent[b], bone_state(data, b),
                             sk.joint_on_child[b])
                     .energy;
        if (p.joint_limit_stiffness != 0 && sk.limited[b])
            e += joint_limit(p.joint_limit_stiffness, 0, bone_state(data, a), bone_state(data, b), sk.limit_axes[b],
                             sk.limit_min[b], sk.limit_max[b])
                     .energy;
    }
    return e;
}

}  // namespace hh
