#include "common/simd.h"

#include <algorithm>

namespace hh {

int& simd_level_override() {
    static int level = -1;
    return level;
}

int detected_simd_level() {
#if defined(__GNUC__) && defined(__x86_64__)
    static const int level = []() {
        const bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
        const bool avx512 = avx2 && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl");
        return avx512 ? 2 : avx2 ? 1 : 0;
    }();
    return level;
#else
    return 0;
#endif
}

int active_simd_level() {
    if (simd_level_override() >= 0) return std::min(simd_level_override(), detected_simd_level());
    return detected_simd_level();
}

}  // namespace hh
