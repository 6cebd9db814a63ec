// The parameter table (include/haptic_hand_params.h) as the library uses it: every row once,
// the structs' defaults filled from it, and every value checked against its row, so a range
// and its message live in one place.
#pragma once
#include <string>
#include <vector>

#include "haptic_hand.h"

namespace hh::params {

// The rows: one per field of each struct, then the scene file's other fields.
const std::vector<hh_param_info>& rows();

// The row of a JSON path (its first one, for a row two structs share); throws
// InvalidArgument for an unknown path.
const hh_param_info& row(const char* json);

// Throws InvalidArgument naming the field, the valid range and a good value when `values`
// (count numbers; enums as their index, booleans as 0 / 1) are not valid for the row.
void check(const hh_param_info& row, const double* values, int count);
inline void check(const char* json, double value) { check(row(json), &value, 1); }

// Fills a struct HH_STRUCT_* with its rows' defaults (and its struct_size).
void fill_defaults(int structure, void* s);

// A struct of the table with its rows' defaults: the library's own settings start from these,
// so a default lives only in its row.
template <class S, int Structure>
S defaults() {
    S s;
    fill_defaults(Structure, &s);
    return s;
}
inline hh_world_params world_defaults() { return defaults<hh_world_params, HH_STRUCT_WORLD_PARAMS>(); }
inline hh_session_params session_defaults() { return defaults<hh_session_params, HH_STRUCT_SESSION_PARAMS>(); }

// The default of a scalar row (by its JSON path) that has no C struct.
inline double default_of(const char* json) { return row(json).default_value[0]; }

// Checks struct_size, then every row of the struct: the first bad field throws.
void validate(int structure, const void* s);

int struct_size(int structure);

// The rule a row's values obey, in words ("in (0, 0.5)", "positive (Pa)").
std::string rule(const hh_param_info& row);

}  // namespace hh::params
