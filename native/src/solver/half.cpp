#include "solver/half.h"

namespace hh {

bool has_f16c() {
#ifdef HH_HAVE_F16C_KERNELS
    static const bool yes = __builtin_cpu_supports("f16c");
    return yes;
#else
    return false;
#endif
}

#ifdef HH_HAVE_F16C_KERNELS
__attribute__((target("avx2,f16c"))) void to_half(const double* from, std::size_t n, double scale, Half* to) {
    const double inverse = 1.0 / scale;
    std::size_t k = 0;
    for (; k + 4 <= n; k += 4) {
        const __m128 f = _mm256_cvtpd_ps(_mm256_mul_pd(_mm256_loadu_pd(from + k), _mm256_set1_pd(inverse)));
        _mm_storel_epi64(reinterpret_cast<__m128i*>(to + k), _mm_cvtps_ph(f, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC));
    }
    for (; k < n; ++k)
        to[k].bits = static_cast<std::uint16_t>(
            _mm_extract_epi16(_mm_cvtps_ph(_mm_set_ss(static_cast<float>(from[k] * inverse)), _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC), 0));
}
#else
void to_half(const double*, std::size_t, double, Half*) {}
#endif

}  // namespace hh
