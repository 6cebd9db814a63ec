// Seconds of wall time since t0, for the cost splits the engine reports; and the steady clock's
// present in seconds, for the haptic loop's periods and costs.
#pragma once
#include <chrono>

namespace hh {

inline double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

inline double wall_seconds() {
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

}  // namespace hh
