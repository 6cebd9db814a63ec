// Seconds of wall time since t0, for the cost splits the engine reports.
#pragma once
#include <chrono>

namespace hh {

inline double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace hh
