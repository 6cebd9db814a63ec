// Which copy of a factor's values a solve pass reads (BlockLDLT, DeformableSystem::FactorForms).
#pragma once

namespace hh {

// The factor's own values (double), or a copy in single or half precision (BlockLDLT's
// set_keep_single, set_keep_half), for passes that precondition rather than solve.
enum class Panels { Double, Single, Half };

}  // namespace hh
