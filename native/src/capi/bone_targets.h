// The bones' targets from the C arrays of hh_set_bone_targets and hh_world_set_bone_targets
// (docs/skeleton.md, Section 7), checked whole before any is written.
#pragma once
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

}  // namespace hh::capi
