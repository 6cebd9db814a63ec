#include "sim/skeleton_frame.h"

#include "rigid/quaternion.h"

namespace hh {

namespace {
Mat3 point_inertia(double m, const Vec3& r) { return m * (r.squaredNorm() * Mat3::Identity() - r * r.transpose()); }

// The free frame's inverse inertia of the whole hand about c at the advanced state, and the sum
// of m (v - omega x (x - c)) x v_frame at the start of the step (update_step_frame).
void free_frame_terms(const Model& model, const Data& data, const std::vector<HandleState>& carried, StepFrame& f) {
    const int n = model.mesh.n_nodes;
    Mat3 inertia = Mat3::Zero();
    f.start_moment.setZero();
    for (int b = 0; b < model.n_bones(); ++b) {
        const HandleModel& bone = model.skeleton.bones[b];
        const HandleState& h = bone_state(data, b);
        const Mat3 turned = quat_to_matrix(carried[b].q);
        inertia += turned * bone.inertia_body * turned.transpose() + point_inertia(bone.mass, carried[b].x_com - f.center);
        f.start_moment += bone.mass * (h.v_com - f.omega.cross(h.x_com - f.center)).cross(carried[b].v_com);
    }
    for (int i = 0; i < n; ++i) {
        const Vec3 r = data.x.segment<3>(3 * i) - f.center;
        inertia += point_inertia(model.masses[i], f.x.segment<3>(3 * i) - f.center);
        f.start_moment += model.masses[i] * (data.v.segment<3>(3 * i) - f.omega.cross(r)).cross(f.v.segment<3>(3 * i));
    }
    f.inertia_inverse = inertia.inverse();
}
}  // namespace

void update_skeleton_frame(const Model& model, const Data& data, StepFrame& f, std::vector<HandleState>& carried) {
    const int n = model.mesh.n_nodes, nb = model.n_bones();
    const bool held = data.device.enabled || data.device.prescribed;
    f.dt = model.params.dt;
    const FrameMotion motion =
        hand_motion(model, data.x, data.v, held, [&](int b) -> const HandleState& { return bone_state(data, b); });
    f.center = motion.center;
    f.omega = motion.omega;
    f.turn = quat_from_rotation_vector(f.dt * f.omega);
    f.rotation = quat_to_matrix(f.turn);
    f.remainder = (Mat3::Identity() - f.dt * skew(f.omega)) * f.rotation - Mat3::Identity();
    f.x.resize(3 * n);
    f.v.resize(3 * n);
    Vec3 moment = Vec3::Zero();  // sum of m (x - c) over the bones and the flesh
    carried.resize(nb);
    for (int b = 0; b < nb; ++b) {
        const HandleState& h = bone_state(data, b);
        const Vec3 turned = f.rotation * (h.x_com - f.center);
        carried[b].x_com = f.center + turned;
        carried[b].q = quat_multiply(f.turn, h.q).normalized();
        carried[b].v_com = f.omega.cross(turned);
        carried[b].omega = f.omega;
        moment += model.skeleton.bones[b].mass * (h.x_com - f.center);
    }
    for (int i = 0; i < n; ++i) {
        const Vec3 r = data.x.segment<3>(3 * i) - f.center;
        const Vec3 turned = f.rotation * r;
        f.x.segment<3>(3 * i) = f.center + turned;
        f.v.segment<3>(3 * i) = f.omega.cross(turned);
        moment += model.masses[i] * r;
    }
    f.handle = carried[0];
    f.imbalance = f.omega.cross(f.remainder * moment);
    f.free = !held;
    f.inertia_inverse.setZero();
    f.start_moment.setZero();
    if (f.free) free_frame_terms(model, data, carried, f);
}

VecX skeleton_frame_velocities(const Model& model, const StepFrame& f, const std::vector<HandleState>& carried,
                               const VecX& relative) {
    const int n = model.mesh.n_nodes, nb = model.n_bones();
    VecX s = relative;
    for (int b = 0; b < nb; ++b) {
        s.segment<3>(6 * b) += carried[b].v_com;
        s.segment<3>(6 * b + 3) += carried[b].omega;
    }
    s.tail(3 * n) += f.v;
    if (!f.free || f.omega.isZero()) return s;
    // the excess angular momentum of the frame's velocities, taken out as a rigid turn (frame_velocities)
    Vec3 moment = -f.start_moment;
    for (int b = 0; b < nb; ++b) moment += model.skeleton.bones[b].mass * relative.segment<3>(6 * b).cross(carried[b].v_com);
    for (int i = 0; i < n; ++i) moment += model.masses[i] * relative.segment<3>(6 * nb + 3 * i).cross(f.v.segment<3>(3 * i));
    const Vec3 turn = -f.dt * (f.inertia_inverse * moment);
    for (int b = 0; b < nb; ++b) {
        s.segment<3>(6 * b) += turn.cross(carried[b].x_com - f.center);
        s.segment<3>(6 * b + 3) += turn;
    }
    for (int i = 0; i < n; ++i) s.segment<3>(6 * nb + 3 * i) += turn.cross(f.x.segment<3>(3 * i) - f.center);
    return s;
}

}  // namespace hh
