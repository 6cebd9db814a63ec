// The C ABI of the parameter table: its rows for bindings, the structs' defaults and the value
// check. Same rules as capi.cpp: guard() around every body.
#include "capi/guard.h"
#include "params/table.h"

using hh::capi::guard;
using hh::capi::require;

extern "C" {

int hh_param_count(void) { return static_cast<int>(hh::params::rows().size()); }

int hh_param_info_get(int index, hh_param_info* out) {
    return guard([&] {
        require(out != nullptr, "hh_param_info_get: null output");
        require(out->struct_size == static_cast<int>(sizeof(hh_param_info)),
                "hh_param_info has the wrong size: rebuild the native library (make native)");
        require(index >= 0 && index < hh_param_count(), "parameter index " + std::to_string(index) + " out of range");
        *out = hh::params::rows()[index];
        return HH_OK;
    });
}

int hh_struct_size(int structure, int* out_size) {
    return guard([&] {
        require(out_size != nullptr, "hh_struct_size: null output");
        *out_size = hh::params::struct_size(structure);
        return HH_OK;
    });
}

int hh_param_check(const char* json, const double* values, int count) {
    return guard([&] {
        require(json && (values || count == 0), "hh_param_check: null pointer");
        hh::params::check(hh::params::row(json), values, count);
        return HH_OK;
    });
}

void hh_default_params(hh_params* p) {
    if (p) hh::params::fill_defaults(HH_STRUCT_PARAMS, p);
}
void hh_default_world_params(hh_world_params* p) {
    if (p) hh::params::fill_defaults(HH_STRUCT_WORLD_PARAMS, p);
}
void hh_default_material(hh_material* m) {
    if (m) hh::params::fill_defaults(HH_STRUCT_MATERIAL, m);
}
void hh_default_session_params(hh_session_params* p) {
    if (p) hh::params::fill_defaults(HH_STRUCT_SESSION_PARAMS, p);
}

}  // extern "C"
