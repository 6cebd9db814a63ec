// Which SIMD kernels the library runs. The library is built for the baseline x86-64
// instruction set; its hot loops are compiled again for AVX2 + FMA and for AVX-512 and chosen
// at run time from what the CPU has.
#pragma once

namespace hh {

// 0 baseline x86-64, 1 AVX2 + FMA, 2 AVX-512 (detected once; HH_NO_AVX512 or HH_NO_SIMD in
// the environment lower it).
int detected_simd_level();
// Tests set it (>= 0) to run every level the CPU has; -1: automatic.
int& simd_level_override();
// The level to use now: the override when set (never above what the CPU has), else detected.
int active_simd_level();

}  // namespace hh
