#include <chrono>

#include "common/clock.h"
#include "rigid/quaternion.h"
#include "sim/data.h"
#include "sim/skeleton_step.h"

namespace hh {

Data::Data(const Model& model) {
    reset(model, *this);
    configure_solver(model, *this);
    tool.A = model.pattern.matrix;
    hand.coupled_nodes = model.handle.nodes;
}

void reset(const Model& model, Data& data) {
    reset_flesh(model, data);
    data.h = HandleState{};
    data.h.x_com = model.handle.rest_com;
    data.device = DeviceFrame{};
    data.device.position = model.handle.rest_com;
    const int nb = model.n_bones();
    data.bones.assign(nb - 1, HandleState{});
    data.targets.assign(nb - 1, DeviceFrame{});
    for (int b = 1; b < nb; ++b) {  // at rest, each target the bone's rest pose
        data.bones[b - 1].x_com = model.skeleton.bones[b].rest_com;
        data.targets[b - 1].position = model.skeleton.bones[b].rest_com;
    }
}

void configure_solver(const Model& model, Data& data) {
    const hh_params& p = model.params;
    data.tool.configure(p.solver == HH_SOLVER_CG                  ? DeformableSolver::ConjugateGradient
                        : p.solver == HH_SOLVER_REUSED_CHOLESKY ? DeformableSolver::ReusedCholesky
                                                                : DeformableSolver::Cholesky,
                        p.cg_tolerance, p.cg_max_iterations);
}

Mat3 handle_world_inertia(const Model& model, const HandleState& h) {
    const Mat3 r = quat_to_matrix(h.q);
    return r * model.handle.inertia_body * r.transpose();
}

void coupling_wrench(const Model& model, const Data& data, Vec3& force, Vec3& torque) {
    force.setZero();
    torque.setZero();
    for (size_t j = 0; j < model.handle.nodes.size(); ++j) {
        const int i = model.handle.nodes[j];
        const SpringForce s = spring_force(model.params.spring_stiffness, model.params.spring_damping,
                                           data.x.segment<3>(3 * i), data.v.segment<3>(3 * i), model.handle.r_body[j], data.h);
        force += s.on_handle;
        torque += s.torque;
    }
}

void formulate(const Model& model, Data& data) {
    formulate_begin(model, data);
    for (int part = 0; part < 3; ++part) formulate_pass(model, data, part);
    formulate_end(model, data);
}

void formulate_begin(const Model& model, Data& data) {
    data.hand.r.resize(6 + 3 * model.mesh.n_nodes);
    update_step_frame(model, data.x, data.v, data.h, data.device.enabled || data.device.prescribed, data.frame);
    begin_flesh(model, data, data.tool);
    // the polar decompositions start from last step's rotations turned by the frame's
    for (Vec4& q : data.rotations.q) q = quat_multiply(data.frame.turn, q);
}

void formulate_pass(const Model& model, Data& data, int part) {
    flesh_pass(model, data, model.params.dt, model.params.rayleigh_beta, data.tool, part, &data.frame.x);
}

void formulate_end(const Model& model, Data& data) {
    const hh_params& p = model.params;
    const double dt = p.dt;
    const int n = model.mesh.n_nodes;
    const Vec3 g(p.gravity[0], p.gravity[1], p.gravity[2]);
    const StepFrame& f = data.frame;

    // Deformable block (shared with every soft body) at the advanced state, then the springs'
    // part of A_t and b_t. Eq. 7 relative to the frame's velocities s~ at the advanced state X~:
    //   A (s - s~) = M (v - v_frame) - dt M omega x (omega x R r) + dt F(X~, s~),
    // the inertia term relative to the frame (sim/step_frame.h) and every force at X~, s~; of
    // Rayleigh damping only alpha M acts on the frame's velocity (beta K damps deformation).
    VecX& r = data.hand.r;
    auto bt = r.tail(3 * n);
    end_flesh(model, data, dt, g, p.rayleigh_alpha, data.tool, bt);  // b_t = M v + dt (f(X~) + M g)
    for (int i = 0; i < n; ++i)
        bt.segment<3>(3 * i) += relative_momentum(f, model.masses[i], data.x.segment<3>(3 * i), Vec3::Zero()) -
                                dt * p.rayleigh_alpha * model.masses[i] * f.v.segment<3>(3 * i);
    assemble_coupling(p.spring_stiffness, p.spring_damping, dt, model.handle.nodes, model.handle.r_body, f.x, f.v,
                      f.handle, data.coupling);
    const CouplingBlocks& cb = data.coupling;
    for (size_t j = 0; j < model.handle.nodes.size(); ++j) {
        add_node_block(model, model.handle.nodes[j], cb.at_diagonal[j], data.tool.A.valuePtr());
        bt.segment<3>(3 * model.handle.nodes[j]) += cb.bt[j];
    }

    // Rigid block (Eq. 3 and 7): gravity acts on the flesh only; the handle's mass is the
    // captured nodes' mass counted again for its inertia, so the hand's weight is counted once.
    const HandleState& h = data.h;
    const Mat3 inertia = handle_world_inertia(model, f.handle);
    Mat6 ah = Mat6::Zero();
    ah.topLeftCorner<3, 3>() = model.handle.mass * Mat3::Identity();
    ah.bottomRightCorner<3, 3>() = inertia;
    Vec6 bh;
    bh.head<3>() = relative_momentum(f, model.handle.mass, h.x_com, h.v_com) - f.imbalance;
    bh.tail<3>() = inertia * (h.omega - f.omega) - dt * h.omega.cross(inertia * h.omega);  // gyroscopic, explicit
    const DeviceFrame& dev = data.device;
    if (dev.enabled) {
        // One-directional viscoelastic virtual coupling to the device frame at the end of the
        // step (Fig. 2, top): implicit in the handle's own position and velocity.
        const double lin = dt * p.coupling_damping + dt * dt * p.coupling_stiffness;
        const double ang = dt * p.coupling_angular_damping + dt * dt * p.coupling_angular_stiffness;
        ah.topLeftCorner<3, 3>() += lin * Mat3::Identity();
        ah.bottomRightCorner<3, 3>() += ang * Mat3::Identity();
        const Vec3 rot_error = quat_to_rotation_vector(quat_multiply(dev.quaternion, quat_conjugate(f.handle.q)));
        bh.head<3>() += dt * (p.coupling_stiffness * (dev.position - f.handle.x_com) +
                              p.coupling_damping * (dev.velocity - f.handle.v_com));
        bh.tail<3>() += dt * (p.coupling_angular_stiffness * rot_error +
                              p.coupling_angular_damping * (dev.angular_velocity - f.omega));
    }
    data.hand.Ah = ah + cb.ah;
    r.head<6>() = bh + cb.bh;
    data.hand.Ath = cb.ath;
    data.hand.Aht = cb.aht;
    data.end_aht.clear();
    if (dev.prescribed) {
        // The handle reaches the device pose at the end of the step: its rows of Eq. 7 become
        // v_h = target, and the flesh still feels it through Ath (Eq. 12). The coupling model
        // reads Aht at that pose (end_aht).
        data.hand.Ah = Mat6::Identity();
        r.segment<3>(0) = (dev.position - f.handle.x_com) / dt;
        r.segment<3>(3) = quat_to_rotation_vector(quat_multiply(dev.quaternion, quat_conjugate(f.handle.q))) / dt;
        for (Mat63& block : data.hand.Aht) block.setZero();
        const Mat3 end_rotation = quat_to_matrix(dev.quaternion);
        data.end_aht.resize(model.handle.nodes.size());
        for (size_t j = 0; j < model.handle.nodes.size(); ++j)
            data.end_aht[j] =
                handle_flesh_block(p.spring_stiffness, p.spring_damping, dt, end_rotation * model.handle.r_body[j]);
    }
}

VecX step_velocities(const Model& model, const Data& data, const VecX& relative) {
    return frame_velocities(model, data.frame, relative);
}

void integrate(const Model& model, Data& data, const VecX& s) {
    const double dt = model.params.dt;
    const int n = model.mesh.n_nodes;
    const StepFrame& f = data.frame;
    data.v = s.tail(3 * n);
    data.x = f.x + dt * (data.v - f.v);
    data.h.v_com = s.segment<3>(0);
    data.h.omega = s.segment<3>(3);
    data.h.x_com = f.handle.x_com + dt * (data.h.v_com - f.handle.v_com);
    // the exponential map keeps q_h a unit quaternion (first-order equal to q + dt G omega)
    data.h.q = quat_multiply(quat_from_rotation_vector(dt * (data.h.omega - f.omega)), f.handle.q);
    data.h.q.normalize();
}

void step(const Model& model, Data& data, bool monolithic) {
    if (model.n_bones() > 1) return step_skeleton(model, data, monolithic);  // (one bone: today's step)
    using clock = std::chrono::steady_clock;
    const auto t0 = clock::now();
    formulate(model, data);
    data.stats = hh_step_stats{};
    data.stats.t_assembly = seconds_since(t0);
    data.tool.reset_counters();
    if (monolithic) {
        const auto t1 = clock::now();
        const VecX s = solve_monolithic(data.hand, data.hand.r);
        data.stats.t_deformable = seconds_since(t1);
        integrate(model, data, step_velocities(model, data, s));
    } else {
        data.hand.solve();
        data.stats.t_deformable = data.hand.t_deformable;
        data.stats.t_schur = data.hand.t_schur;
        data.stats.cg_iterations = data.tool.iterations;
        data.stats.max_residual = data.tool.max_residual;
        integrate(model, data, step_velocities(model, data, data.hand.s));
    }
    data.stats.t_total = seconds_since(t0);
}

}  // namespace hh
