// Shared by the C entry points: the opaque handle types, guard() which turns any exception
// into a status code and a thread-local message, and small argument helpers.
#pragma once
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
inline void put3(const Vec3& v, double* out) {
    if (out) std::memcpy(out, v.data(), 3 * sizeof(double));
}

}  // namespace hh::capi
