// The bones' targets and states from the C arrays of hh_set_bone_targets, hh_set_bone_states and
// their world forms (docs/skeleton.md, Section 7), checked whole before any is written.
#pragma once
#include <cmath>
#include <string>
#include <vector>

#include "capi/guard.h"
#include "sim/data.h"

namespace hh::capi {

inline std::vector<DeviceFrame> bone_targets(const Data& data, int n_bones, const int* modes, const double* positions,
                                             const double* quaternions, const double* velocities,
                                             const double* angular_velocities) {
    require(modes != nullptr, "bone targets: null modes");
    std::vector<DeviceFrame> targets(n_bones);
    const Vec3 zero = Vec3::Zero();
    for (int b = 0; b < n_bones; ++b) {
        require(modes[b] == HH_BONE_FREE || modes[b] == HH_BONE_COUPLED || modes[b] == HH_BONE_PRESCRIBED,
                "bone " + std::to_string(b) + " has mode " + std::to_string(modes[b]) +
                    ": give HH_BONE_FREE (0), HH_BONE_COUPLED (1) or HH_BONE_PRESCRIBED (2)");
        // (velocities not given: zero, as the docs say; poses not given: kept)
        targets[b] = updated_device(bone_target(data, b), modes[b], positions ? positions + 3 * b : nullptr,
                                    quaternions ? quaternions + 4 * b : nullptr,
                                    velocities ? velocities + 3 * b : zero.data(),
                                    angular_velocities ? angular_velocities + 3 * b : zero.data());
    }
    return targets;
}

inline void require_finite(const double* p, int count, const char* what) {
    for (int i = 0; i < count; ++i)
        require(std::isfinite(p[i]), std::string(what) + " contains NaN or infinite values: check the bone poses");
}

inline Vec4 unit_quaternion(const double* q, const char* what) {
    const Vec4 out(q[0], q[1], q[2], q[3]);
    require(out.allFinite() && out.norm() > 1e-12, std::string(what) + ": a zero or non-finite quaternion");
    return out.normalized();
}

// Every bone's state with the given arrays' values (NULL: kept)
inline std::vector<HandleState> bone_states(const Data& data, int n_bones, const double* positions,
                                            const double* quaternions, const double* velocities,
                                            const double* angular_velocities) {
    if (positions) require_finite(positions, 3 * n_bones, "bone positions");
    if (velocities) require_finite(velocities, 3 * n_bones, "bone velocities");
    if (angular_velocities) require_finite(angular_velocities, 3 * n_bones, "bone angular velocities");
    std::vector<HandleState> states(n_bones);
    for (int b = 0; b < n_bones; ++b) {
        HandleState h = bone_state(data, b);
        if (positions) h.x_com = vec3(positions + 3 * b);
        if (quaternions) h.q = unit_quaternion(quaternions + 4 * b, "bone quaternions");
        if (velocities) h.v_com = vec3(velocities + 3 * b);
        if (angular_velocities) h.omega = vec3(angular_velocities + 3 * b);
        states[b] = h;
    }
    return states;
}

}  // namespace hh::capi
