// Which SIMD kernels the library runs. The library is built for the baseline x86-64
// instruction set; its hot loops are compiled again for AVX2 + FMA and for AVX-512 and chosen
// at run time from what the CPU has. Nothing in the environment changes the choice.
#pragma once

namespace hh {

// 0 baseline x86-64, 1 AVX2 + FMA, 2 AVX-512: what the CPU has (detected once).
int detected_simd_level();
// Internal, for the native tests that compare the vector and scalar paths: set it (>= 0) to
// run a given level; -1 (the default) is automatic. Not thread-safe: set it between steps.
int& simd_level_override();
// The level to use now: the override when set (never above what the CPU has), else detected.
int active_simd_level();

}  // namespace hh
