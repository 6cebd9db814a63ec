// The C handle of a haptic session (hh_session) and what the session entry points share:
// session_capi.cpp (the palm handle's sessions and every session's loops) and
// session_bones_capi.cpp (a skeleton hand's gloves, frames and groups).
#pragma once
#include <cmath>

#include "capi/guard.h"
#include "haptics/session.h"
#include "params/table.h"

struct hh_session {
    hh_session(hh_world* w, int hand, const hh::SessionParams& p) : world(w), s(w->w, hand, p) {}
    hh_world* world;
    hh::Session s;
};

namespace hh::capi {

inline hh_session& session_of(hh_session* session) {
    require(session != nullptr, "null session");
    return *session;
}
inline void require_stopped(hh_session& s) { require(!s.s.running(), "the session is running live: stop it first"); }
inline Keyframes keyframes(const double* times, const double* positions, const double* quaternions, int n) {
    require(times && positions && n >= 1, "a device trajectory needs at least one timed pose");
    return Keyframes(times, positions, quaternions, n);
}
// fail_at: a time from the table's range, or +inf for a device that never fails.
inline void require_fail_at(double fail_at) {
    if (fail_at != HUGE_VAL) params::check("haptics.fail_at", fail_at);
}

}  // namespace hh::capi
