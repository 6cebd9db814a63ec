#include "haptics/bone_model.h"

#include "haptics/coupling_model.h"
#include "rigid/quaternion.h"
#include "sim/skeleton_step.h"

namespace hh {

namespace {
VecX stacked(const std::vector<Vec6>& w) {
    VecX out(6 * w.size());
    for (size_t b = 0; b < w.size(); ++b) out.segment<6>(6 * b) = w[b];
    return out;
}
// The angular velocity of the frame of a step whose bones are all prescribed (the root held).
Vec3 held_turn(const Model& m, const Data& d) {
    return hand_motion(m, d.x, d.v, true, [&](int b) -> const HandleState& { return bone_state(d, b); }).omega;
}

}  // namespace

std::unique_ptr<Data> driven_bones(const Model& m, const Data& d, const VecX& vh) {
    const int nb = m.n_bones();
    if (vh.size() != 6 * nb || !vh.allFinite())
        throw InvalidArgument("the bones' end velocities must be 6 finite numbers per bone");
    auto work = std::make_unique<Data>(m);
    static_cast<FleshState&>(*work) = static_cast<const FleshState&>(d);
    work->h = d.h;
    work->bones = d.bones;
    work->targets = d.targets;
    work->device = d.device;
    // a prescribed root holds the frame: it turns by exp(dt omega) about the root's centre, omega
    // the hand's own turn (sim/step_frame.h)
    const double dt = m.params.dt;
    const Vec3 c = d.h.x_com, omega = held_turn(m, d);
    const Vec4 turn = quat_from_rotation_vector(dt * omega);
    const Mat3 rot = quat_to_matrix(turn);
    for (int b = 0; b < nb; ++b) {
        const HandleState& h = bone_state(d, b);
        const Vec3 arm = rot * (h.x_com - c);  // the carried centre is c + arm, its frame velocity omega x arm
        DeviceFrame& t = bone_target(*work, b);
        t.enabled = t.prescribed = true;
        t.position = c + arm + dt * (vh.segment<3>(6 * b) - omega.cross(arm));
        const Vec4 carried = quat_multiply(turn, h.q).normalized();
        t.quaternion = quat_multiply(quat_from_rotation_vector(dt * (vh.segment<3>(6 * b + 3) - omega)), carried).normalized();
    }
    step(m, *work, false);
    return work;
}

VecX bone_response(const Model& m, const Data& d, const VecX& vh) {
    const auto work = driven_bones(m, d, vh);
    return stacked(bone_wrenches(m, *work));
}

BoneLinearModel bone_linear_model(const Model& m, const Data& d) {
    const int nb = m.n_bones();
    const double dt = m.params.dt;
    const auto w = driven_bones(m, d, VecX::Zero(6 * nb));
    BoneLinearModel out;
    if (nb == 1) {  // the palm handle's model (hh_coupling_linear_model), the same step
        const CouplingModel cm = hand_coupling_model(m, *w, Mat6::Zero());
        Mat6 pose_rate = dt * Mat6::Identity();
        pose_rate.bottomRightCorner<3, 3>() = dt * left_jacobian(-dt * held_turn(m, d));
        out.wrench0 = cm.wrench;
        out.response = cm.stiffness * pose_rate;
        return out;
    }
    out.wrench0 = stacked(bone_wrenches(m, *w));
    const double k = m.params.spring_stiffness, damping = m.params.spring_damping;
    // d(x_b, theta_b)/d(v_b, omega_b) of the end pose at v_h = 0: dt I, and dt J_l of the end's
    // turn relative to the frame, exp(dt (omega_b - omega)) at omega_b = 0
    Mat6 pose_rate = dt * Mat6::Identity();
    pose_rate.bottomRightCorner<3, 3>() = dt * left_jacobian(-dt * held_turn(m, d));
    const MatX& columns = w->skeleton.flesh_response();  // A_t^-1 A_th (3n x 6B)
    out.response = MatX::Zero(6 * nb, 6 * nb);
    for (int b = 0; b < nb; ++b) {
        const HandleModel& bone = m.skeleton.bones[b];
        const HandleState& h = bone_state(*w, b);
        const Mat3 end_rotation = quat_to_matrix(h.q);
        Mat6 pose = Mat6::Zero(), velocity = Mat6::Zero();
        for (size_t j = 0; j < bone.nodes.size(); ++j) {
            const int i = bone.nodes[j];
            const SpringJacobian jac = spring_jacobian(k, damping, w->x.segment<3>(3 * i), w->v.segment<3>(3 * i),
                                                       bone.r_body[j], h);
            pose += jac.dfh_dxh;
            velocity += jac.dfh_dvh;
            // the flesh: dv_t = -A_t^-1 A_th dv_h (Eq. 12), dx_t = dt dv_t, seen by W_b through
            // A_ht at the end pose: dt dW/dx_i + dW/dv_i = -A_ht,e / dt
            const Mat63 aht = handle_flesh_block(k, damping, dt, end_rotation * bone.r_body[j]);
            out.response.middleRows<6>(6 * b).noalias() += aht * columns.middleRows<3>(3 * i) / dt;
        }
        out.response.block<6, 6>(6 * b, 6 * b) += pose * pose_rate + velocity;
    }
    if (!out.response.allFinite() || !out.wrench0.allFinite()) throw NumericalError("the bones' model has non-finite entries");
    return out;
}

}  // namespace hh
