// The per-step element pass of assemble_corotational on SIMD lanes: eight elements at a time
// with AVX-512, four with AVX2 (chosen at run time, common/simd.h). Same equations, same
// order of the sums into the forces and the matrix as the scalar loop (element by element), so
// the two agree to round-off (the SIMD build fuses multiply-adds).
#pragma once
#include <cstddef>

#include "fem/corotational.h"

namespace hh {

// Runs the leading elements of [begin, end) in whole batches of lanes: rotations
// (warm-started polar decomposition; inverted elements fall back to the scalar SVD path),
// forces added to f, scale * R Ke R^T added to values, the elastic energy added to energy.
// Returns the first element it did not handle (begin without SIMD); the caller does the rest.
size_t assemble_corotational_simd(const TetMesh& mesh, const CorotationalElements& elements, const double* x, double* f,
                                  ElementRotations& rotations, const StiffnessPattern& pattern, double scale,
                                  double* values, double& energy, size_t begin, size_t end);

}  // namespace hh
