#include "sim/step_frame.h"

#include "rigid/quaternion.h"

namespace hh {

namespace {
Mat3 point_inertia(double m, const Vec3& r) { return m * (r.squaredNorm() * Mat3::Identity() - r * r.transpose()); }
}  // namespace

void TurnFit::add_point(double m, const Vec3& r, const Vec3& v_relative) {
    inertia += point_inertia(m, r);
    momentum += m * r.cross(v_relative);
}

void TurnFit::add_body(double m, const Mat3& world_inertia, const Vec3& r, const Vec3& v_relative, const Vec3& omega) {
    add_point(m, r, v_relative);
    inertia += world_inertia;
    momentum += world_inertia * omega;
}

Vec3 TurnFit::omega() const { return inertia.ldlt().solve(momentum); }

void update_step_frame(const Model& model, const VecX& x, const VecX& v, const HandleState& h, bool held, StepFrame& f) {
    const int n = model.mesh.n_nodes;
    f.dt = model.params.dt;
    const FrameMotion motion = hand_motion(model, x, v, held, [&](int) -> const HandleState& { return h; });
    f.center = motion.center;
    f.omega = motion.omega;
    f.turn = quat_from_rotation_vector(f.dt * f.omega);
    f.rotation = quat_to_matrix(f.turn);
    f.remainder = (Mat3::Identity() - f.dt * skew(f.omega)) * f.rotation - Mat3::Identity();
    f.x.resize(3 * n);
    f.v.resize(3 * n);
    Vec3 moment = model.handle.mass * (h.x_com - f.center);  // sum of m (x - c)
    for (int i = 0; i < n; ++i) {
        const Vec3 r = x.segment<3>(3 * i) - f.center;
        const Vec3 turned = f.rotation * r;
        f.x.segment<3>(3 * i) = f.center + turned;
        f.v.segment<3>(3 * i) = f.omega.cross(turned);
        moment += model.masses[i] * r;
    }
    const Vec3 handle_turned = f.rotation * (h.x_com - f.center);
    f.handle.x_com = f.center + handle_turned;
    f.handle.q = quat_multiply(f.turn, h.q).normalized();
    f.handle.v_com = f.omega.cross(handle_turned);
    f.handle.omega = f.omega;
    f.imbalance = f.omega.cross(f.remainder * moment);
    f.free = !held;
    f.inertia_inverse.setZero();
    f.start_moment.setZero();
    if (f.free) {
        const Mat3 turned = quat_to_matrix(f.handle.q);
        Mat3 inertia =
            turned * model.handle.inertia_body * turned.transpose() + point_inertia(model.handle.mass, handle_turned);
        f.start_moment = model.handle.mass * (h.v_com - f.omega.cross(h.x_com - f.center)).cross(f.handle.v_com);
        for (int i = 0; i < n; ++i) {
            const Vec3 r = x.segment<3>(3 * i) - f.center;
            inertia += point_inertia(model.masses[i], f.x.segment<3>(3 * i) - f.center);
            f.start_moment += model.masses[i] * (v.segment<3>(3 * i) - f.omega.cross(r)).cross(f.v.segment<3>(3 * i));
        }
        f.inertia_inverse = inertia.inverse();
    }
}

Vec3 turn_remainder(const StepFrame& f, const Vec3& x) { return f.remainder * (x - f.center); }

VecX frame_velocities(const Model& model, const StepFrame& f, const VecX& relative) {
    VecX s = relative;
    s.head<6>() += f.handle_velocity();
    s.tail(f.v.size()) += f.v;
    if (!f.free || f.omega.isZero()) return s;
    const int n = model.mesh.n_nodes;
    Vec3 moment = model.handle.mass * relative.head<3>().cross(f.handle.v_com) - f.start_moment;
    for (int i = 0; i < n; ++i) moment += model.masses[i] * relative.segment<3>(6 + 3 * i).cross(f.v.segment<3>(3 * i));
    const Vec3 turn = -f.dt * (f.inertia_inverse * moment);
    s.segment<3>(0) += turn.cross(f.handle.x_com - f.center);
    s.segment<3>(3) += turn;
    for (int i = 0; i < n; ++i) s.segment<3>(6 + 3 * i) += turn.cross(f.x.segment<3>(3 * i) - f.center);
    return s;
}

Vec3 relative_momentum(const StepFrame& f, double mass, const Vec3& x, const Vec3& v) {
    const Vec3 r = x - f.center;
    return mass * (v - f.omega.cross(r) - f.dt * f.omega.cross(f.omega.cross(f.rotation * r)));
}

}  // namespace hh
