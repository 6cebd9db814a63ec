#include "haptics/bone_proxies.h"

#include <string>

#include "rigid/quaternion.h"

namespace hh {

BoneProxies::BoneProxies(const Model& m, const std::vector<HandleState>& bones, const VirtualCoupling& c)
    : state(bones), coupling(c) {
    const int nb = static_cast<int>(bones.size());
    for (int b = 0; b < nb; ++b) {
        mass.push_back(m.skeleton.bones[b].mass);
        inertia_body.push_back(m.skeleton.bones[b].inertia_body);
    }
    rhs_ = v_ = force_ = delta_ = VecX::Zero(6 * nb);
}

void BoneProxies::prepare(BoneSnapshot& s, double h) const {
    const int nb = n();
    s.inertia.resize(nb);
    MatX lhs = MatX::Zero(6 * nb, 6 * nb);
    if (s.model.valid) lhs = -h * h * s.model.stiffness;
    const double lin = h * h * coupling.stiffness + h * coupling.damping;
    const double ang = h * h * coupling.angular_stiffness + h * coupling.angular_damping;
    for (int b = 0; b < nb; ++b) {
        const Mat3 r = quat_to_matrix(s.model.ends[b].q);
        s.inertia[b] = r * inertia_body[b] * r.transpose();
        lhs.block<3, 3>(6 * b, 6 * b) += (mass[b] + lin) * Mat3::Identity();
        lhs.block<3, 3>(6 * b + 3, 6 * b + 3) += s.inertia[b] + ang * Mat3::Identity();
    }
    s.step_inverse = lhs.partialPivLu().inverse();
    if (!s.step_inverse.allFinite()) throw NumericalError("the bones' haptic step matrix is singular: lower the haptic rate's period or the coupling model's stiffness");
}

void BoneProxies::step(double h, double t, const BoneSnapshot& s, bool linearized, const Pose* devices,
                       Feedback* out) noexcept {
    const int nb = n();
    const BoneCouplingModel& model = s.model;
    if (!linearized) {
        for (int b = 0; b < nb; ++b) state[b] = model.ends[b];
    } else {
        // the bones' linearized wrenches at the proxies' poses at the step's end (the model's
        // references move on by h), and each proxy's momentum and still coupling
        if (model.valid) {
            for (int b = 0; b < nb; ++b) delta_.segment<6>(6 * b) = model.displacement(b, t + h, state[b].x_com, state[b].q);
            force_ = model.wrench;
            force_.noalias() += model.stiffness * delta_;
        } else {
            force_.setZero();
        }
        for (int b = 0; b < nb; ++b) {
            const Mat3& inertia = s.inertia[b];
            const HandleState& p = state[b];
            HandleState still = p;
            still.v_com.setZero();
            still.omega.setZero();
            rhs_.segment<3>(6 * b) = mass[b] * p.v_com;
            rhs_.segment<3>(6 * b + 3) = inertia * p.omega - h * p.omega.cross(inertia * p.omega);
            rhs_.segment<6>(6 * b) += h * (force_.segment<6>(6 * b) + coupling_on_proxy(still, devices[b], coupling));
        }
        v_.noalias() = s.step_inverse * rhs_;
        for (int b = 0; b < nb; ++b) {
            HandleState& p = state[b];
            p.v_com = v_.segment<3>(6 * b);
            p.omega = v_.segment<3>(6 * b + 3);
            p.x_com += h * p.v_com;
            p.q = quat_multiply(quat_from_rotation_vector(h * p.omega), p.q).normalized();
        }
    }
    for (int b = 0; b < nb; ++b) {
        const Vec6 w = coupling_on_proxy(state[b], devices[b], coupling);
        out[b].force = -w.head<3>();
        out[b].torque = -w.tail<3>();
    }
}

FeedbackGroups::FeedbackGroups(std::vector<int> group_of_bone, int n_groups)
    : of_bone(std::move(group_of_bone)), first(n_groups, -1) {
    for (int b = static_cast<int>(of_bone.size()) - 1; b >= 0; --b) {
        if (of_bone[b] < -1 || of_bone[b] >= n_groups)
            throw InvalidArgument("bone " + std::to_string(b) + " is in group " + std::to_string(of_bone[b]) +
                                  ": give each bone a group from 0 to " + std::to_string(n_groups - 1) + ", or -1 for none");
        if (of_bone[b] >= 0) first[of_bone[b]] = b;
    }
    for (int g = 0; g < n_groups; ++g)
        if (first[g] < 0) throw InvalidArgument("group " + std::to_string(g) + " has no bone: number the groups 0 .. n - 1, each with a bone");
}

void group_feedback(const FeedbackGroups& groups, const Pose* devices, const Feedback* bones, Feedback* out) noexcept {
    for (int g = 0; g < groups.n(); ++g) out[g] = Feedback{};
    for (size_t b = 0; b < groups.of_bone.size(); ++b) {
        const int g = groups.of_bone[b];
        if (g < 0) continue;
        const Vec3 arm = devices[b].position - devices[groups.first[g]].position;
        out[g].force += bones[b].force;
        out[g].torque += bones[b].torque + arm.cross(bones[b].force);
    }
}

}  // namespace hh
