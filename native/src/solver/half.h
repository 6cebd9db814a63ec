// Half-precision (IEEE binary16) panel values for the supernodal factor's preconditioner
// passes (BlockLDLT::set_keep_half). The passes are memory bound, and a half is a quarter of a
// double's traffic; their arithmetic is float (BlockLDLT::float_passes), so a pass applies the
// inverse of L_h L_h^T to float round-off, L_h the factor with its entries below the diagonal
// rounded (the kernels divide by the diagonal's own values). Each scalar column of a panel is stored
// divided by its largest magnitude (kept as a float scale), so every column uses the format's full relative precision
// (2^-11) whatever the matrix's units, and its small entries lose at most 2^-24 of the column's
// largest in the subnormal range.
//
// The conversions are AVX2-era F16C instructions: the loads below are for kernels compiled
// for AVX2 / AVX-512 (their target attribute includes f16c, and they inline these with
// `flatten`); has_f16c() says whether the CPU has them.
#pragma once
#include <cstddef>
#include <cstdint>

#if defined(__GNUC__) && defined(__x86_64__)
#include <immintrin.h>
#define HH_HAVE_F16C_KERNELS 1
#endif

namespace hh {

struct Half {
    std::uint16_t bits;
};

// Whether the CPU converts halves (F16C), and the library was built with the kernels that use it
bool has_f16c();

// to[k] = half(from[k] / scale) for k < n, rounded to nearest (ties to even). Needs has_f16c().
void to_half(const double* from, std::size_t n, double scale, Half* to);

#ifdef HH_HAVE_F16C_KERNELS
typedef float HalfFloat8 __attribute__((vector_size(32)));
typedef float HalfFloat16 __attribute__((vector_size(64)));
// eight / sixteen consecutive halves as floats
__attribute__((target("avx2,fma,f16c"))) inline HalfFloat8 load_half8_floats(const Half* p) {
    return _mm256_cvtph_ps(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)));
}
__attribute__((target("avx512f,avx512vl,avx2,fma,f16c"))) inline HalfFloat16 load_half16_floats(const Half* p) {
    // (the zero-masked form: GCC 12's plain one warns of its undefined pass-through operand)
    return _mm512_maskz_cvtph_ps(0xFFFF, _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p)));
}
__attribute__((target("f16c"))) inline float half_float(Half h) { return _cvtsh_ss(h.bits); }
#endif

}  // namespace hh
