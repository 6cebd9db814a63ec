// C entry points that check scene values holding between numbers (a trajectory's times, a box's
// cells) before anything is built, so the scene loader refuses them with the library's message.
#include <string>

#include "capi/guard.h"
#include "params/table.h"
#include "sim/keyframes.h"

using hh::capi::guard;
using hh::capi::require;

namespace {
// The most tets a box body may have: beyond, one step takes seconds and its factor runs the
// memory out.
constexpr double kMaxBoxTets = 200000;
constexpr int kTetsPerCell = 6;  // a cube split around its main diagonal

// 1234567 as "1,234,567".
std::string grouped(double count) {
    std::string digits = std::to_string(static_cast<long long>(count));
    for (int at = static_cast<int>(digits.size()) - 3; at > 0; at -= 3) digits.insert(at, ",");
    return digits;
}
}  // namespace

extern "C" {

int hh_trajectory_check(const double* times, const double* positions, const double* quaternions, int n) {
    return guard([&] {
        hh::Keyframes(times, positions, quaternions, n);
        return HH_OK;
    });
}

int hh_box_cells_check(const double cells[3]) {
    return guard([&] {
        require(cells != nullptr, "hh_box_cells_check: null pointer");
        hh::params::check(hh::params::row("bodies[].cells"), cells, 3);
        const double tets = kTetsPerCell * cells[0] * cells[1] * cells[2];
        if (tets > kMaxBoxTets)
            throw hh::InvalidArgument("cells [" + grouped(cells[0]) + ", " + grouped(cells[1]) + ", " +
                                      grouped(cells[2]) + "] make " + grouped(tets) + " tets, over " +
                                      grouped(kMaxBoxTets) + ": use fewer cells (a few per centimetre)");
        return HH_OK;
    });
}

}  // extern "C"
