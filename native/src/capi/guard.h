// Shared by the C entry points: the opaque handle types, guard() which turns any exception
// into a status code and a thread-local message, and small argument helpers.
#pragma once
#include <atomic>
#include <cstring>
#include <new>
#include <string>

#include "haptic_hand.h"
#include "sim/world.h"

struct hh_model {
    hh::Model m;
};
struct hh_data {
    explicit hh_data(const hh::Model& model) : d(model) {}
    hh::Data d;
};
struct hh_world {
    explicit hh_world(const hh::WorldSettings& s) : w(s) {}
    hh::World w;
    // The live haptic session stepping the world on its own thread, or null. While it is set
    // the world's entry points refuse to touch the world (a data race would corrupt the
    // simulation). It belongs to the session that set it: only that session clears it, so
    // closing another session (never started) leaves it in place.
    std::atomic<const hh_session*> live_session{nullptr};
    bool in_live_session() const { return live_session.load(std::memory_order_acquire) != nullptr; }
    // Claims the world for `s`; false when another session has it.
    bool claim(const hh_session* s) {
        const hh_session* expected = nullptr;
        return live_session.compare_exchange_strong(expected, s, std::memory_order_acq_rel) || expected == s;
    }
    // Gives the world back if `s` holds it; another session's claim is left alone.
    void release(const hh_session* s) {
        const hh_session* expected = s;
        live_session.compare_exchange_strong(expected, nullptr, std::memory_order_acq_rel);
    }
};

namespace hh::capi {

inline std::string& last_error() {
    thread_local std::string message;
    return message;
}

template <class F>
int guard(F&& body) {
    std::string& err = last_error();
    try {
        err.clear();
        return body();
    } catch (const InvalidArgument& e) {
        err = e.what();
        return HH_ERR_INVALID_ARGUMENT;
    } catch (const NumericalError& e) {
        err = e.what();
        return HH_ERR_NUMERICAL;
    } catch (const std::bad_alloc&) {
        err = "out of memory: the mesh is too large for this machine";
        return HH_ERR_INTERNAL;
    } catch (const std::exception& e) {
        err = std::string("internal error: ") + e.what();
        return HH_ERR_INTERNAL;
    } catch (...) {
        err = "internal error: unknown exception";
        return HH_ERR_INTERNAL;
    }
}

inline void require(bool ok, const char* message) {
    if (!ok) throw InvalidArgument(message);
}
inline void require(bool ok, const std::string& message) {
    if (!ok) throw InvalidArgument(message);
}
inline void require_size(int given, int expected, const char* what) {
    if (given != expected)
        throw InvalidArgument(std::string(what) + ": array size " + std::to_string(given) +
                              " does not match the model's " + std::to_string(expected));
}
inline Vec3 vec3(const double* p) { return Vec3(p[0], p[1], p[2]); }
// The entry points built for the palm handle alone (docs/skeleton.md: the hand-alone
// linearization, the solver comparison and the world take one bone until the skeleton reaches them).
inline void require_one_bone(const Model& m, const char* what) {
    if (m.n_bones() != 1)
        throw InvalidArgument(std::string(what) + " takes a hand with one handle; this model has " +
                              std::to_string(m.n_bones()) + " bones (a skeleton): not supported there yet");
}

// The device frame with the given fields replaced (null: kept), checked and normalized; shared
// by the hand's and the world's hh_*_set_device.
inline DeviceFrame updated_device(DeviceFrame dev, int enabled, const double* position, const double* quaternion,
                                  const double* velocity, const double* angular_velocity) {
    dev.enabled = enabled != 0;
    dev.prescribed = enabled == 2;
    if (position) dev.position = vec3(position);
    if (quaternion) dev.quaternion = Vec4(quaternion[0], quaternion[1], quaternion[2], quaternion[3]);
    if (velocity) dev.velocity = vec3(velocity);
    if (angular_velocity) dev.angular_velocity = vec3(angular_velocity);
    if (!(dev.position.allFinite() && dev.quaternion.allFinite() && dev.quaternion.norm() > 1e-12 &&
          dev.velocity.allFinite() && dev.angular_velocity.allFinite()))
        throw InvalidArgument(
            "device pose or velocity contains NaN or infinite values, or a zero quaternion: check the device "
            "trajectory");
    dev.quaternion.normalize();
    return dev;
}
inline void put3(const Vec3& v, double* out) {
    if (out) std::memcpy(out, v.data(), 3 * sizeof(double));
}

}  // namespace hh::capi
