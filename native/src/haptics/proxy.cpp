#include "haptics/proxy.h"

#include "params/table.h"
#include "rigid/quaternion.h"

#include <cmath>
#include <cstdio>
#include <string>

namespace hh {

namespace {
std::string number(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.4g", v);
    return buf;
}
}  // namespace

VirtualCoupling::VirtualCoupling()
    : VirtualCoupling(params::default_of("coupling.stiffness"), params::default_of("coupling.damping"),
                      params::default_of("coupling.angular_stiffness"), params::default_of("coupling.angular_damping")) {}

void check_passive(const VirtualCoupling& c, double rate) {
    // Colgate & Schenkel 1997: a spring K sampled with period T stays passive when the damping
    // beside it is at least K T / 2 (what a zero-order hold adds per period)
    const double period = 1.0 / rate;
    auto check = [&](double k, double b, const char* what, const char* units_k, const char* units_b) {
        const double needed = 0.5 * k * period;
        if (b >= needed) return;
        std::string fix = "raise the " + std::string(what) + " damping to at least " + number(needed) + " " + units_b;
        if (b > 0) {
            fix += ", lower the " + std::string(what) + " stiffness to at most " + number(2 * b / period) + " " + units_k;
            if (k / (2 * b) <= 10000) fix += ", or raise the haptic rate to at least " + number(std::ceil(k / (2 * b))) + " Hz";
        }
        throw InvalidArgument("the virtual coupling is not passive at " + number(rate) + " Hz: its " + what + " damping " +
                              number(b) + " " + units_b + " is below stiffness x period / 2 = " + number(needed) + " " +
                              units_b + " (Colgate's bound), so the device would gain energy from it: " + fix);
    };
    check(c.stiffness, c.damping, "linear", "N/m", "N s/m");
    check(c.angular_stiffness, c.angular_damping, "angular", "N m/rad", "N m s/rad");
}

Vec6 coupling_on_proxy(const HandleState& proxy, const Pose& device, const VirtualCoupling& c) {
    Vec6 w;
    w.head<3>() = c.stiffness * (device.position - proxy.x_com) + c.damping * (device.velocity - proxy.v_com);
    const Vec3 rot = quat_to_rotation_vector(quat_multiply(device.quaternion, quat_conjugate(proxy.q)));
    w.tail<3>() = c.angular_stiffness * rot + c.angular_damping * (device.angular_velocity - proxy.omega);
    return w;
}

Feedback ProxyHandle::step(double dt, double t, const CouplingModel& model, bool linearized, const Pose& device,
                           const VirtualCoupling& c) {
    if (!linearized) {
        state.x_com = model.x_h;
        state.q = model.q_h;
        state.v_com = model.v_h;
        state.omega = model.omega_h;
    } else {
        // Backward Euler on v' = (v_com, omega) with every force linearized about the current
        // state: x' = x + dt v', theta' = theta + dt omega' (to first order), so
        //   (M - dt^2 K + dt^2 Kc + dt Dc) v' = M v + dt (F*_c(x, q at t + dt) + Fc(x, v = 0) + Dc v_d)
        // with K the model's stiffness, Kc and Dc the coupling's. The gyroscopic term is explicit.
        const Mat3 r = quat_to_matrix(state.q);
        const Mat3 inertia = r * inertia_body * r.transpose();
        Mat6 mass_matrix = Mat6::Zero();
        mass_matrix.topLeftCorner<3, 3>() = mass * Mat3::Identity();
        mass_matrix.bottomRightCorner<3, 3>() = inertia;
        Mat6 lhs = mass_matrix;
        Vec6 rhs;
        rhs.head<3>() = mass * state.v_com;
        rhs.tail<3>() = inertia * state.omega - dt * state.omega.cross(inertia * state.omega);
        if (model.valid) {
            lhs -= dt * dt * model.stiffness;
            // the model's reference moves on by dt during the step: evaluate at its end
            rhs += dt * model.evaluate(t + dt, state.x_com, state.q);
        }
        HandleState still = state;
        still.v_com.setZero();
        still.omega.setZero();
        rhs += dt * coupling_on_proxy(still, device, c);
        const double lin = dt * dt * c.stiffness + dt * c.damping;
        const double ang = dt * dt * c.angular_stiffness + dt * c.angular_damping;
        lhs.topLeftCorner<3, 3>() += lin * Mat3::Identity();
        lhs.bottomRightCorner<3, 3>() += ang * Mat3::Identity();
        const Vec6 v = lhs.partialPivLu().solve(rhs);
        state.v_com = v.head<3>();
        state.omega = v.tail<3>();
        state.x_com += dt * state.v_com;
        state.q = quat_multiply(quat_from_rotation_vector(dt * state.omega), state.q).normalized();
    }
    const Vec6 w = coupling_on_proxy(state, device, c);
    Feedback fb;
    fb.force = -w.head<3>();
    fb.torque = -w.tail<3>();
    return fb;
}

}  // namespace hh
